"""Storage of imported models in the object library: ``imported/<id>/<id>.toml`` + one PLY and PNG per part.

Each part is a binary little-endian PLY (``double x y z``, ``double texture_u texture_v``, triangles;
``comment TextureFile part_000.png``, so MeshLab / Blender / trimesh open it with its texture) next to its
texture PNG. Vertices are float64 metres in the canonical frame (bottom centre at the origin, +z up, front
+y), UVs have v = 0 at the bottom row of the texture. The TOML (read by the ``imported`` builder,
:mod:`synthleak.assets.builders.imported`; schema in docs/your-own-models.md)::

    id = "my_chair"
    category = "chair"
    builder = "imported"
    symmetry = "none"
    support = "floor"
    size = [0.46, 0.5, 0.92]            # canonical extents, metres
    scale_range = [0.9, 1.1]
    colour_range = [0.08, 0.15, 0.15]
    description = "..."

    [imported]                          # provenance (informational)
    source = "chair.glb"
    sha256 = "..."
    up = "y"  front = "-z"  units = "cm"  scale = 1.0

    [textures.part_000]                 # one table per part
    mesh = "part_000.ply"
    file = "part_000.png"
    roughness = 0.6                     # optional: metallic, recolour (bool), source_name
"""

from __future__ import annotations

import functools
import re
from pathlib import Path

import cv2
import numpy as np

IMPORTED_BUILDER = "imported"
IMPORTED_DIR = "imported"


# ----------------------------------------------------------------------------------------------------- PLY
def ply_bytes(vertices: np.ndarray, faces: np.ndarray, uv: np.ndarray, texture_file: str) -> bytes:
    """Binary PLY of one part (layout in the module docstring)."""
    v = np.asarray(vertices, dtype="<f8").reshape(-1, 3)
    t = np.asarray(uv, dtype="<f8").reshape(-1, 2)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"comment TextureFile {texture_file}\n"
        f"element vertex {len(v)}\n"
        "property double x\nproperty double y\nproperty double z\n"
        "property double texture_u\nproperty double texture_v\n"
        f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode("ascii")
    vrec = np.empty(len(v), dtype=[("p", "<f8", 3), ("t", "<f8", 2)])
    vrec["p"], vrec["t"] = v, t
    frec = np.empty(len(f), dtype=[("n", "u1"), ("i", "<i4", 3)])
    frec["n"], frec["i"] = 3, f
    return header + vrec.tobytes() + frec.tobytes()


@functools.lru_cache(maxsize=256)
def _read_ply_cached(path: str, mtime_ns: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise ValueError(f"{path}: not a PLY file written by synthleak import")
    header = data[:end].decode("ascii", "replace")
    nv = re.search(r"element vertex (\d+)", header)
    nf = re.search(r"element face (\d+)", header)
    expected = "property double x\nproperty double y\nproperty double z\nproperty double texture_u\n"
    if not nv or not nf or "binary_little_endian" not in header or expected not in header:
        raise ValueError(f"{path}: unexpected PLY layout (re-import the model)")
    n_v, n_f = int(nv.group(1)), int(nf.group(1))
    vdt = np.dtype([("p", "<f8", 3), ("t", "<f8", 2)])
    fdt = np.dtype([("n", "u1"), ("i", "<i4", 3)])
    body = data[end + len(b"end_header\n") :]
    if len(body) != n_v * vdt.itemsize + n_f * fdt.itemsize:
        raise ValueError(f"{path}: truncated PLY (expected {n_v} vertices and {n_f} faces)")
    verts = np.frombuffer(body, vdt, n_v)
    faces = np.frombuffer(body, fdt, n_f, offset=n_v * vdt.itemsize)
    out = (np.array(verts["p"]), np.array(faces["i"], dtype=np.int64), np.array(verts["t"]))
    for a in out:
        a.flags.writeable = False
    return out


def read_ply(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices (N, 3), faces (M, 3), uv (N, 2)) of a part PLY (cached, read-only arrays)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: imported mesh file is missing")
    st = path.stat()
    return _read_ply_cached(str(path), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=256)
def _read_png_cached(path: str, mtime_ns: int, size: int) -> np.ndarray:
    image = cv2.imread(path, cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: imported texture is unreadable")
    rgb = np.ascontiguousarray(image[..., ::-1])
    rgb.flags.writeable = False
    return rgb


def read_texture(path: Path) -> np.ndarray:
    """RGB uint8 texture of a part (cached, read-only)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: imported texture file is missing")
    st = path.stat()
    return _read_png_cached(str(path), st.st_mtime_ns, st.st_size)
