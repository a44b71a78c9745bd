"""Study configuration: TOML files in ``render_configs/``, validated against typed dataclasses.

A config may start with ``extends = "NAME"`` to inherit another config of the same folder (deep merge,
the child wins). Unknown keys and wrong types raise :class:`ConfigError` naming the file and the key.
"""

from __future__ import annotations

import dataclasses
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from synthleak.paths import render_configs_dir


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class ScenesConfig:
    """How many rooms, which objects, and how far variants drift from their model."""

    rooms: int = 2
    objects_per_room: tuple[int, int] = (4, 10)
    room_size_x: tuple[float, float] = (4.0, 6.0)
    room_size_y: tuple[float, float] = (3.5, 5.0)
    room_height: tuple[float, float] = (2.5, 2.8)
    distinct_objects: int = 0
    """Target number of distinct selected models over the study (0: no target)."""
    models: list[str] = field(default_factory=list)
    """Restrict selection to these model ids (empty: the whole library)."""
    scene_variant_magnitude: float = 0.3
    attacker_variant_magnitude: float = 0.5
    attacker_variant_kinds: list[str] = field(default_factory=lambda: ["colour", "scale", "shape"])
    lights_per_room: tuple[int, int] = (2, 4)


@dataclass(frozen=True)
class RenderConfig:
    """Renderer preset: backend, resolution, sampling, and frame counts per sequence."""

    renderer: str = "mitsuba"
    width: int = 640
    height: int = 480
    hfov_deg: float = 65.0
    spp: int = 8
    integrator: str = "direct"
    max_depth: int = 3
    filter: str = "box"
    scene_frames: int = 200
    attacker_frames: int = 100
    query_every: int = 5
    """Every n-th walk-through frame is held out as a genuine query and kept out of the map."""
    bop_extras: bool = True
    """Write the whole BOP layout after each sequence (full/visible masks, scene_gt_info, 16-bit depth, models);
    false keeps only bop/scene_gt.json and scene_camera.json (the attack study does not read the extras)."""
    raster_shadows: bool = True
    """pyrender only: shadow maps for rect (spot) and distant lights; off renders RGB about 2x faster."""
    mitsuba_variant: str = "scalar_rgb"
    """mitsuba only: ``scalar_rgb`` (runs anywhere) or ``llvm_ad_rgb`` (vectorised, all lights in one pass:
    measured 7x less CPU per room frame and 13x per attacker frame at 640x480; needs the LLVM shared library,
    version >= 16: ``apt-get install libllvm19`` on Debian 12). Same seed, same bytes within a variant."""
    notes: str = ""


@dataclass(frozen=True)
class LocalizeConfig:
    """Localization server: feature tiers, retrieval, PnP."""

    tiers: list[str] = field(default_factory=lambda: ["sift"])
    retrieval: str = "exhaustive"
    top_k: int = 10
    bow_branching: int = 32
    """Bag-of-words vocabulary tree: children per node ..."""
    bow_depth: int = 2
    """... and levels: up to ``bow_branching ** bow_depth`` words (see :mod:`synthleak.localize.retrieval`)."""
    max_keypoints: int = 4096
    pnp_max_error_px: float = 12.0
    min_inliers: int = 0
    """0: the tier's own default."""
    pairs_per_image: int = 10


@dataclass(frozen=True)
class AttackConfig:
    """Attacker: local model source, aligners, Alg. 1 thresholds (degrees, metres)."""

    local_model: str = "oracle"
    aligners: list[str] = field(default_factory=lambda: ["alg1", "robust"])
    thresholds: list[tuple[float, float]] = field(
        default_factory=lambda: [(10.0, 0.25), (30.0, 0.5), (60.0, 2.0)]
    )
    queries_per_object: int = 0
    """0: every attacker frame is sent."""


@dataclass(frozen=True)
class DefenseConfig:
    """Query defense (paper Sec. 6) and its offline sweep grid."""

    enabled: bool = False
    min_fraction: float = 0.1
    min_instances: int = 3
    sweep_fractions: list[float] = field(default_factory=lambda: [0.05, 0.1, 0.2, 0.3])
    sweep_min_instances: list[int] = field(default_factory=lambda: [1, 2, 3, 4, 5, 6])


@dataclass(frozen=True)
class SweepConfig:
    """Leakage-vs-dissimilarity sweep over attacker variant magnitudes (empty: no sweep)."""

    magnitudes: list[float] = field(default_factory=list)
    kinds: list[str] = field(default_factory=lambda: ["all"])


@dataclass(frozen=True)
class StudyConfig:
    """One study, from stages to report."""

    name: str
    seed: int = 0
    description: str = ""
    scenes: ScenesConfig = field(default_factory=ScenesConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    localize: LocalizeConfig = field(default_factory=LocalizeConfig)
    attack: AttackConfig = field(default_factory=AttackConfig)
    defense: DefenseConfig = field(default_factory=DefenseConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)


def resolve_config_path(name_or_path: str | Path) -> Path:
    """A config file path from a path or a bare name of ``render_configs/`` (``ci-tiny``)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    candidate = render_configs_dir() / f"{path.name.removesuffix('.toml')}.toml"
    if candidate.is_file():
        return candidate
    raise ConfigError(f"{name_or_path}: no such config file (looked in {render_configs_dir()})")


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path in seen:
        raise ConfigError(f"{path}: 'extends' cycle through {[str(p) for p in seen]}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: key 'extends' must be a config name (str)")
    return _deep_merge(_read_toml(resolve_config_path(parent), (*seen, path)), data)


def _deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _convert(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table")
        return _build(hint, value, where)
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
        raise ConfigError(f"{where}: value {value!r} matches none of {hint}")
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


def _build(cls: type, data: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    prefix = f"{where}." if where and not where.endswith(": ") else where
    for key in data:
        if key not in names:
            raise ConfigError(f"{prefix}{key}: unknown key (allowed: {', '.join(sorted(names))})")
    kwargs = {key: _convert(value, hints[key], f"{prefix}{key}") for key, value in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> StudyConfig:
    """Validate a plain dict (as read from TOML) into a :class:`StudyConfig`."""
    data = dict(data)
    data.setdefault("name", Path(source).stem)
    return _build(StudyConfig, data, f"{source}: ")


def load_config(name_or_path: str | Path) -> StudyConfig:
    """Load and validate a study config by path or by name in ``render_configs/``."""
    path = resolve_config_path(name_or_path)
    return config_from_dict(_read_toml(path), str(path))


def config_to_dict(config: StudyConfig) -> dict[str, Any]:
    """Plain-data form of a config (tuples become lists), for manifests and cache keys."""

    def plain(value: Any) -> Any:
        if isinstance(value, tuple | list):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return plain(dataclasses.asdict(config))
