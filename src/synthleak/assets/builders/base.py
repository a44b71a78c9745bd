"""Builder registry and the :class:`PartBuilder` drawing context the parametric builders use.

A *builder* is a function ``fn(b: PartBuilder, p: dict[str, float]) -> None`` registered with
:func:`builder`. ``p`` holds ``width``, ``depth``, ``height`` (the model's declared ``size``) plus every shape
parameter. Rule for all builders: the built bounding box is exactly ``width x depth x height`` whatever the
shape parameters (they change proportions inside it: seat height vs backrest, number of shelves, leg
thickness...); per-axis size changes are the variant's *scale*. ``b`` draws primitives into named *materials*
(the model's ``[textures.*]`` entries: one textured part per material) and records support surfaces.
After the builder returns, the mesh is re-centred to the canonical frame (bottom centre of the bounding box
at the origin) and the support surfaces with it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from synthleak.assets import primitives as prim
from synthleak.assets.mesh import ObjectMesh, TexturedPart


@dataclass(frozen=True)
class SupportSurface:
    """A horizontal top (object frame, metres) on which small objects may stand: height ``z`` and its
    axis-aligned footprint."""

    z: float
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    def to_dict(self) -> dict[str, float]:
        return {
            "z": self.z,
            "x_min": self.x_min,
            "x_max": self.x_max,
            "y_min": self.y_min,
            "y_max": self.y_max,
        }

    def scaled(self, scale: Sequence[float]) -> SupportSurface:
        """The surface of the object scaled per axis about the canonical origin."""
        sx, sy, sz = (float(s) for s in scale)
        return SupportSurface(self.z * sz, self.x_min * sx, self.x_max * sx, self.y_min * sy, self.y_max * sy)


@dataclass(frozen=True)
class BuilderSpec:
    name: str
    fn: Callable[[PartBuilder, dict[str, float]], None]
    materials: tuple[str, ...]
    """Material slots the builder draws into; the model's textures must define all of them."""
    params: dict[str, float | None]
    """Shape parameters the builder reads: name -> builder default (None: the model must declare it)."""
    optional_materials: tuple[str, ...] = ()


BUILDERS: dict[str, BuilderSpec] = {}


def builder(
    name: str,
    materials: Sequence[str],
    params: dict[str, float | None] | Sequence[str] = (),
    optional_materials: Sequence[str] = (),
):
    """Register a parametric builder under ``name``."""
    pdict = dict(params) if isinstance(params, dict) else dict.fromkeys(params)

    def deco(fn):
        if name in BUILDERS:
            raise ValueError(f"builder {name!r} registered twice")
        BUILDERS[name] = BuilderSpec(name, fn, tuple(materials), pdict, tuple(optional_materials))
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
