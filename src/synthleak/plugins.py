"""Lazy references for the registries (feature tiers, renderers, aligners; ``docs/ARCHITECTURE.md``).

A registry entry may be given as ``"package.module:attribute"``: the module is imported when the entry is first
used, so registering costs no import (torch, mitsuba, bpy) and a module registered by name may import its
registry's module without an import cycle.
"""

from __future__ import annotations

import importlib
from typing import TypeVar

T = TypeVar("T")


def resolve(entry: T | str) -> T:
    """``entry`` itself, or the object a ``"package.module:attribute"`` string names (imported now)."""
    if not isinstance(entry, str):
        return entry
    module, sep, attribute = entry.partition(":")
    if not (sep and module and attribute):
        raise ValueError(f"{entry!r}: a lazy registry entry must read 'package.module:attribute'")
    return getattr(importlib.import_module(module), attribute)
