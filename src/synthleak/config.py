"""Study configuration: TOML files in ``render_configs/``, validated against typed dataclasses.

A config may start with ``extends = "NAME"`` to inherit another config (deep merge, the child wins); NAME is
looked up beside the file first, then in ``render_configs/``. Unknown keys, wrong types, names that no registry
knows (tiers, aligners, renderers, ...) and values out of range raise :class:`ConfigError` naming the file and
the key, when the config loads: each config class lists a rule per field in its ``RULES``. An empty file is
refused.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import tomllib
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from synthleak.errors import ConfigError, SynthleakError
from synthleak.paths import render_configs_dir, results_index_path
from synthleak.schema import Rule, anything, at_least, each, from_table, one_of, one_or_each, ordered, within


def _tiers() -> Iterable[str]:
    from synthleak.localize.tiers import tier_names

    return tier_names()


def _profiles() -> Iterable[str]:
    from synthleak.localize.tiers import profile_names

    return profile_names()


def _representations() -> Iterable[str]:
    from synthleak.localize.representations import representation_names

    return representation_names()


def _aligners() -> Iterable[str]:
    from synthleak.attack.align import aligner_names

    return aligner_names()


def _presence_rules() -> Iterable[str]:
    from synthleak.evaluate.tables import PRESENCE_RULES

    return PRESENCE_RULES


def _renderers() -> Iterable[str]:
    from synthleak.render.registry import available_renderers

    return available_renderers()


def _render_option(name: str) -> Callable[[], Iterable[str]]:
    def names() -> Iterable[str]:
        from synthleak.render import registry

        return getattr(registry, name)

    return names


def _retrieval_methods() -> Iterable[str]:
    from synthleak.localize.retrieval import RETRIEVAL_METHODS

    return RETRIEVAL_METHODS


def _pnp_solvers() -> Iterable[str]:
    from synthleak.localize.pnp import PNP_SOLVERS

    return PNP_SOLVERS


def _layouts() -> Iterable[str]:
    from synthleak.scene.placement import LAYOUTS

    return LAYOUTS


def _walkthroughs() -> Iterable[str]:
    from synthleak.render.trajectories import WALKTHROUGHS

    return WALKTHROUGHS


def _lighting_changes() -> Iterable[str]:
    from synthleak.render.light_conditions import LIGHTING_CHANGES

    return LIGHTING_CHANGES


def _capture_profiles() -> Iterable[str]:
    from synthleak.render.devices import PROFILE_NAMES

    return PROFILE_NAMES


def _variant_kinds() -> Iterable[str]:
    from synthleak.assets.mesh import VARIANT_KINDS

    return VARIANT_KINDS


def _study_option(name: str) -> Callable[[], Iterable[str]]:
    def names() -> Iterable[str]:
        from synthleak import study

        return getattr(study, name)

    return names


POSITIVE = at_least(0.0, exclusive=True)
COUNT = at_least(1)


@dataclass(frozen=True)
class ScenesConfig:
    """How many rooms, which objects, and how far variants drift from their model."""

    RULES: ClassVar[dict[str, Rule]] = {
        "rooms": COUNT,
        "objects_per_room": ordered(at_least(0)),
        "room_size_x": ordered(POSITIVE),
        "room_size_y": ordered(POSITIVE),
        "room_height": ordered(POSITIVE),
        "distinct_objects": at_least(0),
        "models": anything,  # model ids are checked against the library when the stages are planned
        "scene_variant_magnitude": at_least(0.0),
        "attacker_variant_magnitude": at_least(0.0),
        "attacker_variant_kinds": each(one_of(_variant_kinds)),
        "lights_per_room": ordered(at_least(0)),
        "material_sharing": within(0.0, 1.0),
        "distractors": ordered(at_least(0)),
        "clutter": at_least(0.0),
        "layout": one_of(_layouts),
    }
    """A rule per field, checked when the config loads."""


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
    material_sharing: float = 0.0
    """Probability in [0, 1] that a model's material slot uses a shared catalogue SKU (the same exact texture
    on every product using it) instead of a model-unique texture; 0 keeps every model's own textures."""
    distractors: tuple[int, int] = (0, 0)
    """Per room [min, max] look-alike furniture models that are never attacker objects (never "present")."""
    clutter: float = 0.0
    """Clutter level: 1 is a lived-in home (about 0.25 floor props per m² of floor, 0.1 wall props per metre
    of free wall, 4 small props per m² of table and shelf tops); 0 places none."""
    layout: str = "scatter"
    """``home``: furniture as people place it (cupboards, beds, sofas, shelves, desks backed against walls,
    chairs at tables, lamps beside seats); ``scatter``: anywhere, half of it free-standing."""


@dataclass(frozen=True)
class RenderConfig:
    """Renderer preset: backend, resolution, sampling, and frame counts per sequence."""

    RULES: ClassVar[dict[str, Rule]] = {
        "renderer": one_of(_renderers),
        "width": COUNT,
        "height": COUNT,
        "hfov_deg": within(0.0, 180.0, low_open=True, high_open=True),
        "spp": COUNT,
        "integrator": one_of(_render_option("INTEGRATORS")),
        "max_depth": COUNT,
        "filter": one_of(_render_option("FILTERS")),
        "scene_frames": COUNT,
        "attacker_frames": COUNT,
        "query_every": at_least(2),
        "bop_extras": anything,
        "raster_shadows": anything,
        "mitsuba_variant": one_of(_render_option("MITSUBA_VARIANTS")),
        "walkthrough": one_of(_walkthroughs),
        "genuine_closeup_fraction": within(0.0, 1.0),
        "capture_map": one_of(_capture_profiles),
        "capture_genuine": one_of(_capture_profiles),
        "capture_attacker": one_of(_capture_profiles),
        "light_map": one_of(_lighting_changes),
        "light_genuine": one_of(_lighting_changes),
        "light_attacker": one_of(_lighting_changes),
        "notes": anything,
    }
    """A rule per field, checked when the config loads."""
    KEY_DEFAULTS: ClassVar[dict[str, Any]] = {
        "capture_map": "ideal", "capture_genuine": "ideal", "capture_attacker": "ideal",
        "light_map": "same", "light_genuine": "same", "light_attacker": "same",
    }  # fmt: skip
    """Fields added after content keys were in use: :func:`config_to_dict` leaves them out at these values, so a
    config that does not change them keeps its keys (and its cached renders and everything after them)."""


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
    false keeps only bop/scene_gt.json, scene_camera.json and rgb/ (hard links to the images; the attack study
    does not read the extras)."""
    raster_shadows: bool = True
    """pyrender only: shadow maps for rect (spot) and distant lights; off renders RGB about 2x faster."""
    mitsuba_variant: str = "scalar_rgb"
    """mitsuba only: ``scalar_rgb`` (runs anywhere) or ``llvm_ad_rgb`` (vectorised, all lights in one pass:
    measured 7x less CPU per room frame and 13x per attacker frame at 640x480; needs the LLVM shared library,
    version >= 16: ``apt-get install libllvm19`` on Debian 12). Same seed, same bytes within a variant."""
    walkthrough: str = "loop"
    """``furniture``: the walk-through visits the furniture and looks at each piece from its open side,
    0.6-2.6 m away, as a mapping crew would; ``loop``: a loop through the free floor looking across the room."""
    genuine_closeup_fraction: float = 0.0
    """Share of the held-out genuine query frames taken 0.5-1.5 m from one object or a small group, as a
    phone user would (the rest are walk-through frames)."""
    capture_map: str = "ideal"
    """Camera profile (:mod:`synthleak.render.devices`) that photographs the mapping walk-through frames;
    ``ideal``: the renderer's plain 8-bit encoding (docs/renderers.md, "Photographic capture")."""
    capture_genuine: str = "ideal"
    """Camera profile of the held-out genuine query frames (``split.json`` ``query``, close-ups included)."""
    capture_attacker: str = "ideal"
    """Camera profile of the attacker's orbit photos."""
    light_map: str = "same"
    """Light of the mapping walk-through: ``same`` (the stage's lights) or ``varied`` (a lighting condition drawn
    per sequence: lamps, daylight, colour temperature; :mod:`synthleak.render.light_conditions`)."""
    light_genuine: str = "same"
    """Light of the held-out genuine query frames (its own condition when ``varied``)."""
    light_attacker: str = "same"
    """Light of the attacker's orbit photos (its own condition when ``varied``)."""
    notes: str = ""

    @property
    def captures(self) -> dict[str, str]:
        """The camera profile of each kind of capture: ``map``, ``genuine``, ``attacker``."""
        return {"map": self.capture_map, "genuine": self.capture_genuine, "attacker": self.capture_attacker}

    @property
    def photographed(self) -> bool:
        """True when any kind of capture goes through a camera profile other than ``ideal``."""
        return any(profile != "ideal" for profile in self.captures.values())


@dataclass(frozen=True)
class LocalizeConfig:
    """Localization server: feature tiers, retrieval, PnP."""

    RULES: ClassVar[dict[str, Rule]] = {
        "tiers": each(one_of(_tiers), nonempty=True),
        "profile": one_or_each(one_of(_profiles)),
        "representation": one_or_each(one_of(_representations)),
        "servers": each(anything),
        "retrieval": one_of(_retrieval_methods),
        "top_k": COUNT,
        "bow_branching": at_least(2),
        "bow_depth": COUNT,
        "max_keypoints": COUNT,
        "pnp_max_error_px": at_least(0.0),
        "pnp_solver": one_of(_pnp_solvers),
        "min_inliers": at_least(0),
        "pairs_per_image": COUNT,
        "two_view_min_inliers": at_least(0),
    }
    """A rule per field, checked when the config loads."""
    KEY_DEFAULTS: ClassVar[dict[str, Any]] = {"profile": "strict", "representation": "points", "servers": [],
                                              "two_view_min_inliers": 0, "pnp_solver": "colmap"}
    """Fields added after content keys were in use: :func:`config_to_dict` leaves them out at these values, so a
    config that does not change them keeps its keys (and its cached maps, queries and report)."""


    tiers: list[str] = field(default_factory=lambda: ["sift"])
    profile: str | list[str] = "strict"
    """Server profile: ``strict`` (each tier's own thresholds: stricter than published defaults for the learned
    tiers) or ``hloc`` (HLoc's defaults for each tier: matcher checks, LightGlue's 0.1, 12 px PnP, a pose from 3
    inliers); :data:`synthleak.localize.tiers.PROFILES`, ``docs/learned-tiers.md``. Maps record it. A list
    (``["strict", "hloc"]``) runs a server per tier and profile on the same query features; a server under a
    profile other than ``strict`` is named ``<tier>@<profile>`` (:mod:`synthleak.localize.servers`)."""
    representation: str | list[str] = "points"
    """What a map stores: ``points`` (3D points, PnP), ``line-cloud`` (a random 3D line through each point, never
    the point; Speciale et al. CVPR 2019) or ``paired-point`` (a 3D line through each random pair of points; Lee et
    al. CVPR 2023); :data:`synthleak.localize.representations.REPRESENTATIONS`. Maps record
    it. A list runs a server per tier and representation; one over a map other than ``points`` is named
    ``<tier>+<representation>`` (:mod:`synthleak.localize.servers`)."""
    servers: list[str] = field(default_factory=list)
    """The servers of ``tiers`` x ``profile`` x ``representation`` a study runs, by name (``["sift", "xfeat",
    "sift@hloc", "xfeat@hloc"]``); empty (the default): every one. HLoc has no ORB or AKAZE configuration, and a
    HLoc-profile server with mutual-NN matching costs several times a strict one (thousands of matches through
    10,000 RANSAC trials), so a small study can run the paper's server for the tiers the paper ran only."""
    retrieval: str = "bow"
    """``bow`` (vocabulary-tree bag of words, then the ``top_k`` map images) or ``exhaustive`` (every map image);
    docs/retrieval.md has the measured recall against exhaustive matching and the cost per query."""
    top_k: int = 40
    bow_branching: int = 64
    """Bag-of-words vocabulary tree: children per node ..."""
    bow_depth: int = 2
    """... and levels: up to ``bow_branching ** bow_depth`` words (see :mod:`synthleak.localize.retrieval`)."""
    max_keypoints: int = 4096
    pnp_max_error_px: float = 0.0
    """RANSAC PnP threshold in pixels; 0: the tier's own (12 px for every built-in tier, HLoc's default). A server
    profile that sets it (``hloc``: 12 px) keeps its own (:func:`synthleak.localize.tiers.profile_fixes`)."""
    pnp_solver: str = "colmap"
    """Whose RANSAC PnP a point server runs, under COLMAP's stopping rule and trial cap either way
    (:mod:`synthleak.localize.pnp`): ``colmap`` (the default: pycolmap's ``estimate_and_refine_absolute_pose``,
    HLoc's own call) or ``poselib`` (about half the cost per query; its local optimisation finds fewer inliers on
    some queries near the bar, so it accepts slightly fewer: ``benchmarks/pnp.py`` measures both)."""
    min_inliers: int = 0
    """0: the tier's own default; a profile that sets it (``hloc``: 3) keeps its own."""
    pairs_per_image: int = 10
    two_view_min_inliers: int = 0
    """0: off. Otherwise a server keeps of each (query, map image) pair's matches only the inliers of an essential
    matrix (LO-RANSAC, the PnP threshold in pixels), from pairs with at least this many (COLMAP's two-view
    default: 15), before PnP or the line solver (:mod:`synthleak.localize.two_view`); every server of the study,
    points and lines alike. The success count stays computed on the matches before it. A query of another place
    then reaches a line server's p6L RANSAC rarely (``docs/map-representations.md``, "Cost")."""

    def check_fields(self, where: str) -> None:
        """``servers`` names servers of this config's tiers, profiles and representations, each once."""
        if not self.servers:
            return
        from synthleak.localize.servers import study_servers

        known = [server.name for server in study_servers(dataclasses.replace(self, servers=[]))]
        for name in self.servers:
            if name not in known:
                raise ConfigError(f"{where}servers: {name!r} is not a server of tiers x profile x representation "
                                  f"(known: {', '.join(known)})")
        if len(set(self.servers)) != len(self.servers):
            raise ConfigError(f"{where}servers: a server is named twice in {self.servers!r}")


@dataclass(frozen=True)
class AttackConfig:
    """Attacker: local model source, aligners, Alg. 1 thresholds (degrees, metres)."""

    RULES: ClassVar[dict[str, Rule]] = {
        "local_model": one_of(_study_option("LOCAL_MODELS")),
        "aligners": each(one_of(_aligners), nonempty=True),
        "thresholds": each(each(POSITIVE), nonempty=True),
        "queries_per_object": at_least(0),
        "presence": one_of(_presence_rules),
    }
    """A rule per field, checked when the config loads."""


    local_model: str = "oracle"
    aligners: list[str] = field(default_factory=lambda: ["alg1", "robust", "pivot"])
    thresholds: list[tuple[float, float]] = field(
        default_factory=lambda: [(10.0, 0.25), (30.0, 0.5), (60.0, 2.0)]
    )
    queries_per_object: int = 0
    """0: every attacker frame is sent."""
    presence: str = "eps"
    """The ``decision`` column: the paper's ε rule (``eps``) or the attacker-side classifier (``classifier``);
    results carry both."""


@dataclass(frozen=True)
class DefenseConfig:
    """Query defense (paper Sec. 6) and its offline sweep grid."""

    RULES: ClassVar[dict[str, Rule]] = {
        "enabled": anything,
        "min_fraction": within(0.0, 1.0, low_open=True),
        "min_instances": COUNT,
        "sweep_fractions": each(within(0.0, 1.0, low_open=True)),
        "sweep_min_instances": each(COUNT),
    }
    """A rule per field, checked when the config loads."""


    enabled: bool = False
    min_fraction: float = 0.1
    min_instances: int = 3
    sweep_fractions: list[float] = field(default_factory=lambda: [0.05, 0.1, 0.2, 0.3])
    sweep_min_instances: list[int] = field(default_factory=lambda: [1, 2, 3, 4, 5, 6])


@dataclass(frozen=True)
class SweepConfig:
    """Sweeps (each empty: not swept): leakage against attacker variant magnitude (attackers re-rendered only),
    and against the hard-world knobs ``material_sharing`` and ``clutter`` (a whole study per value)."""

    RULES: ClassVar[dict[str, Rule]] = {
        "magnitudes": each(at_least(0.0)),
        "kinds": each(one_of(_study_option("SWEEP_KINDS"))),
        "material_sharing": each(within(0.0, 1.0)),
        "clutter": each(at_least(0.0)),
    }
    """A rule per field, checked when the config loads."""


    magnitudes: list[float] = field(default_factory=list)
    kinds: list[str] = field(default_factory=lambda: ["all"])
    material_sharing: list[float] = field(default_factory=list)
    clutter: list[float] = field(default_factory=list)


@dataclass(frozen=True)
class StudyConfig:
    """One study, from stages to report."""

    RULES: ClassVar[dict[str, Rule]] = {
        "name": anything,
        "seed": at_least(0),
        "description": anything,
    }
    """A rule per field, checked when the config loads."""


    name: str
    seed: int = 0
    description: str = ""
    scenes: ScenesConfig = field(default_factory=ScenesConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    localize: LocalizeConfig = field(default_factory=LocalizeConfig)
    attack: AttackConfig = field(default_factory=AttackConfig)
    defense: DefenseConfig = field(default_factory=DefenseConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)


SECTIONS: dict[str, type] = {
    "scenes": ScenesConfig,
    "render": RenderConfig,
    "localize": LocalizeConfig,
    "attack": AttackConfig,
    "defense": DefenseConfig,
    "sweep": SweepConfig,
}
"""The tables of a config file and their classes."""


def resolve_config_path(name_or_path: str | Path) -> Path:
    """A config file path from a path or a bare name of ``render_configs/`` (``ci-tiny``)."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    candidate = render_configs_dir() / f"{path.name.removesuffix('.toml')}.toml"
    if candidate.is_file():
        return candidate
    raise ConfigError(f"{name_or_path}: no such config file (looked in {render_configs_dir()})")


def _parent_path(parent: str, path: Path) -> Path:
    """The file ``extends = parent`` in ``path`` means: beside ``path`` first, then in ``render_configs/``."""
    name = parent if parent.endswith(".toml") else f"{parent}.toml"
    for candidate in (path.parent / name, render_configs_dir() / Path(name).name):
        if candidate.is_file() and candidate.resolve() != path.resolve():  # a file may extend its namesake
            return candidate
    raise ConfigError(f"{path}: extends: no config {parent!r} (looked in {path.parent} and {render_configs_dir()})")


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path.resolve() in seen:
        raise ConfigError(f"{path}: 'extends' cycle through {[str(p) for p in seen]}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    if not data:
        raise ConfigError(f"{path}: the config file is empty (start from `extends = \"study\"` or a copy of "
                          f"{render_configs_dir() / 'ci-tiny.toml'})")
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: extends: must be a config name (str)")
    return _deep_merge(_read_toml(_parent_path(parent, path), (*seen, path.resolve())), data)


def _deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(merged.get(key), dict):
            merged[key] = _deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def config_from_dict(data: dict[str, Any], source: str = "<dict>") -> StudyConfig:
    """Validate a plain dict (as read from TOML) into a :class:`StudyConfig`."""
    data = dict(data)
    data.setdefault("name", Path(source).stem)
    return from_table(StudyConfig, data, f"{source}: ")


def check_config(config: StudyConfig, source: str = "<config>") -> StudyConfig:
    """Check every rule of ``config`` (one built in Python, e.g. with ``dataclasses.replace``); returns it."""
    for cls, value, where in [(StudyConfig, config, f"{source}: ")] + [
        (cls, getattr(config, name), f"{source}: {name}.") for name, cls in SECTIONS.items()
    ]:
        for key, rule in cls.RULES.items():
            rule(getattr(value, key), f"{where}{key}")
        if hasattr(value, "check_fields"):
            value.check_fields(where)
    return config


def load_config(name_or_path: str | Path) -> StudyConfig:
    """Load and validate a study config by path or by name in ``render_configs/``."""
    path = resolve_config_path(name_or_path)
    return config_from_dict(_read_toml(path), str(path))


def config_to_dict(config: Any) -> dict[str, Any]:
    """Plain-data form of a config or of one of its sections (tuples become lists), for manifests and cache keys.
    A class's ``KEY_DEFAULTS`` fields are left out at their default value (:func:`config_from_dict` reads them
    back as the default)."""
    _omit = object()

    def plain(value: Any) -> Any:
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            defaults = getattr(value, "KEY_DEFAULTS", {})
            return {f.name: plain(v) for f in dataclasses.fields(value)
                    if (v := getattr(value, f.name)) != defaults.get(f.name, _omit)}
        if isinstance(value, tuple | list):
            return [plain(v) for v in value]
        if isinstance(value, dict):
            return {k: plain(v) for k, v in value.items()}
        return value

    return plain(config)


# ------------------------------------------------------------------------------------------------- presets
@dataclass(frozen=True)
class PresetCost:
    """A preset's measured cost: one entry of ``docs/results/index.json``'s ``presets``."""

    wall_s: float
    """Wall time of the whole study (seconds)."""
    cores: int | None = None
    cpu: str = ""
    commit: str = ""
    page: str = ""
    """The results page, relative to the repository root."""
    config_key: str = ""
    """The content key of the config the run was made with ('' in entries written before keys were recorded)."""
    stale: bool = False
    """The preset's config has changed since (its content key differs): the figure is of an earlier config."""
    from_empty: bool = True
    """The recorded invocations started from an empty folder; False: some stages were made by an unrecorded
    run, so :attr:`wall_s` is less than the cost from scratch."""

    def __str__(self) -> str:
        """``11.8 min (2 cores)``; ``>=`` before it when not :attr:`from_empty`, ``an earlier config`` after it
        when :attr:`stale`."""
        return ("" if self.from_empty else ">= ") + self._wall() + (", an earlier config" if self.stale else "")

    def _wall(self) -> str:
        if self.wall_s < 60:
            wall = f"{self.wall_s:.0f} s"
        elif self.wall_s < 7200:
            wall = f"{self.wall_s / 60:.1f} min"
        else:
            wall = f"{self.wall_s / 3600:.1f} h"
        if self.cores is None:
            return wall
        return f"{wall} ({self.cores} core{'' if self.cores == 1 else 's'})"


@dataclass(frozen=True)
class Preset:
    """One config of ``render_configs/``, as ``synthleak presets`` lists it."""

    name: str
    """The name ``load_config`` and the CLI take (the file's stem)."""
    path: Path
    extends: str | None
    """The config it extends directly (None: none)."""
    description: str
    renderer: str | None
    tiers: list[str]
    cost: PresetCost | None
    """Measured cost (None: not measured)."""
    error: str | None = None
    """Why the config does not load (one line); ``renderer`` and ``tiers`` are then unknown."""


def load_costs(index: Path) -> dict[str, PresetCost]:
    """The measured costs of ``index`` (``{"presets": {name: {"wall_s": ..., "cores": ..., ...}}}``) by preset
    name; empty if the file does not exist. Unknown keys are ignored; raises :class:`ConfigError` naming the file
    for a file that is not such JSON."""
    try:
        data = json.loads(index.read_text())
    except FileNotFoundError:
        return {}
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{index}: not valid JSON: {exc}") from exc
    presets = data.get("presets", {}) if isinstance(data, dict) else None
    if not isinstance(presets, dict):
        raise ConfigError(f"{index}: presets: must be an object of preset names")
    costs = {}
    for name, entry in presets.items():
        where = f"{index}: presets.{name}"
        if not isinstance(entry, dict):
            raise ConfigError(f"{where}: must be an object")
        wall_s, cores = entry.get("wall_s"), entry.get("cores")
        if isinstance(wall_s, bool) or not isinstance(wall_s, int | float) or wall_s < 0:
            raise ConfigError(f"{where}.wall_s: must be a number of seconds >= 0, got {wall_s!r}")
        if cores is not None and (isinstance(cores, bool) or not isinstance(cores, int) or cores < 1):
            raise ConfigError(f"{where}.cores: must be an integer >= 1, got {cores!r}")
        text = {k: str(entry.get(k) or "") for k in ("cpu", "commit", "page", "config_key")}
        if not text["config_key"] and text["page"]:  # entries before keys were recorded: the page's summary has it
            summary = index.parent.parent.parent / Path(text["page"]).with_suffix(".json")
            with contextlib.suppress(OSError, json.JSONDecodeError, AttributeError):
                text["config_key"] = str(json.loads(summary.read_text()).get("config_key") or "")
        from_empty = entry.get("from_empty", True)
        if not isinstance(from_empty, bool):
            raise ConfigError(f"{where}.from_empty: must be true or false, got {from_empty!r}")
        costs[name] = PresetCost(wall_s=float(wall_s), cores=cores, from_empty=from_empty, **text)
    return costs


def list_presets(index: Path | None = None, folder: Path | None = None) -> list[Preset]:
    """Every config of ``folder`` (default: ``render_configs/``) by name, each loaded with :func:`load_config`:
    one that does not load is listed with its ``error``. Costs come from ``index`` (default:
    :func:`synthleak.paths.results_index_path`; a missing file: no costs), by file name or the config's ``name``."""
    folder = folder if folder is not None else render_configs_dir()
    costs = load_costs(index if index is not None else results_index_path())
    presets = []
    for path in sorted(folder.glob("*.toml"), key=lambda p: p.stem):
        try:
            raw = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError):
            raw = {}  # load_config says why below
        extends, description = raw.get("extends"), raw.get("description", "")
        common = {"name": path.stem, "path": path, "extends": extends if isinstance(extends, str) else None,
                  "cost": costs.get(path.stem)}
        try:
            config = load_config(path)
        except (SynthleakError, ValueError, OSError) as exc:
            presets.append(Preset(**common, description=description if isinstance(description, str) else "",
                                  renderer=None, tiers=[], error=" ".join(str(exc).split())))
            continue
        common["cost"] = common["cost"] or costs.get(config.name)  # the index may name it by its `name` key
        if common["cost"] is not None:  # a run of another config than today's: say so
            from synthleak.provenance import config_key

            key = common["cost"].config_key
            common["cost"] = dataclasses.replace(common["cost"], stale=bool(key) and key != config_key(config))
        presets.append(Preset(**common, description=config.description, renderer=config.render.renderer,
                              tiers=list(config.localize.tiers)))
    return presets
