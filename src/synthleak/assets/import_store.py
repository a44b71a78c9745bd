"""Storage of imported models in the object library: ``imported/<id>/<id>.toml`` + one PLY and PNG per part.

Each part is a binary little-endian PLY (``double x y z``, ``double texture_u texture_v``, triangles;
``comment TextureFile part_000.png``, so MeshLab / Blender / trimesh open it with its texture) next to its
texture PNG. Vertices are float64 metres in the canonical frame (bottom centre at the origin, +z up, front
+y), UVs have v = 0 at the bottom row of the texture. The TOML (schema in docs/your-own-models.md)::

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
import tomllib
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from synthleak.assets.library import SUPPORTS, SYMMETRIES, ObjectModel
from synthleak.assets.mesh import ObjectMesh, TexturedPart
from synthleak.errors import UnknownNameError

IMPORTED_BUILDER = "imported"
IMPORTED_DIR = "imported"
_TOP = {
    "id",
    "category",
    "builder",
    "symmetry",
    "support",
    "size",
    "scale_range",
    "colour_range",
    "description",
    "imported",
    "textures",
}
_PART = {"mesh", "file", "roughness", "metallic", "recolour", "source_name"}


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


# ---------------------------------------------------------------------------------------------- models
def _err(path: Path, key: str, msg: str) -> ValueError:
    return ValueError(f"{path}: key '{key}': {msg}")


def _numbers(path: Path, key: str, value: Any, n: int) -> tuple[float, ...]:
    if (
        not isinstance(value, list)
        or len(value) != n
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in value)
    ):
        raise _err(path, key, f"expected a list of {n} numbers, got {value!r}")
    return tuple(float(v) for v in value)


def parse_imported_model(path: Path, data: dict[str, Any] | None = None) -> ObjectModel:
    """An imported model's TOML -> :class:`ObjectModel` (``builder = "imported"``, no shape parameters;
    ``textures[part]`` holds ``mesh``, ``file`` and material hints). Errors name the file and the key."""
    path = Path(path)
    if data is None:
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: not valid TOML: {exc}") from exc
    for k in data:
        if k not in _TOP:
            raise _err(path, k, f"unknown key for an imported model (known: {', '.join(sorted(_TOP))})")
    for k in ("id", "category", "builder", "symmetry", "support", "size", "textures"):
        if k not in data:
            raise _err(path, k, "missing")
    if data["builder"] != IMPORTED_BUILDER:
        raise _err(path, "builder", f"expected {IMPORTED_BUILDER!r}, got {data['builder']!r}")
    if not isinstance(data["id"], str) or not re.fullmatch(r"[a-z0-9_]+", data["id"]):
        raise _err(path, "id", f"{data['id']!r} must match [a-z0-9_]+")
    if not isinstance(data["category"], str) or not data["category"]:
        raise _err(path, "category", "expected a non-empty string")
    if data["symmetry"] not in SYMMETRIES:
        raise _err(path, "symmetry", f"{data['symmetry']!r} not in {SYMMETRIES}")
    if data["support"] not in SUPPORTS:
        raise _err(path, "support", f"{data['support']!r} not in {SUPPORTS}")
    size = _numbers(path, "size", data["size"], 3)
    if min(size) <= 0:
        raise _err(path, "size", "extents must be positive")
    scale_range = _numbers(path, "scale_range", data.get("scale_range", [0.9, 1.1]), 2)
    if not 0 < scale_range[0] <= 1.0 <= scale_range[1]:
        raise _err(path, "scale_range", f"need 0 < min <= 1 <= max, got {scale_range}")
    colour_range = _numbers(path, "colour_range", data.get("colour_range", [0.08, 0.15, 0.15]), 3)
    if min(colour_range) < 0 or colour_range[0] > 0.5 or max(colour_range[1:]) > 1:
        raise _err(path, "colour_range", "need 0 <= hue <= 0.5 and 0 <= saturation, value <= 1")
    textures = data["textures"]
    if not isinstance(textures, dict) or not textures:
        raise _err(path, "textures", "expected one table per part")
    parts: dict[str, dict[str, Any]] = {}
    for name, spec in textures.items():
        key = f"textures.{name}"
        if not isinstance(spec, dict):
            raise _err(path, key, "expected a table")
        for k in spec:
            if k not in _PART:
                raise _err(path, f"{key}.{k}", f"unknown key (known: {', '.join(sorted(_PART))})")
        for k in ("mesh", "file"):
            if not isinstance(spec.get(k), str):
                raise _err(path, f"{key}.{k}", "expected a file name relative to the TOML")
            if not (path.parent / spec[k]).is_file():
                raise _err(path, f"{key}.{k}", f"file {path.parent / spec[k]} does not exist")
        for k in ("roughness", "metallic"):
            if k in spec and (not isinstance(spec[k], int | float) or not 0 <= spec[k] <= 1):
                raise _err(path, f"{key}.{k}", f"expected a number in [0, 1], got {spec[k]!r}")
        if "recolour" in spec and not isinstance(spec["recolour"], bool):
            raise _err(path, f"{key}.recolour", "expected true or false")
        parts[name] = dict(spec)
    return ObjectModel(
        model_id=data["id"],
        category=data["category"],
        builder=IMPORTED_BUILDER,
        symmetry=data["symmetry"],
        support=data["support"],
        size=size,  # type: ignore[arg-type]
        params={},
        scale_range=scale_range,  # type: ignore[arg-type]
        textures=parts,
        source=str(path),
        colour_range=colour_range,  # type: ignore[arg-type]
        description=str(data.get("description", "")),
    )


def is_imported(model: ObjectModel) -> bool:
    return model.builder == IMPORTED_BUILDER


def imported_texture(model: ObjectModel, part: str) -> np.ndarray:
    """The stored (read-only) texture of one part of an imported model."""
    if part not in model.textures:
        raise UnknownNameError(
            f"imported model {model.model_id!r} has no part {part!r}; it has {sorted(model.textures)}"
        )
    return read_texture(Path(model.source).parent / model.textures[part]["file"])


def build_imported(
    model: ObjectModel, params: dict[str, float] | None = None, textures: dict[str, np.ndarray] | None = None
) -> ObjectMesh:
    """The imported mesh (canonical frame, fresh arrays); ``textures`` replaces part textures (colour
    variants). Imported models have no shape parameters: any non-None ``params`` entry raises ``KeyError``."""
    given = {k: v for k, v in (params or {}).items() if v is not None}
    if given:
        raise UnknownNameError(
            f"model {model.model_id!r} is an imported mesh and has no shape parameters (got {sorted(given)})"
        )
    base = Path(model.source).parent
    parts = []
    for name, spec in model.textures.items():
        verts, faces, uv = read_ply(base / spec["mesh"])
        tex = textures[name] if textures is not None and name in textures else imported_texture(model, name)
        parts.append(
            TexturedPart(
                name=name,
                vertices=np.array(verts),
                faces=np.array(faces),
                uv=np.array(uv),
                texture=np.array(tex),
                roughness=float(spec.get("roughness", 0.6)),
                metallic=float(spec.get("metallic", 0.0)),
            )
        )
    return ObjectMesh(parts)


def load_imported_models(library_dir: Path) -> dict[str, ObjectModel]:
    """All imported models under ``library_dir/imported/*/*.toml``, by id."""
    out: dict[str, ObjectModel] = {}
    for path in sorted((Path(library_dir) / IMPORTED_DIR).glob("*/*.toml")):
        model = parse_imported_model(path)
        if model.model_id in out:
            raise _err(path, "id", f"duplicate id {model.model_id!r} (also in {out[model.model_id].source})")
        out[model.model_id] = model
    return out
