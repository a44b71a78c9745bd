"""Axis-aligned textured boxes for shell pieces, with planar UVs shared across the boxes of one piece.

A wall with an opening is several boxes; mapping every face by its position in a common rectangle (instead
of [0, 1] per face) keeps the wall texture continuous around the opening.
"""

from __future__ import annotations

import numpy as np

from synthleak.assets.mesh import TexturedPart

# For a face whose normal is along axis a, the (u, v) axes of the planar projection.
_UV_AXES = {0: (1, 2), 1: (0, 2), 2: (0, 1)}


def planar_box(
    name: str,
    lo: np.ndarray,
    hi: np.ndarray,
    texture: np.ndarray,
    uv_lo: np.ndarray,
    uv_hi: np.ndarray,
    *,
    roughness: float = 0.8,
    metallic: float = 0.0,
) -> TexturedPart:
    """Box ``[lo, hi]`` (object frame) with 24 vertices / 12 outward CCW triangles.

    Each face's UV is its position within the box ``[uv_lo, uv_hi]`` projected on the face plane (clipped
    to [0, 1]), so boxes built with the same ``uv_lo/uv_hi`` share one continuous texture mapping.
    """
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    if np.any(hi - lo <= 0):
        raise ValueError(f"box {name!r}: field 'hi' must exceed 'lo' on every axis, got {lo} .. {hi}")
    uv_lo, uv_span = np.asarray(uv_lo, dtype=np.float64), np.asarray(uv_hi, dtype=np.float64) - uv_lo
    verts, uvs, faces = [], [], []
    for axis in range(3):
        ua, va = _UV_AXES[axis]
        for side, value in ((-1, lo[axis]), (1, hi[axis])):
            corners = []
            for cu, cv in ((0, 0), (1, 0), (1, 1), (0, 1)):
                p = np.empty(3)
                p[axis] = value
                p[ua] = (lo, hi)[cu][ua]
                p[va] = (lo, hi)[cv][va]
                corners.append(p)
            corners = np.array(corners)
            normal = np.cross(corners[1] - corners[0], corners[2] - corners[0])
            order = [0, 1, 2, 3] if normal[axis] * side > 0 else [0, 3, 2, 1]
            corners = corners[order]
            base = len(verts) * 4
            verts.append(corners)
            uv = np.stack(
                [(corners[:, ua] - uv_lo[ua]) / uv_span[ua], (corners[:, va] - uv_lo[va]) / uv_span[va]],
                axis=1,
            )
            uvs.append(np.clip(uv, 0.0, 1.0))
            faces.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
    return TexturedPart(
        name=name,
        vertices=np.concatenate(verts),
        faces=np.asarray(faces, dtype=np.int64),
        uv=np.concatenate(uvs),
        texture=texture,
        roughness=roughness,
        metallic=metallic,
    )


def box_with_holes(
    name: str,
    length: float,
    thickness: float,
    height: float,
    holes: list[tuple[float, float, float, float]],
    texture: np.ndarray,
    *,
    x_extra: float = 0.0,
    roughness: float = 0.8,
) -> TexturedPart:
    """A wall slab ``x in [-length/2 - x_extra, length/2 + x_extra]``, ``y in [-t/2, t/2]``, ``z in [0, h]``
    with rectangular through-holes ``(x0, x1, z0, z1)`` (non-overlapping), built from boxes.

    The slab is cut into vertical strips at the hole edges; each strip is split around the holes it spans;
    the boxes are merged into one part.
    """
    x_min, x_max = -length / 2 - x_extra, length / 2 + x_extra
    uv_lo = np.array([x_min, -thickness / 2, 0.0])
    uv_hi = np.array([x_max, thickness / 2, height])
    cuts = sorted({x_min, x_max, *[h[0] for h in holes], *[h[1] for h in holes]})
    parts: list[TexturedPart] = []
    for x0, x1 in zip(cuts[:-1], cuts[1:], strict=True):
        if x1 - x0 < 1e-9:
            continue
        xc = 0.5 * (x0 + x1)
        spans = sorted((h[2], h[3]) for h in holes if h[0] <= xc <= h[1])
        z = 0.0
        for z0, z1 in [*spans, (height, height)]:
            if z0 - z > 1e-9:
                parts.append(
                    planar_box(
                        f"{name}_{len(parts)}",
                        [x0, -thickness / 2, z],
                        [x1, thickness / 2, z0],
                        texture,
                        uv_lo,
                        uv_hi,
                        roughness=roughness,
                    )
                )
            z = max(z, z1)
    return merge_parts(name, parts)


def merge_parts(name: str, parts: list[TexturedPart]) -> TexturedPart:
    """Concatenate parts that share one texture and material into a single part."""
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    return TexturedPart(
        name=name,
        vertices=np.concatenate([p.vertices for p in parts]),
        faces=np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)]),
        uv=np.concatenate([p.uv for p in parts]),
        texture=parts[0].texture,
        roughness=parts[0].roughness,
        metallic=parts[0].metallic,
        emissive=parts[0].emissive,
    )
