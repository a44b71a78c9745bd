"""Lazy references: registry entries (feature tiers, renderers, aligners; ``docs/ARCHITECTURE.md``) and package
exports.

A registry entry may be given as ``"package.module:attribute"``: the module is imported when the entry is first
used, so registering costs no import (torch, mitsuba, bpy) and a module registered by name may import its
registry's module without an import cycle. :func:`lazy_exports` does the same for a package's public names.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any, TypeVar

T = TypeVar("T")


def resolve(entry: T | str) -> T:
    """``entry`` itself, or the object a ``"package.module:attribute"`` string names (imported now)."""
    if not isinstance(entry, str):
        return entry
    module, sep, attribute = entry.partition(":")
    if not (sep and module and attribute):
        raise ValueError(f"{entry!r}: a lazy registry entry must read 'package.module:attribute'")
    return getattr(importlib.import_module(module), attribute)


def lazy_exports(package: str, exports: dict[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """A package's module-level ``__getattr__`` and ``__dir__`` for ``exports`` (public name -> its module: a bare
    name is a module of ``package``, a dotted one is absolute): each name is imported on first use and then
    kept in the package's namespace."""

    def __getattr__(name: str) -> Any:
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        module = exports[name]
        value = getattr(importlib.import_module(module if "." in module else f"{package}.{module}"), name)
        setattr(importlib.import_module(package), name, value)  # looked up once
        return value

    def __dir__() -> list[str]:
        return sorted({*vars(importlib.import_module(package)), *exports})

    return __getattr__, __dir__
