"""The parametric builders: :class:`BuilderSpec` (a :class:`~synthleak.assets.model.ModelBuilder` reading the
model TOML as a :class:`ParametricTable`), the :func:`builder` decorator that registers them, and the
:class:`PartBuilder` drawing context they use.

A parametric builder is a function ``fn(b: PartBuilder, p: dict[str, float]) -> None`` registered with
:func:`builder`. ``p`` holds ``width``, ``depth``, ``height`` (the model's declared ``size``) plus every shape
parameter. Rule for all builders: the built bounding box is exactly ``width x depth x height`` whatever the
shape parameters (they change proportions inside it: seat height vs backrest, number of shelves, leg
thickness...); per-axis size changes are the variant's *scale*. ``b`` draws primitives into named *materials*
(the model's ``[textures.*]`` entries: one textured part per material) and records support surfaces.
After the builder returns, the mesh is re-centred to the canonical frame (bottom centre of the bounding box
at the origin) and the support surfaces with it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from synthleak.assets import primitives as prim
from synthleak.assets.materials import get_sku
from synthleak.assets.mesh import ObjectMesh, SupportSurface, TexturedPart
from synthleak.assets.model import (
    BUILDERS,
    PROPS_DIR,
    ROLES,
    TEXTURE_SEED,
    MaterialSpec,
    ModelBuilder,
    ModelTable,
    ObjectModel,
    ParamRange,
    register_builder,
    toml_error,
)
from synthleak.assets.textures import make_texture
from synthleak.errors import UnknownNameError
from synthleak.schema import Rule, from_table, one_of, within
from synthleak.seeding import make_rng

__all__ = ["BUILDERS", "BuilderSpec", "MaterialSlot", "ParametricTable", "PartBuilder", "SupportSurface", "builder"]


@dataclass(frozen=True, kw_only=True)
class ParametricTable(ModelTable):
    """The TOML of a parametric model (schema in ``object_library/README.md``)."""

    RULES: ClassVar[dict[str, Rule]] = {
        **ModelTable.RULES,
        "role": one_of(ROLES),
        "texture_size": within(64, 1024),
    }

    role: str = "furniture"
    texture_size: int = 512
    params: dict[str, ParamRange] = field(default_factory=dict)
    textures: dict[str, MaterialSpec]


@dataclass(frozen=True)
class BuilderSpec(ModelBuilder):
    """A parametric builder: ``fn`` draws the model (see the module docstring) with procedural textures."""

    name: str
    fn: Callable[[PartBuilder, dict[str, float]], None]
    materials: tuple[str, ...]
    """Material slots the builder draws into; the model's textures must define all of them."""
    params: dict[str, float | None]
    """Shape parameters the builder reads: name -> builder default (None: the model must declare it)."""
    optional_materials: tuple[str, ...] = ()

    def parse(self, path: Path, data: dict[str, Any]) -> ObjectModel:
        t: ParametricTable = from_table(ParametricTable, data, f"{path}: ")
        if path.parent.name == PROPS_DIR and t.role != "prop":
            raise toml_error(path, "role", f'a model in {PROPS_DIR}/ must declare role = "prop" (got {t.role!r})')
        for name, r in t.params.items():
            key = f"params.{name}"
            if name not in self.params:
                raise toml_error(
                    path, key, f"builder {self.name!r} has no such parameter (it reads {sorted(self.params)})"
                )
            if not r.min <= r.default <= r.max:
                raise toml_error(path, key, f"need min <= default <= max, got {r}")
            if r.integer and any(v != round(v) for v in (r.default, r.min, r.max)):
                raise toml_error(path, key, "an integer parameter needs integer default/min/max")
        missing = [k for k, v in self.params.items() if v is None and k not in t.params]
        if missing:
            raise toml_error(path, f"params.{missing[0]}", f"builder {self.name!r} needs it declared")
        for mat in self.materials:
            if mat not in t.textures:
                raise toml_error(
                    path, f"textures.{mat}", f"builder {self.name!r} draws into material {mat!r}: define it"
                )
        for mat, spec in t.textures.items():
            if mat not in self.materials and mat not in self.optional_materials:
                raise toml_error(path, f"textures.{mat}", f"builder {self.name!r} does not use this material "
                                 f"(it uses {list(self.materials) + list(self.optional_materials)})")
            if spec.sku is not None:
                raise toml_error(path, f"textures.{mat}.sku", "a slot's shared SKU is drawn by the study "
                                 "([scenes] material_sharing), not set in the model")
        return ObjectModel(
            model_id=t.id,
            category=t.category,
            builder=t.builder,
            symmetry=t.symmetry,
            support=t.support,
            size=t.size,
            params=t.params,
            scale_range=t.scale_range,
            textures=t.textures,
            source=str(path),
            colour_range=t.colour_range,
            description=t.description,
            texture_size=t.texture_size,
            role=t.role,
        )

    def build(
        self, model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
    ) -> tuple[ObjectMesh, list[SupportSurface]]:
        p: dict[str, float] = {k: float(v) for k, v in self.params.items() if v is not None}
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
            tex = textures[mat] if textures is not None and mat in textures else self.texture(model, mat)
            slots[mat] = MaterialSlot(
                texture=np.array(tex),
                texel_scale=float(m.texel_scale),
                roughness=float(m.roughness),
                metallic=float(m.metallic),
                emissive=m.emissive,
            )
        b = PartBuilder(materials=slots, rng=make_rng(TEXTURE_SEED, "builder", model.model_id))
        self.fn(b, p)
        return b.finish()

    def texture(self, model: ObjectModel, material: str) -> np.ndarray:
        """The slot's shared SKU texture, or its own: ``make_texture`` from ``make_rng(0, "texture", model_id,
        material)`` (cached, read-only)."""
        spec = model.textures[material]
        if spec.sku:
            return get_sku(spec.sku).texture()
        return _cached_texture(
            model.model_id, material, spec.kind, spec.colour, spec.colour2, spec.feature_scale, model.texture_size
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


def builder(
    name: str,
    materials: Sequence[str],
    params: dict[str, float | None] | Sequence[str] = (),
    optional_materials: Sequence[str] = (),
):
    """Register a parametric builder under ``name``."""
    pdict = dict(params) if isinstance(params, dict) else dict.fromkeys(params)

    def deco(fn):
        register_builder(BuilderSpec(name, fn, tuple(materials), pdict, tuple(optional_materials)))
        return fn

    return deco


@dataclass
class MaterialSlot:
    texture: np.ndarray
    texel_scale: float = 1.0
    roughness: float = 0.6
    metallic: float = 0.0
    emissive: tuple[float, float, float] | None = None


@dataclass
class PartBuilder:
    """Collects primitives per material for one build. ``rng`` is a per-model Generator (stable across
    builds and variants of a model) for builders that scatter things (leaves, books)."""

    materials: dict[str, MaterialSlot]
    rng: np.random.Generator
    parts: dict[str, list[TexturedPart]] = field(default_factory=dict)
    surfaces: list[SupportSurface] = field(default_factory=list)
    _count: int = 0

    def has(self, mat: str) -> bool:
        return mat in self.materials

    def _slot(self, mat: str) -> MaterialSlot:
        if mat not in self.materials:
            raise KeyError(f"builder draws into material {mat!r}, which the model does not define")
        return self.materials[mat]

    def _add(self, mat: str, part: TexturedPart) -> TexturedPart:
        self.parts.setdefault(mat, []).append(part)
        return part

    def _name(self, mat: str) -> str:
        self._count += 1
        return f"{mat}/{self._count}"

    def _kw(self, mat: str, kw: dict[str, Any]) -> dict[str, Any]:
        s = self._slot(mat)
        kw.setdefault("texel_scale", s.texel_scale)
        kw.setdefault("roughness", s.roughness)
        kw.setdefault("metallic", s.metallic)
        return kw

    # primitives: same arguments as synthleak.assets.primitives minus name/texture
    def box(self, mat: str, extents, centre, **kw) -> TexturedPart:
        return self._add(
            mat, prim.box(self._name(mat), extents, centre, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def box_span(self, mat: str, lo, hi, **kw) -> TexturedPart:
        """A box from its min corner ``lo`` to its max corner ``hi``."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        return self.box(mat, hi - lo, 0.5 * (lo + hi), **kw)

    def hexahedron(self, mat: str, corners, **kw) -> TexturedPart:
        return self._add(
            mat, prim.hexahedron(self._name(mat), corners, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def tapered_box(self, mat: str, bottom, top, height, bottom_centre, **kw) -> TexturedPart:
        return self._add(
            mat,
            prim.tapered_box(
                self._name(mat),
                bottom,
                top,
                height,
                bottom_centre,
                self._slot(mat).texture,
                **self._kw(mat, kw),
            ),
        )

    def cylinder(self, mat: str, radius, height, centre, **kw) -> TexturedPart:
        return self._add(
            mat,
            prim.cylinder(
                self._name(mat), radius, height, centre, self._slot(mat).texture, **self._kw(mat, kw)
            ),
        )

    def bar(self, mat: str, p0, p1, radius, **kw) -> TexturedPart:
        return self._add(
            mat, prim.bar(self._name(mat), p0, p1, radius, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def leg(self, mat: str, foot, top, radius, **kw) -> TexturedPart:
        """A round bar standing on the plane z = foot[2]: the foot end is raised so the lowest point of its
        (tilted) end cap touches that plane (splayed legs never poke below the floor)."""
        foot, top = np.asarray(foot, float), np.asarray(top, float)
        d = top - foot
        sin_tilt = float(np.linalg.norm(d[:2]) / np.linalg.norm(d))
        lifted = foot + np.array([0.0, 0.0, radius * sin_tilt])
        return self.bar(mat, lifted, top, radius, **kw)

    def torus(self, mat: str, major, minor, centre, **kw) -> TexturedPart:
        return self._add(
            mat,
            prim.torus(self._name(mat), major, minor, centre, self._slot(mat).texture, **self._kw(mat, kw)),
        )

    def sphere(self, mat: str, radius, centre, **kw) -> TexturedPart:
        return self._add(
            mat, prim.sphere(self._name(mat), radius, centre, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def revolve(self, mat: str, profile, **kw) -> TexturedPart:
        return self._add(
            mat, prim.revolve(self._name(mat), profile, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def rounded_box(self, mat: str, extents, centre, radius, **kw) -> TexturedPart:
        return self._add(
            mat,
            prim.rounded_box(
                self._name(mat), extents, centre, radius, self._slot(mat).texture, **self._kw(mat, kw)
            ),
        )

    def extrude(self, mat: str, outline, thickness, **kw) -> TexturedPart:
        return self._add(
            mat,
            prim.extrude(self._name(mat), outline, thickness, self._slot(mat).texture, **self._kw(mat, kw)),
        )

    def tube(self, mat: str, path, radius, **kw) -> TexturedPart:
        return self._add(
            mat, prim.tube(self._name(mat), path, radius, self._slot(mat).texture, **self._kw(mat, kw))
        )

    def surface(self, z: float, x_min: float, x_max: float, y_min: float, y_max: float) -> None:
        """Record a horizontal support top (builder frame; shifted with the re-centring)."""
        self.surfaces.append(SupportSurface(float(z), float(x_min), float(x_max), float(y_min), float(y_max)))

    def finish(self) -> tuple[ObjectMesh, list[SupportSurface]]:
        out = []
        for mat in sorted(self.parts):
            part = prim.merge_parts(mat, self.parts[mat])
            part.emissive = self.materials[mat].emissive
            out.append(part)
        mesh = ObjectMesh(parts=out)
        lo, hi = mesh.bounds()
        shift = -np.array([0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), lo[2]])
        for p in mesh.parts:
            p.vertices = p.vertices + shift
        dx, dy, dz = (float(v) for v in shift)
        surfaces = [
            SupportSurface(s.z + dz, s.x_min + dx, s.x_max + dx, s.y_min + dy, s.y_max + dy)
            for s in self.surfaces
        ]
        return mesh, surfaces
