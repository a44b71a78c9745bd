"""The object library: model definitions (``object_library/*.toml``, props in ``object_library/props/*.toml``)
and their parametric builds.

One TOML file per model (schema in ``object_library/README.md``)::

    id = "chair_ladderback"            # unique, [a-z0-9_]
    category = "chair"
    builder = "chair_ladderback"       # a registered builder (synthleak.assets.builders)
    symmetry = "none"                  # none | 2 | 4 | z  (2-/4-fold about +z, or continuous about z)
    support = "floor"                  # floor | wall | ceiling | surface
    role = "furniture"                 # optional: furniture (default) | prop (small clutter; props/*.toml)
    size = [0.46, 0.50, 0.92]          # full extents x, y, z in metres at default params
    scale_range = [0.9, 1.1]           # per-axis multiplicative scale range for variants
    colour_range = [0.08, 0.15, 0.15]  # optional: max |hue turns|, |saturation|, |value| shift
    description = "..."                # optional
    texture_size = 512                 # optional, 256..1024

    [params]
    seat_height = { default = 0.46, min = 0.42, max = 0.50 }
    n_slats = { default = 3, min = 2, max = 5, integer = true }

    [textures.frame]                   # one entry per material slot the builder draws
    kind = "wood"                      # synthleak.assets.textures.TEXTURE_KINDS
    colour = [0.55, 0.36, 0.20]
    colour2 = [0.3, 0.2, 0.1]          # optional; roughness, metallic, texel_scale (m per texture),
                                       # feature_scale, recolour (bool), emissive ([r, g, b]) optional

Textures of a model are deterministic: material ``m`` of model ``id`` uses
``make_rng(0, "texture", id, m)``; they are cached, so building a model repeatedly is cheap.
"""

from __future__ import annotations

import difflib
import functools
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.assets.builders import BUILDERS, PartBuilder, SupportSurface
from synthleak.assets.builders.base import MaterialSlot
from synthleak.assets.materials import get_sku
from synthleak.assets.mesh import ObjectMesh
from synthleak.assets.textures import TEXTURE_KINDS, make_texture
from synthleak.errors import UnknownNameError
from synthleak.paths import object_library_dir
from synthleak.seeding import make_rng

SYMMETRIES = ("none", "2", "4", "z")
SUPPORTS = ("floor", "wall", "ceiling", "surface")
ROLES = ("furniture", "prop")
"""``furniture``: the objects a study attacks and places as its scene objects; ``prop``: small clutter
(books, cushions, rugs, posters...) read from ``object_library/props/``."""
PROPS_DIR = "props"
TEXTURE_SEED = 0
"""Root seed of every model's textures (a model's look is fixed; variants recolour it)."""
_MATERIAL_KEYS = {
    "kind",
    "colour",
    "colour2",
    "roughness",
    "metallic",
    "texel_scale",
    "feature_scale",
    "recolour",
    "emissive",
}
_TOP_KEYS = {
    "id",
    "category",
    "builder",
    "symmetry",
    "support",
    "role",
    "size",
    "scale_range",
    "colour_range",
    "description",
    "texture_size",
    "params",
    "textures",
    "imported",
}


@dataclass(frozen=True)
class ParamRange:
    """A shape parameter: its default and the range variants may use (inclusive)."""

    default: float
    min: float
    max: float
    integer: bool = False

    def clip(self, value: float) -> float:
        v = float(np.clip(value, self.min, self.max))
        return float(round(v)) if self.integer else v


@dataclass(frozen=True)
class ObjectModel:
    """One model of the library (a parsed TOML file): a piece of furniture or a prop (``role``)."""

    model_id: str
    category: str
    builder: str
    symmetry: str
    support: str
    size: tuple[float, float, float]
    params: dict[str, ParamRange] = field(hash=False)
    scale_range: tuple[float, float]
    textures: dict[str, dict[str, Any]] = field(hash=False)
    source: str
    colour_range: tuple[float, float, float] = (0.08, 0.15, 0.15)
    description: str = ""
    texture_size: int = 512
    role: str = "furniture"

    def default_params(self) -> dict[str, float]:
        return {k: float(v.default) for k, v in self.params.items()}

    def build(self, params: dict[str, float] | None = None) -> ObjectMesh:
        """The textured mesh at ``params`` (defaults for missing / None), canonical frame, unscaled."""
        return build_model(self, params)[0]

    def material_texture(self, material: str) -> np.ndarray:
        """The (cached, read-only) base texture of one material slot (its shared SKU's, if it uses one)."""
        if self.builder == "imported":
            from synthleak.assets.import_store import imported_texture

            return imported_texture(self, material)
        spec = self.textures[material]
        if spec.get("sku"):
            return get_sku(spec["sku"]).texture()
        return _cached_texture(
            self.model_id,
            material,
            spec["kind"],
            tuple(spec["colour"]),
            tuple(spec["colour2"]) if spec.get("colour2") is not None else None,
            float(spec.get("feature_scale", 1.0)),
            int(self.texture_size),
        )


@functools.lru_cache(maxsize=512)
def _cached_texture(
    model_id: str,
    material: str,
    kind: str,
    colour: tuple,
    colour2: tuple | None,
    feature_scale: float,
    size: int,
) -> np.ndarray:
    tex = make_texture(
        kind,
        make_rng(TEXTURE_SEED, "texture", model_id, material),
        colour,
        size,
        colour2=colour2,
        feature_scale=feature_scale,
    )
    tex.flags.writeable = False
    return tex


def build_model(
    model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
) -> tuple[ObjectMesh, list[SupportSurface]]:
    """Build ``model`` at ``params`` -> (mesh in the canonical frame, support surfaces).

    ``textures`` optionally replaces material textures (variants pass recoloured ones)."""
    if model.builder == "imported":
        from synthleak.assets.import_store import build_imported

        return build_imported(model, params, textures), []
    spec = BUILDERS[model.builder]
    p: dict[str, float] = {k: float(v) for k, v in spec.params.items() if v is not None}
    p.update(model.default_params())
    for k, v in (params or {}).items():
        if k not in model.params:
            raise UnknownNameError(
                f"model {model.model_id!r} has no shape parameter {k!r}; it has {sorted(model.params)}"
            )
        if v is not None:
            p[k] = float(round(v)) if model.params[k].integer else float(v)
    p["width"], p["depth"], p["height"] = (float(s) for s in model.size)
    slots = {}
    for mat, m in model.textures.items():
        tex = textures[mat] if textures is not None and mat in textures else model.material_texture(mat)
        slots[mat] = MaterialSlot(
            texture=np.array(tex),
            texel_scale=float(m.get("texel_scale", 1.0)),
            roughness=float(m.get("roughness", 0.6)),
            metallic=float(m.get("metallic", 0.0)),
            emissive=tuple(m["emissive"]) if m.get("emissive") is not None else None,
        )
    b = PartBuilder(materials=slots, rng=make_rng(TEXTURE_SEED, "builder", model.model_id))
    spec.fn(b, p)
    return b.finish()


# ----------------------------------------------------------------------------------------------- loading
def _err(path: Path, key: str, msg: str) -> ValueError:
    return ValueError(f"{path}: key '{key}': {msg}")


def _floats(path: Path, key: str, value: Any, n: int) -> tuple[float, ...]:
    if (
        not isinstance(value, list | tuple)
        or len(value) != n
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise _err(path, key, f"expected a list of {n} numbers, got {value!r}")
    return tuple(float(v) for v in value)


def _parse_model(path: Path) -> ObjectModel:
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML: {e}") from e
    if data.get("builder") == "imported":
        from synthleak.assets.import_store import parse_imported_model

        return parse_imported_model(path, data)
    for k in data:
        if k not in _TOP_KEYS:
            raise _err(path, k, f"unknown key (known: {', '.join(sorted(_TOP_KEYS))})")
    for k in ("id", "category", "builder", "symmetry", "support", "size", "scale_range", "textures"):
        if k not in data:
            raise _err(path, k, "missing")
    for k in ("id", "category", "builder", "symmetry", "support"):
        if not isinstance(data[k], str):
            raise _err(path, k, f"expected a string, got {data[k]!r}")
    mid = data["id"]
    if not re.fullmatch(r"[a-z0-9_]+", mid):
        raise _err(path, "id", f"{mid!r} must match [a-z0-9_]+")
    if data["builder"] not in BUILDERS:
        close = difflib.get_close_matches(data["builder"], BUILDERS, n=3)
        raise _err(
            path,
            "builder",
            f"unknown builder {data['builder']!r} (close: {close}; known: {sorted(BUILDERS)})",
        )
    spec = BUILDERS[data["builder"]]
    if data["symmetry"] not in SYMMETRIES:
        raise _err(path, "symmetry", f"{data['symmetry']!r} not in {SYMMETRIES}")
    if data["support"] not in SUPPORTS:
        raise _err(path, "support", f"{data['support']!r} not in {SUPPORTS}")
    size = _floats(path, "size", data["size"], 3)
    if min(size) <= 0:
        raise _err(path, "size", "extents must be positive")
    scale_range = _floats(path, "scale_range", data["scale_range"], 2)
    if not 0 < scale_range[0] <= 1.0 <= scale_range[1]:
        raise _err(path, "scale_range", f"need 0 < min <= 1 <= max, got {scale_range}")
    colour_range = _floats(path, "colour_range", data.get("colour_range", [0.08, 0.15, 0.15]), 3)
    if min(colour_range) < 0 or colour_range[0] > 0.5 or max(colour_range[1:]) > 1:
        raise _err(path, "colour_range", "need 0 <= hue <= 0.5 and 0 <= saturation, value <= 1")
    role = data.get("role", "furniture")
    if role not in ROLES:
        raise _err(path, "role", f"{role!r} not in {ROLES}")
    if path.parent.name == PROPS_DIR and role != "prop":
        raise _err(path, "role", f'a model in {PROPS_DIR}/ must declare role = "prop" (got {role!r})')
    texture_size = data.get("texture_size", 512)
    if not isinstance(texture_size, int) or not 64 <= texture_size <= 1024:
        raise _err(path, "texture_size", f"expected an integer in [64, 1024], got {texture_size!r}")
    # params
    raw_params = data.get("params", {})
    if not isinstance(raw_params, dict):
        raise _err(path, "params", "expected a table")
    params: dict[str, ParamRange] = {}
    for name, pr in raw_params.items():
        key = f"params.{name}"
        if name not in spec.params:
            raise _err(
                path, key, f"builder {spec.name!r} has no such parameter (it reads {sorted(spec.params)})"
            )
        if (
            not isinstance(pr, dict)
            or not {"default", "min", "max"} <= set(pr)
            or set(pr) - {"default", "min", "max", "integer"}
        ):
            raise _err(path, key, "expected { default = .., min = .., max = .., integer = false }")
        for k in ("default", "min", "max"):
            if not isinstance(pr[k], int | float) or isinstance(pr[k], bool):
                raise _err(path, f"{key}.{k}", f"expected a number, got {pr[k]!r}")
        integer = pr.get("integer", False)
        if not isinstance(integer, bool):
            raise _err(path, f"{key}.integer", "expected true or false")
        r = ParamRange(float(pr["default"]), float(pr["min"]), float(pr["max"]), integer)
        if not r.min <= r.default <= r.max:
            raise _err(path, key, f"need min <= default <= max, got {r}")
        if integer and any(v != round(v) for v in (r.default, r.min, r.max)):
            raise _err(path, key, "an integer parameter needs integer default/min/max")
        params[name] = r
    missing = [k for k, v in spec.params.items() if v is None and k not in params]
    if missing:
        raise _err(path, f"params.{missing[0]}", f"builder {spec.name!r} needs it declared")
    # textures
    textures = data["textures"]
    if not isinstance(textures, dict):
        raise _err(path, "textures", "expected a table of materials")
    for mat in spec.materials:
        if mat not in textures:
            raise _err(
                path, f"textures.{mat}", f"builder {spec.name!r} draws into material {mat!r}: define it"
            )
    clean_textures: dict[str, dict[str, Any]] = {}
    for mat, m in textures.items():
        key = f"textures.{mat}"
        if mat not in spec.materials and mat not in spec.optional_materials:
            raise _err(
                path,
                key,
                f"builder {spec.name!r} does not use this material "
                f"(it uses {list(spec.materials) + list(spec.optional_materials)})",
            )
        if not isinstance(m, dict):
            raise _err(path, key, "expected a table")
        for k in m:
            if k not in _MATERIAL_KEYS:
                raise _err(path, f"{key}.{k}", f"unknown key (known: {', '.join(sorted(_MATERIAL_KEYS))})")
        if m.get("kind") not in TEXTURE_KINDS:
            raise _err(path, f"{key}.kind", f"{m.get('kind')!r} is not one of {TEXTURE_KINDS}")
        if "colour" not in m:
            raise _err(path, f"{key}.colour", "missing")
        mm = dict(m)
        for ck in ("colour", "colour2", "emissive"):
            if ck in m:
                col = _floats(path, f"{key}.{ck}", m[ck], 3)
                if ck != "emissive" and not all(0 <= c <= 1 for c in col):
                    raise _err(path, f"{key}.{ck}", "RGB components must be in [0, 1]")
                mm[ck] = list(col)
        for nk, lo, hi in (
            ("roughness", 0, 1),
            ("metallic", 0, 1),
            ("texel_scale", 0.05, 10),
            ("feature_scale", 0.1, 10),
        ):
            if nk in m and (not isinstance(m[nk], int | float) or not lo <= m[nk] <= hi):
                raise _err(path, f"{key}.{nk}", f"expected a number in [{lo}, {hi}], got {m[nk]!r}")
        if "recolour" in m and not isinstance(m["recolour"], bool):
            raise _err(path, f"{key}.recolour", "expected true or false")
        clean_textures[mat] = mm
    return ObjectModel(
        model_id=mid,
        category=data["category"],
        builder=data["builder"],
        symmetry=data["symmetry"],
        support=data["support"],
        size=size,
        params=params,
        scale_range=scale_range,  # type: ignore[arg-type]
        textures=clean_textures,
        source=str(path),
        colour_range=colour_range,  # type: ignore[arg-type]
        description=str(data.get("description", "")),
        texture_size=texture_size,
        role=role,
    )


def load_library(directory: Path | None = None) -> dict[str, ObjectModel]:
    """All models of ``directory`` (default: :func:`synthleak.paths.object_library_dir`): ``*.toml``,
    ``props/*.toml`` and ``imported/*/*.toml``, sorted by id (ids unique over all of them).

    A bad file raises ``ValueError`` naming the file and the key."""
    d = Path(directory) if directory is not None else object_library_dir()
    if not d.is_dir():
        raise FileNotFoundError(f"object library folder {d} does not exist")
    models: dict[str, ObjectModel] = {}
    paths = sorted(d.glob("*.toml")) + sorted(d.glob(f"{PROPS_DIR}/*.toml")) + sorted(d.glob("imported/*/*.toml"))
    for path in paths:
        m = _parse_model(path)
        if m.model_id in models:
            raise _err(path, "id", f"duplicate id {m.model_id!r} (also in {models[m.model_id].source})")
        models[m.model_id] = m
    return dict(sorted(models.items()))


def by_role(library: dict[str, ObjectModel], role: str) -> dict[str, ObjectModel]:
    """The models of ``library`` with ``role`` (``"furniture"`` or ``"prop"``), in the library's order."""
    if role not in ROLES:
        raise ValueError(f"role: {role!r} not in {ROLES}")
    return {k: m for k, m in library.items() if m.role == role}


@functools.lru_cache(maxsize=8)
def _default_library(directory: str) -> dict[str, ObjectModel]:
    return load_library(Path(directory))


def get_model(model_id: str, library: dict[str, ObjectModel] | None = None) -> ObjectModel:
    """One model of ``library`` (default: the default library, loaded once). Unknown id -> ``KeyError``
    listing close names."""
    lib = library if library is not None else _default_library(str(object_library_dir()))
    if model_id not in lib:
        close = difflib.get_close_matches(model_id, lib, n=5, cutoff=0.4)
        raise UnknownNameError(
            f"unknown model {model_id!r}; close: {close or 'none'} ({len(lib)} models in the library)"
        )
    return lib[model_id]
