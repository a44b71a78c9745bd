"""Shell styles (textures, palettes, light colours) read from TOML templates in ``scenes_usd/``.

``room_styles.toml`` holds the styles rooms are drawn from, ``attacker_hall.toml`` those of the attacker's
inventory hall. Each ``[[style]]`` table lists texture kinds and RGB colours per surface; bad entries raise
:class:`StyleError` naming the file and the field.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np

from synthleak.errors import SynthleakError
from synthleak.paths import scenes_usd_dir

Colour = tuple[float, float, float]
SURFACES = ("floor", "wall", "ceiling", "door", "backdrop")
EXTRA_SURFACES = ("pedestal", "panel")


class StyleError(SynthleakError, ValueError):
    """A style template that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Finish:
    """Texture kinds and colours one surface is drawn from."""

    kinds: tuple[str, ...]
    colours: tuple[Colour, ...]

    def draw(self, rng: np.random.Generator) -> tuple[str, Colour]:
        kind = self.kinds[int(rng.integers(len(self.kinds)))]
        colour = self.colours[int(rng.integers(len(self.colours)))]
        return kind, colour


@dataclass(frozen=True)
class ShellStyle:
    """One shell style: a finish per surface plus lighting."""

    name: str
    finishes: dict[str, Finish]
    light_colour: Colour
    light_intensity: tuple[float, float]
    ambient: tuple[float, float]
    size: tuple[float, float, float] | None = None


def _colour(value: object, where: str) -> Colour:
    if (
        not isinstance(value, list)
        or len(value) != 3
        or not all(isinstance(c, int | float) and not isinstance(c, bool) and 0.0 <= c <= 1.0 for c in value)
    ):
        raise StyleError(f"{where}: expected an RGB list of 3 numbers in [0, 1], got {value!r}")
    return (float(value[0]), float(value[1]), float(value[2]))


def _pair(value: object, where: str) -> tuple[float, float]:
    if not isinstance(value, list) or len(value) != 2 or not all(isinstance(v, int | float) for v in value):
        raise StyleError(f"{where}: expected [min, max] numbers, got {value!r}")
    lo, hi = float(value[0]), float(value[1])
    if lo > hi or lo < 0:
        raise StyleError(f"{where}: expected 0 <= min <= max, got {value!r}")
    return lo, hi


def _finish(table: dict, surface: str, where: str) -> Finish:
    kinds = table.get(surface)
    colours = table.get(f"{surface}_colours")
    if not isinstance(kinds, list) or not kinds or not all(isinstance(k, str) for k in kinds):
        raise StyleError(f"{where}.{surface}: expected a non-empty list of texture kinds")
    if not isinstance(colours, list) or not colours:
        raise StyleError(f"{where}.{surface}_colours: expected a non-empty list of RGB colours")
    from synthleak.assets.textures import TEXTURE_KINDS

    for kind in kinds:
        if kind not in TEXTURE_KINDS:
            raise StyleError(
                f"{where}.{surface}: unknown texture kind {kind!r} (known: {', '.join(TEXTURE_KINDS)})"
            )
    cols = tuple(_colour(c, f"{where}.{surface}_colours[{i}]") for i, c in enumerate(colours))
    return Finish(tuple(kinds), cols)


def parse_styles(data: dict, source: str, extra: tuple[str, ...] = ()) -> list[ShellStyle]:
    """Validate the ``[[style]]`` tables of a template (``extra``: surfaces required beyond the shell's)."""
    tables = data.get("style")
    if not isinstance(tables, list) or not tables:
        raise StyleError(f"{source}: expected at least one [[style]] table")
    styles = []
    for i, table in enumerate(tables):
        where = f"{source}: style[{i}]"
        known = {"name", "size", "light_colour", "light_intensity", "ambient"}
        for surface in (*SURFACES, *EXTRA_SURFACES):
            known |= {surface, f"{surface}_colours"}
        for key in table:
            if key not in known:
                raise StyleError(f"{where}.{key}: unknown key")
        name = table.get("name")
        if not isinstance(name, str) or not name:
            raise StyleError(f"{where}.name: expected a non-empty string")
        finishes = {s: _finish(table, s, where) for s in (*SURFACES, *extra)}
        size = table.get("size")
        if size is not None and (
            not isinstance(size, list)
            or len(size) != 3
            or not all(isinstance(v, int | float) and v > 0 for v in size)
        ):
            raise StyleError(f"{where}.size: expected [x, y, z] positive sizes in metres")
        styles.append(
            ShellStyle(
                name=name,
                finishes=finishes,
                light_colour=_colour(table.get("light_colour"), f"{where}.light_colour"),
                light_intensity=_pair(table.get("light_intensity"), f"{where}.light_intensity"),
                ambient=_pair(table.get("ambient"), f"{where}.ambient"),
                size=None if size is None else (float(size[0]), float(size[1]), float(size[2])),
            )
        )
    return styles


def load_styles(path: Path, extra: tuple[str, ...] = ()) -> list[ShellStyle]:
    """Read and validate a style template file."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except FileNotFoundError as exc:
        raise StyleError(f"{path}: no such style template") from exc
    except tomllib.TOMLDecodeError as exc:
        raise StyleError(f"{path}: not valid TOML: {exc}") from exc
    return parse_styles(data, str(path), extra)


@cache
def room_styles() -> tuple[ShellStyle, ...]:
    """Styles of ``scenes_usd/room_styles.toml``."""
    return tuple(load_styles(scenes_usd_dir() / "room_styles.toml"))


@cache
def attacker_styles() -> tuple[ShellStyle, ...]:
    """Styles of ``scenes_usd/attacker_hall.toml`` (with pedestal and wall-panel finishes and a hall size)."""
    styles = tuple(load_styles(scenes_usd_dir() / "attacker_hall.toml", EXTRA_SURFACES))
    for style in styles:
        if style.size is None:
            raise StyleError(
                f"{scenes_usd_dir() / 'attacker_hall.toml'}: style {style.name!r}: field 'size' missing"
            )
    return styles
