"""Typed TOML tables: a frozen dataclass per table, its field types converted and a rule per field checked.

:func:`from_table` turns a TOML table into a dataclass: unknown and missing keys, wrong types and every rule in
the class's ``RULES`` (``field -> rule``) raise :class:`~synthleak.errors.ConfigError` naming the file and the
key. Study configs (:mod:`synthleak.config`) and object library models (:mod:`synthleak.assets.model`) are read
with it. This module sits below every stage: it imports nothing of synthleak but the error classes.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from collections.abc import Callable, Iterable
from typing import Any

from synthleak.errors import ConfigError

# ------------------------------------------------------------------------------------------------- rules
Rule = Callable[[Any, str], None]
"""``rule(value, where)`` raises :class:`ConfigError` (``where`` names the file and the key) for a bad value."""


def _fmt(value: Any) -> str:
    return repr(list(value)) if isinstance(value, tuple) else repr(value)


def anything(value: Any, where: str) -> None:
    """Any value of the declared type (free text, switches)."""


def at_least(low: float, exclusive: bool = False) -> Rule:
    """A number ``>= low`` (``> low`` when ``exclusive``)."""

    def rule(value: Any, where: str) -> None:
        if value < low or (exclusive and value == low):
            raise ConfigError(f"{where}: must be {'>' if exclusive else '>='} {low:g}, got {_fmt(value)}")

    return rule


def within(low: float, high: float, low_open: bool = False, high_open: bool = False) -> Rule:
    """A number in the interval from ``low`` to ``high`` (``*_open``: that end excluded)."""
    text = f"{'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"

    def rule(value: Any, where: str) -> None:
        if value < low or value > high or (low_open and value == low) or (high_open and value == high):
            raise ConfigError(f"{where}: must be in {text}, got {_fmt(value)}")

    return rule


def one_of(names: Iterable[str] | Callable[[], Iterable[str]]) -> Rule:
    """A name among ``names`` (a callable is asked when the config loads: a registry, imported lazily)."""

    def rule(value: Any, where: str) -> None:
        known = list(names() if callable(names) else names)
        if value not in known:
            raise ConfigError(f"{where}: unknown name {value!r} (known: {', '.join(known)})")

    return rule


def each(item: Rule, nonempty: bool = False) -> Rule:
    """A list whose items all pass ``item`` (``nonempty``: at least one item)."""

    def rule(value: Any, where: str) -> None:
        if nonempty and not value:
            raise ConfigError(f"{where}: must not be empty")
        for i, v in enumerate(value):
            item(v, f"{where}[{i}]")

    return rule


def one_or_each(item: Rule) -> Rule:
    """A single value passing ``item``, or a non-empty list of distinct values that each pass it (a study axis:
    ``profile = "hloc"`` or ``profile = ["strict", "hloc"]``)."""

    def rule(value: Any, where: str) -> None:
        if not isinstance(value, list):
            item(value, where)
            return
        each(item, nonempty=True)(value, where)
        if len(set(value)) != len(value):
            raise ConfigError(f"{where}: values must be distinct, got {_fmt(value)}")

    return rule


def as_list(value: Any) -> list:
    """A :func:`one_or_each` value as a list."""
    return list(value) if isinstance(value, list | tuple) else [value]


def ordered(item: Rule = anything) -> Rule:
    """A ``[min, max]`` pair whose values pass ``item``, with min <= max."""

    def rule(value: Any, where: str) -> None:
        each(item)(value, where)
        if value[0] > value[1]:
            raise ConfigError(f"{where}: [min, max] must be ordered, got {_fmt(value)}")

    return rule


def optional(item: Rule) -> Rule:
    """``None`` (the field left out) or a value passing ``item``."""

    def rule(value: Any, where: str) -> None:
        if value is not None:
            item(value, where)

    return rule


def matches(pattern: str) -> Rule:
    """A string matching the regular expression ``pattern`` as a whole."""

    def rule(value: Any, where: str) -> None:
        if not re.fullmatch(pattern, value):
            raise ConfigError(f"{where}: {value!r} must match {pattern}")

    return rule


def _convert(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table")
        return from_table(hint, value, where)
    if hint is Any:
        return value
    if origin is dict:
        _, item_hint = typing.get_args(hint)
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table")
        return {k: _convert(v, item_hint, f"{where}.{k}") for k, v in value.items()}
    if origin in (list,):
        (item_hint,) = typing.get_args(hint)
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__}")
        return [_convert(v, item_hint, f"{where}[{i}]") for i, v in enumerate(value)]
    if origin is tuple:
        args = typing.get_args(hint)
        if not isinstance(value, list) or len(value) != len(args):
            raise ConfigError(f"{where}: expected a list of {len(args)} values")
        return tuple(_convert(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args, strict=True)))
    if origin in (typing.Union, types.UnionType):
        for arg in typing.get_args(hint):
            try:
                return _convert(value, arg, where)
            except ConfigError:
                continue
        kinds = " or ".join(getattr(a, "__name__", str(a)) if typing.get_origin(a) is None else str(a)
                            for a in typing.get_args(hint))
        raise ConfigError(f"{where}: expected {kinds}, got {value!r}")
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {type(value).__name__}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {type(value).__name__}")
        return value
    if hint in (str, bool):
        if not isinstance(value, hint):
            raise ConfigError(f"{where}: expected {hint.__name__}, got {type(value).__name__}")
        return value
    if hint is type(None):
        if value is not None:
            raise ConfigError(f"{where}: expected nothing")
        return None
    raise ConfigError(f"{where}: unsupported type {hint}")


def from_table(cls: type, data: dict[str, Any], where: str) -> Any:
    """``data`` (a TOML table) as a ``cls`` instance, checked field by field (see the module docstring).

    ``where`` names the table: ``"<file>: "`` for the top level, ``"<file>: <key>"`` for a nested table."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    prefix = f"{where}." if where and not where.endswith(": ") else where
    for key in data:
        if key not in names:
            raise ConfigError(f"{prefix}{key}: unknown key (allowed: {', '.join(sorted(names))})")
    for f in dataclasses.fields(cls):
        required = f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
        if required and f.name not in data:
            raise ConfigError(f"{prefix}{f.name}: missing")
    kwargs = {key: _convert(value, hints[key], f"{prefix}{key}") for key, value in data.items()}
    try:
        built = cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from exc
    for key, rule in getattr(cls, "RULES", {}).items():
        rule(getattr(built, key), f"{prefix}{key}")
    if hasattr(built, "check_fields"):  # rules across fields
        built.check_fields(prefix)
    return built
