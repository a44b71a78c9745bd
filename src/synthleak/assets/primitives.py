"""Closed, textured mesh primitives: boxes, tapered blocks, cylinders, bars, tori, spheres, lathe profiles,
swept tubes.

Every function returns a :class:`~synthleak.assets.mesh.TexturedPart` whose triangles are counter-clockwise
seen from outside (each primitive is a closed surface; its orientation is checked by its signed volume and
flipped if needed) and whose UVs lie in [0, 1].

UV layout ("chart tiling", the convention of the whole object library)
----------------------------------------------------------------------
The texture of a part stands for a square of ``texel_scale`` metres (default 1 m: a 512 px texture is
~2 mm per texel), so texture density is the same on every part in metres and patterns are never smeared.
Each primitive is cut into *charts* (a box face, the unrolled side of a cylinder, a cap disk, a lathe band)
with coordinates in metres. A chart larger than ``texel_scale`` is cut along its grid lines into blocks no
larger than ``texel_scale`` (vertices are duplicated along the cuts). Each block is placed into the texture
square at an offset derived from a hash of ``(part name, chart, block)`` so that different faces and legs show
different areas of the texture (less repetition for feature matching) and the placement is stable under
small shape changes. Wood grain runs along texture u (image rows); box faces orient u along the box's
longest axis. ``uv_mode="fit"`` instead stretches each chart over the whole texture (posters, clock dials).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence

import numpy as np

from synthleak.assets.mesh import TexturedPart

_UV_MARGIN = 1e-3


# ------------------------------------------------------------------------------------------ internal helpers
def _hash_fraction(*keys: object) -> tuple[float, float]:
    h = hashlib.sha256("/".join(str(k) for k in keys).encode()).digest()
    return int.from_bytes(h[:4], "little") / 2**32, int.from_bytes(h[4:8], "little") / 2**32


def _splits(lo_hi_extent, n: int, limit: float) -> list[tuple[int, int]]:
    """Greedy split of cell index range [0, n) into blocks whose metre extent stays <= limit."""
    blocks = []
    start = 0
    while start < n:
        end = start + 1
        while end < n and lo_hi_extent(start, end + 1) <= limit + 1e-9:
            end += 1
        blocks.append((start, end))
        start = end
    return blocks


def _grid_mesh(
    P: np.ndarray, S: np.ndarray, texel_scale: float, uv_mode: str, key: str
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate a (nu+1, nv+1) grid of positions ``P`` with metre coordinates ``S`` into chart blocks."""
    nu, nv = P.shape[0] - 1, P.shape[1] - 1
    T = float(texel_scale)
    if uv_mode == "fit":
        blocks = [((0, nu), (0, nv))]
    else:

        def ext_u(a, b):
            sub = S[a : b + 1]
            return float(np.max(sub.max(axis=(0, 1)) - sub.min(axis=(0, 1))))

        blocks = []
        for ua, ub in _splits(ext_u, nu, T):

            def ext_v(a, b, ua=ua, ub=ub):
                sub = S[ua : ub + 1, a : b + 1]
                return float(np.max(sub.max(axis=(0, 1)) - sub.min(axis=(0, 1))))

            blocks.extend(((ua, ub), vb) for vb in _splits(ext_v, nv, T))
    verts, faces, uvs = [], [], []
    base = 0
    for bi, ((ua, ub), (va, vb)) in enumerate(blocks):
        p = P[ua : ub + 1, va : vb + 1].reshape(-1, 3)
        s = S[ua : ub + 1, va : vb + 1].reshape(-1, 2)
        smin, smax = s.min(axis=0), s.max(axis=0)
        ext = smax - smin
        if uv_mode == "fit":
            uv = (s - smin) / np.where(ext > 0, ext, 1.0)
        else:
            span = np.maximum(ext, T)
            f = np.asarray(_hash_fraction(key, bi))
            uv = (s - smin + f * (span - ext)) / span
        uv = _UV_MARGIN + (1 - 2 * _UV_MARGIN) * uv
        w = vb - va + 1
        ii, jj = np.meshgrid(np.arange(ub - ua), np.arange(vb - va), indexing="ij")
        a = (ii * w + jj).ravel()
        b = ((ii + 1) * w + jj).ravel()
        c = ((ii + 1) * w + jj + 1).ravel()
        d = (ii * w + jj + 1).ravel()
        f_ = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]) + base
        verts.append(p)
        uvs.append(uv)
        faces.append(f_)
        base += len(p)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(uvs)


def _finish(
    name: str, pieces, texture: np.ndarray, roughness: float, metallic: float, closed: bool = True
) -> TexturedPart:
    V = np.concatenate([p[0] for p in pieces]).astype(np.float64)
    offs = np.cumsum([0] + [len(p[0]) for p in pieces[:-1]])
    F = np.concatenate([p[1] + o for p, o in zip(pieces, offs, strict=True)]).astype(np.int64)
    UV = np.clip(np.concatenate([p[2] for p in pieces]).astype(np.float64), 0.0, 1.0)
    cr = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    area2 = np.linalg.norm(cr, axis=1)
    F = F[area2 > 1e-14]
    if closed:
        vol = np.einsum("ij,ij->i", V[F[:, 0]], np.cross(V[F[:, 1]], V[F[:, 2]])).sum()
        if vol < 0:
            F = F[:, ::-1].copy()
    return TexturedPart(
        name=name, vertices=V, faces=F, uv=UV, texture=texture, roughness=roughness, metallic=metallic
    )


def _n_cells(length: float, texel_scale: float) -> int:
    return max(1, int(np.ceil(length / (0.5 * texel_scale) - 1e-9)))


def _bilinear(c00, c10, c11, c01, nu, nv):
    s = np.linspace(0, 1, nu + 1)[:, None, None]
    t = np.linspace(0, 1, nv + 1)[None, :, None]
    return (1 - s) * (1 - t) * c00 + s * (1 - t) * c10 + s * t * c11 + (1 - s) * t * c01


def rotation_matrix(axis: Sequence[float], angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` radians about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def rot_x(angle: float) -> np.ndarray:
    return rotation_matrix((1, 0, 0), angle)


def rot_y(angle: float) -> np.ndarray:
    return rotation_matrix((0, 1, 0), angle)


def rot_z(angle: float) -> np.ndarray:
    return rotation_matrix((0, 0, 1), angle)


def _frame_to(direction: Sequence[float]) -> np.ndarray:
    """A rotation taking +z onto ``direction``."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    c = float(d @ z)
    if c > 1 - 1e-12:
        return np.eye(3)
    if c < -1 + 1e-12:
        return rot_x(np.pi)
    axis = np.cross(z, d)
    return rotation_matrix(axis, np.arccos(np.clip(c, -1, 1)))


# ------------------------------------------------------------------------------------------ primitives
def hexahedron(
    name: str,
    corners: np.ndarray,
    texture: np.ndarray,
    texel_scale: float = 1.0,
    uv_mode: str = "tile",
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A closed six-faced block from 8 corners: bottom ring (-x-y, +x-y, +x+y, -x+y) then the top ring.

    Faces may be non-parallel (tapered legs, slanted backrests); each face is a bilinear patch cut into cells
    of at most ``texel_scale / 2``."""
    C = np.asarray(corners, np.float64).reshape(8, 3)
    # the block's long axis: grain direction for wood-like textures
    axes = [
        C[1] - C[0] + C[2] - C[3] + C[5] - C[4] + C[6] - C[7],
        C[3] - C[0] + C[2] - C[1] + C[7] - C[4] + C[6] - C[5],
        C[4:].sum(0) - C[:4].sum(0),
    ]
    grain = axes[int(np.argmax([np.linalg.norm(a) for a in axes]))]
    grain = grain / (np.linalg.norm(grain) + 1e-12)
    quads = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    # one cell count per edge direction class, so faces sharing an edge split it identically (no T-junctions)
    classes = [
        ((0, 1), (3, 2), (4, 5), (7, 6)),
        ((0, 3), (1, 2), (5, 6), (4, 7)),
        ((0, 4), (1, 5), (2, 6), (3, 7)),
    ]
    edge_class = {}
    counts = []
    for ci, edges in enumerate(classes):
        counts.append(
            1
            if uv_mode == "fit"
            else _n_cells(max(np.linalg.norm(C[i] - C[j]) for i, j in edges), texel_scale)
        )
        for i, j in edges:
            edge_class[(i, j)] = edge_class[(j, i)] = ci
    pieces = []
    for qi, (a, b, c, d) in enumerate(quads):
        c00, c10, c11, c01 = C[a], C[b], C[c], C[d]
        nu, nv = counts[edge_class[(a, b)]], counts[edge_class[(a, d)]]
        e_u, e_v = c10 - c00, c01 - c00
        swapped = uv_mode != "fit" and (
            abs(e_v @ grain) / (np.linalg.norm(e_v) + 1e-12)
            > abs(e_u @ grain) / (np.linalg.norm(e_u) + 1e-12) + 1e-9
        )
        if swapped:
            c00, c10, c11, c01 = c00, c01, c11, c10  # put u along the grain (this mirrors the winding)
            nu, nv = nv, nu
        lu = max(np.linalg.norm(c10 - c00), np.linalg.norm(c11 - c01))
        lv = max(np.linalg.norm(c01 - c00), np.linalg.norm(c11 - c10))
        P = _bilinear(c00, c10, c11, c01, nu, nv)
        su = np.linspace(0, lu, nu + 1)[:, None].repeat(nv + 1, 1)
        sv = np.linspace(0, lv, nv + 1)[None, :].repeat(nu + 1, 0)
        S = np.stack([su, sv], -1)
        V, F, UV = _grid_mesh(P, S, texel_scale, uv_mode, f"{name}/hexa/{qi}")
        pieces.append((V, F[:, ::-1] if swapped else F, UV))
    return _finish(name, pieces, texture, roughness, metallic)


def _apply(part: TexturedPart, rotation: np.ndarray | None, translation: Sequence[float]) -> TexturedPart:
    V = part.vertices
    if rotation is not None:
        R = np.asarray(rotation, np.float64)
        V = V @ R.T
        if np.linalg.det(R) < 0:
            part.faces = part.faces[:, ::-1].copy()
    part.vertices = V + np.asarray(translation, np.float64)
    return part


def box(
    name: str,
    extents: Sequence[float],
    centre: Sequence[float],
    texture: np.ndarray,
    texel_scale: float = 1.0,
    rotation: np.ndarray | None = None,
    uv_mode: str = "tile",
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """An axis-aligned box of full ``extents`` centred at ``centre`` (optionally rotated about its centre)."""
    ex, ey, ez = (0.5 * float(e) for e in extents)
    C = np.array(
        [
            [-ex, -ey, -ez],
            [ex, -ey, -ez],
            [ex, ey, -ez],
            [-ex, ey, -ez],
            [-ex, -ey, ez],
            [ex, -ey, ez],
            [ex, ey, ez],
            [-ex, ey, ez],
        ]
    )
    part = hexahedron(name, C, texture, texel_scale, uv_mode, roughness, metallic)
    return _apply(part, rotation, centre)


def tapered_box(
    name: str,
    bottom: Sequence[float],
    top: Sequence[float],
    height: float,
    bottom_centre: Sequence[float],
    texture: np.ndarray,
    texel_scale: float = 1.0,
    top_offset: Sequence[float] = (0.0, 0.0),
    rotation: np.ndarray | None = None,
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A frustum-like block: ``bottom`` (x, y) full sizes at z=0, ``top`` (x, y) at z=``height``, the top
    centre shifted by ``top_offset`` (splayed legs); placed with its bottom centre at ``bottom_centre``."""
    bx, by = 0.5 * bottom[0], 0.5 * bottom[1]
    tx, ty = 0.5 * top[0], 0.5 * top[1]
    ox, oy = top_offset
    C = np.array(
        [
            [-bx, -by, 0],
            [bx, -by, 0],
            [bx, by, 0],
            [-bx, by, 0],
            [ox - tx, oy - ty, height],
            [ox + tx, oy - ty, height],
            [ox + tx, oy + ty, height],
            [ox - tx, oy + ty, height],
        ]
    )
    part = hexahedron(name, C, texture, texel_scale, "tile", roughness, metallic)
    return _apply(part, rotation, bottom_centre)


def revolve(
    name: str,
    profile: Sequence[Sequence[float]],
    texture: np.ndarray,
    segments: int = 24,
    centre: Sequence[float] = (0.0, 0.0, 0.0),
    rotation: np.ndarray | None = None,
    texel_scale: float = 1.0,
    uv_mode: str = "tile",
    uv_style: str = "auto",
    roughness: float = 0.6,
    metallic: float = 0.0,
    theta0: float = 0.0,
) -> TexturedPart:
    """Lathe: revolve a (r, z) ``profile`` about the z axis (then rotate, then translate by ``centre``).

    A solid profile starts and ends on the axis (r = 0) and runs through the outline, e.g. a vase's outer
    wall up, over the lip and down its inner wall; a closed loop (first point == last point, r > 0) gives a
    ring (torus-like). Mostly horizontal profile segments get a planar (x, y) chart, the others a cylindrical
    one (arc length around x arc length along the profile); ``uv_style="cyl"`` forces cylindrical charts.
    ``segments`` should be a multiple of 4 so the bounding box is exact."""
    prof = np.asarray(profile, np.float64)
    th = theta0 + np.linspace(0, 2 * np.pi, segments + 1)
    kinds = []
    for i in range(len(prof) - 1):
        dr, dz = prof[i + 1] - prof[i]
        kinds.append("cyl" if uv_style == "cyl" or abs(dz) > abs(dr) else "plan")
    groups = []
    i = 0
    while i < len(kinds):
        j = i
        while j + 1 < len(kinds) and kinds[j + 1] == kinds[i]:
            j += 1
        groups.append((i, j + 1, kinds[i]))
        i = j + 1
    pieces = []
    cos, sin = np.cos(th), np.sin(th)
    for gi, (a, b, kind) in enumerate(groups):
        r = prof[a : b + 1, 0][:, None]
        z = prof[a : b + 1, 1][:, None]
        P = np.stack([r * cos, r * sin, np.broadcast_to(z, (b - a + 1, segments + 1))], -1)
        if kind == "plan":
            S = P[..., :2] + prof[:, 0].max()
        else:
            seg = np.linalg.norm(np.diff(prof[a : b + 1], axis=0), axis=1)
            arc = np.concatenate([[0.0], np.cumsum(seg)])[:, None].repeat(segments + 1, 1)
            rr = max(float(prof[a : b + 1, 0].max()), 1e-6)
            around = (th - theta0)[None, :].repeat(b - a + 1, 0) * rr
            S = np.stack([around, arc], -1)
        pieces.append(_grid_mesh(P, S, texel_scale, uv_mode, f"{name}/rev/{gi}"))
    part = _finish(name, pieces, texture, roughness, metallic)
    return _apply(part, rotation, centre)


def cylinder(
    name: str,
    radius: float,
    height: float,
    centre: Sequence[float],
    texture: np.ndarray,
    segments: int = 24,
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    texel_scale: float = 1.0,
    radius_top: float | None = None,
    roughness: float = 0.6,
    metallic: float = 0.0,
    uv_mode: str = "tile",
) -> TexturedPart:
    """A closed (optionally conical: ``radius_top``) cylinder centred at ``centre`` along ``axis``."""
    rt = radius if radius_top is None else radius_top
    h = 0.5 * height
    prof = [(0.0, -h), (radius, -h), (rt, h), (0.0, h)]
    return revolve(
        name,
        prof,
        texture,
        segments,
        centre,
        _frame_to(axis),
        texel_scale,
        uv_mode,
        roughness=roughness,
        metallic=metallic,
    )


def bar(
    name: str,
    p0: Sequence[float],
    p1: Sequence[float],
    radius: float,
    texture: np.ndarray,
    segments: int = 12,
    texel_scale: float = 1.0,
    roughness: float = 0.5,
    metallic: float = 0.0,
) -> TexturedPart:
    """A round bar (tube) from ``p0`` to ``p1`` (bicycle frames, chair tubes, lamp stems)."""
    p0 = np.asarray(p0, np.float64)
    p1 = np.asarray(p1, np.float64)
    d = p1 - p0
    return cylinder(
        name,
        radius,
        float(np.linalg.norm(d)),
        0.5 * (p0 + p1),
        texture,
        segments,
        d,
        texel_scale,
        roughness=roughness,
        metallic=metallic,
    )


def torus(
    name: str,
    major_radius: float,
    minor_radius: float,
    centre: Sequence[float],
    texture: np.ndarray,
    segments: int = 32,
    ring_segments: int = 12,
    axis: Sequence[float] = (0.0, 0.0, 1.0),
    texel_scale: float = 1.0,
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A torus about ``axis`` (lamp-shade rims, foot rings, tyres)."""
    a = np.linspace(0, 2 * np.pi, ring_segments + 1)
    prof = np.stack([major_radius + minor_radius * np.cos(a), minor_radius * np.sin(a)], 1)
    prof[-1] = prof[0]
    return revolve(
        name,
        prof,
        texture,
        segments,
        centre,
        _frame_to(axis),
        texel_scale,
        uv_style="cyl",
        roughness=roughness,
        metallic=metallic,
    )


def sphere(
    name: str,
    radius: float,
    centre: Sequence[float],
    texture: np.ndarray,
    segments: int = 24,
    rings: int = 12,
    texel_scale: float = 1.0,
    squash: float = 1.0,
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A UV sphere (``squash`` scales z: ellipsoids for knobs, foliage)."""
    a = np.linspace(-np.pi / 2, np.pi / 2, rings + 1)
    prof = np.stack([radius * np.cos(a), squash * radius * np.sin(a)], 1)
    prof[0, 0] = prof[-1, 0] = 0.0
    return revolve(
        name,
        prof,
        texture,
        segments,
        centre,
        None,
        texel_scale,
        uv_style="cyl",
        roughness=roughness,
        metallic=metallic,
    )


def rounded_box(
    name: str,
    extents: Sequence[float],
    centre: Sequence[float],
    radius: float,
    texture: np.ndarray,
    texel_scale: float = 1.0,
    cells: int = 6,
    rotation: np.ndarray | None = None,
    roughness: float = 0.8,
    metallic: float = 0.0,
) -> TexturedPart:
    """A box with rounded edges and corners of ``radius`` (cushions, mattresses, upholstery).

    The bounding box is exactly ``extents``. UVs come from the unrounded faces."""
    e = 0.5 * np.asarray(extents, np.float64)
    r = float(min(radius, *(e * 0.999)))
    inner = e - r
    quads = [
        ((-1, -1, -1), (-1, 1, -1), (1, 1, -1), (1, -1, -1)),  # bottom
        ((-1, -1, 1), (1, -1, 1), (1, 1, 1), (-1, 1, 1)),  # top
        ((-1, -1, -1), (1, -1, -1), (1, -1, 1), (-1, -1, 1)),  # front -y
        ((1, -1, -1), (1, 1, -1), (1, 1, 1), (1, -1, 1)),
        ((1, 1, -1), (-1, 1, -1), (-1, 1, 1), (1, 1, 1)),
        ((-1, 1, -1), (-1, -1, -1), (-1, -1, 1), (-1, 1, 1)),
    ]
    pieces = []
    for qi, q in enumerate(quads):
        c = [np.asarray(v, np.float64) * e for v in q]
        lu, lv = np.linalg.norm(c[1] - c[0]), np.linalg.norm(c[3] - c[0])
        nu = max(cells, _n_cells(lu, texel_scale))
        nv = max(cells, _n_cells(lv, texel_scale))
        # cells concentrated near the edges so the rounding is smooth
        su = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, nu + 1))
        sv = 0.5 - 0.5 * np.cos(np.linspace(0, np.pi, nv + 1))
        P = (
            (1 - su)[:, None, None] * (1 - sv)[None, :, None] * c[0]
            + su[:, None, None] * (1 - sv)[None, :, None] * c[1]
            + su[:, None, None] * sv[None, :, None] * c[2]
            + (1 - su)[:, None, None] * sv[None, :, None] * c[3]
        )
        cl = np.clip(P, -inner, inner)
        d = P - cl
        n = np.linalg.norm(d, axis=-1, keepdims=True)
        P = cl + r * d / np.where(n > 0, n, 1.0)
        S = np.stack(np.meshgrid(su * lu, sv * lv, indexing="ij"), -1)
        pieces.append(_grid_mesh(P, S, texel_scale, "tile", f"{name}/rbox/{qi}"))
    part = _finish(name, pieces, texture, roughness, metallic)
    return _apply(part, rotation, centre)


def extrude(
    name: str,
    outline: Sequence[Sequence[float]],
    thickness: float,
    texture: np.ndarray,
    centre: Sequence[float] = (0.0, 0.0, 0.0),
    rotation: np.ndarray | None = None,
    texel_scale: float = 1.0,
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A prism: a *convex* (x, y) outline (counter-clockwise) extruded along z by ``thickness`` (centred)."""
    O = np.asarray(outline, np.float64)
    n = len(O)
    h = 0.5 * thickness
    pieces = []
    ext = O.max(0) - O.min(0)
    for gi, z in enumerate((-h, h)):  # caps as fans; chart = planar (x, y)
        P = np.concatenate([O.mean(0)[None], O])
        V = np.concatenate([P, np.full((n + 1, 1), z)], 1)
        F = np.array([[0, 1 + i, 1 + (i + 1) % n] for i in range(n)])
        F = F[:, ::-1] if gi == 0 else F  # bottom cap faces -z
        s = P - O.min(0)
        span = np.maximum(ext, texel_scale)
        f = np.asarray(_hash_fraction(name, "cap", gi))
        uv = _UV_MARGIN + (1 - 2 * _UV_MARGIN) * (s + f * (span - ext)) / span
        pieces.append((V, F, uv))
    loop = np.concatenate([O, O[:1]])
    seg = np.linalg.norm(np.diff(loop, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    P = np.stack(
        [
            np.concatenate([loop, np.full((n + 1, 1), -h)], 1),
            np.concatenate([loop, np.full((n + 1, 1), h)], 1),
        ],
        1,
    )  # (n+1, 2, 3)
    S = np.stack([arc[:, None].repeat(2, 1), np.array([[0.0, thickness]]).repeat(n + 1, 0)], -1)
    pieces.append(_grid_mesh(P, S, texel_scale, "tile", f"{name}/ext/side"))
    part = _finish(name, pieces, texture, roughness, metallic)
    return _apply(part, rotation, centre)


def tube(
    name: str,
    path: Sequence[Sequence[float]],
    radius: float,
    texture: np.ndarray,
    segments: int = 8,
    texel_scale: float = 1.0,
    roughness: float = 0.6,
    metallic: float = 0.0,
) -> TexturedPart:
    """A round tube swept along a polyline ``path`` (n >= 2 points), capped at both ends (mug and basket
    handles). Cross-sections are perpendicular to the mean tangent at each point; their frame is carried
    along the path by parallel transport, so a planar path keeps ring point 0 in its plane (``segments`` a
    multiple of 4 puts ring points exactly in and across that plane). Chart: arc length along the path x arc
    length around the tube."""
    P = np.asarray(path, np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or len(P) < 2:
        raise ValueError(f"tube {name!r}: path must be (n >= 2, 3), got shape {P.shape}")
    seg = np.diff(P, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    if np.any(seg_len <= 0):
        raise ValueError(f"tube {name!r}: path has repeated points")
    ts = seg / seg_len[:, None]
    T = np.concatenate([ts[:1], ts[:-1] + ts[1:], ts[-1:]])
    T /= np.linalg.norm(T, axis=1, keepdims=True)
    # initial normal: in the path's plane when it has one (perpendicular to T[0], towards the bend)
    bend = (P[-1] - P[0]) if len(P) > 2 else np.array([0.0, 0.0, 1.0])
    n0 = bend - (bend @ T[0]) * T[0]
    if np.linalg.norm(n0) < 1e-9:
        ref = np.eye(3)[int(np.argmin(np.abs(T[0])))]
        n0 = ref - (ref @ T[0]) * T[0]
    N = [n0 / np.linalg.norm(n0)]
    for i in range(1, len(P)):
        axis = np.cross(T[i - 1], T[i])
        s = float(np.linalg.norm(axis))
        n = N[-1]
        if s > 1e-12:
            n = rotation_matrix(axis, float(np.arctan2(s, T[i - 1] @ T[i]))) @ n
        n = n - (n @ T[i]) * T[i]
        N.append(n / np.linalg.norm(n))
    Nn = np.asarray(N)
    B = np.cross(T, Nn)
    a = np.linspace(0, 2 * np.pi, segments + 1)
    ring = np.cos(a)[None, :, None] * Nn[:, None, :] + np.sin(a)[None, :, None] * B[:, None, :]
    G = P[:, None, :] + radius * ring  # (n, segments + 1, 3)
    arc = np.concatenate([[0.0], np.cumsum(seg_len)])
    S = np.stack([arc[:, None].repeat(segments + 1, 1), (a * radius)[None, :].repeat(len(P), 0)], -1)
    V, F, UV = _grid_mesh(G, S, texel_scale, "tile", f"{name}/tube")
    pieces = [(V, F[:, ::-1], UV)]  # the grid's (along, around) order winds inwards
    for ci, (i, sign) in enumerate(((0, -1), (len(P) - 1, 1))):  # end caps as fans, outward along -/+ T
        Vc = np.concatenate([P[i][None], G[i, :-1]])
        k = np.arange(segments)
        Fc = np.stack([np.zeros(segments, np.int64), 1 + k, 1 + (k + 1) % segments], 1)
        Fc = Fc if sign > 0 else Fc[:, ::-1]
        f = np.asarray(_hash_fraction(name, "cap", ci))
        span = max(2 * radius, texel_scale)
        uvc = np.stack([np.concatenate([[0.0], np.cos(a[:-1])]), np.concatenate([[0.0], np.sin(a[:-1])])], 1)
        uvc = (radius * (uvc + 1) + f * (span - 2 * radius)) / span
        pieces.append((Vc, Fc, _UV_MARGIN + (1 - 2 * _UV_MARGIN) * uvc))
    return _finish(name, pieces, texture, roughness, metallic)


def merge_parts(name: str, parts: Sequence[TexturedPart]) -> TexturedPart:
    """Concatenate parts that share one texture (the first part's texture and material hints are kept)."""
    if not parts:
        raise ValueError("merge_parts needs at least one part")
    V = np.concatenate([p.vertices for p in parts])
    UV = np.concatenate([p.uv for p in parts])
    offs = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    F = np.concatenate([p.faces + o for p, o in zip(parts, offs, strict=True)])
    p0 = parts[0]
    return TexturedPart(
        name=name,
        vertices=V,
        faces=F,
        uv=UV,
        texture=p0.texture,
        roughness=p0.roughness,
        metallic=p0.metallic,
        emissive=p0.emissive,
    )


def transform_part(part: TexturedPart, matrix: np.ndarray) -> TexturedPart:
    """A copy of ``part`` with vertices mapped by a 4x4 (column-vector) transform; mirrors keep winding."""
    M = np.asarray(matrix, np.float64)
    V = part.vertices @ M[:3, :3].T + M[:3, 3]
    F = part.faces[:, ::-1].copy() if np.linalg.det(M[:3, :3]) < 0 else part.faces.copy()
    return TexturedPart(
        name=part.name,
        vertices=V,
        faces=F,
        uv=part.uv.copy(),
        texture=part.texture,
        roughness=part.roughness,
        metallic=part.metallic,
        emissive=part.emissive,
    )
