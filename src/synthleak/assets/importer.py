"""``synthleak import``: bring your own textured model into the object library (canonical frame, UV textures).

:func:`import_model` reads OBJ (+ MTL and textures), glTF / GLB, PLY (via trimesh) and USD / USDA / USDC / USDZ
(via :func:`synthleak.core.usd_read.read_render_scene`, which already applies the stage's ``metersPerUnit`` and
``upAxis``), then

1. rotates so the file's ``up`` axis becomes +z and its ``front`` axis +y (default: +z for a y-up file, as glTF
   faces, else +y), converts ``units`` to metres,
2. recentres to the bottom centre of the footprint (x / y bounding-box centre, lowest z at 0),
3. optionally scales uniformly (``height`` in metres or a factor ``scale``),

and writes ``<library>/imported/<id>/`` (see :mod:`synthleak.assets.import_store`) through a temporary folder
renamed into place, so a failed import leaves the library as it was. Parts keep their UVs and textures; a part
without a texture gets a small texture of its base colour (and zero UVs). Bad files raise ``ValueError``
naming the file: no geometry, a texture without UVs, a missing texture file, non-finite vertices, a file over
:data:`MAX_IMPORT_BYTES` (checked before reading).

The library reads the result with its ``imported`` builder (:mod:`synthleak.assets.builders.imported`):
colour and scale variants work; imported models have no shape parameters, so asking for ``shape`` variants
warns.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tempfile
import tomllib
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.assets.builders.imported import parse_imported_model
from synthleak.assets.import_store import IMPORTED_BUILDER, IMPORTED_DIR, ply_bytes
from synthleak.assets.model import SUPPORTS, SYMMETRIES, ObjectModel
from synthleak.atomic_io import folder_mode
from synthleak.core.dataset import encode_png

MAX_IMPORT_BYTES = 2 * 1024**3
"""Files larger than this are refused before reading (2 GiB)."""
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
TRIMESH_SUFFIXES = (".obj", ".glb", ".gltf", ".ply", ".stl", ".off")
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")
_AXES = {"x": 0, "y": 1, "z": 2}

__all__ = [
    "MAX_IMPORT_BYTES",
    "SourcePart",
    "canonical_rotation",
    "default_front",
    "import_model",
    "read_source",
]


@dataclass
class SourcePart:
    """One textured triangle mesh as read from a file (file units and axes)."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    uv: np.ndarray
    texture: np.ndarray
    roughness: float = 0.6
    metallic: float = 0.0


def _fail(path: Path, msg: str) -> ValueError:
    return ValueError(f"{path}: cannot import: {msg}")


# ------------------------------------------------------------------------------------------------- axes
def _axis(path: Path, flag: str, value: str) -> np.ndarray:
    text = str(value).strip().lower()
    sign = -1.0 if text.startswith("-") else 1.0
    name = text.lstrip("+-")
    if name not in _AXES:
        raise ValueError(f"{path}: --{flag} {value!r}: expected one of x, y, z with an optional + or - sign")
    out = np.zeros(3)
    out[_AXES[name]] = sign
    return out


def default_front(up: str) -> str:
    """The front axis assumed when none is given: ``+z`` for a y-up file (glTF / GLB: y up, facing +z), ``+y``
    otherwise (synthleak's canonical frame: z up, front +y)."""
    return "+z" if str(up).strip().lower().lstrip("+-") == "y" else "+y"


def canonical_rotation(up: str = "z", front: str | None = None, path: Path | str = "<model>") -> np.ndarray:
    """Rotation (3, 3) taking the file's ``up`` axis to +z and its ``front`` axis (default:
    :func:`default_front`) to +y (a proper rotation)."""
    front = default_front(up) if front is None else front
    u, f = _axis(Path(path), "up", up), _axis(Path(path), "front", front)
    if abs(float(u @ f)) > 0.5:
        raise ValueError(f"{path}: --front {front!r} must be perpendicular to --up {up!r}")
    return np.stack([np.cross(f, u), f, u])  # rows: x = f x u, y = f, z = u


# ---------------------------------------------------------------------------------------------- reading
def _rgb(image: Any) -> np.ndarray:
    array = np.asarray(image.convert("RGB") if hasattr(image, "convert") else image)
    if array.ndim == 2:
        array = np.repeat(array[..., None], 3, axis=2)
    return np.ascontiguousarray(array[..., :3].astype(np.uint8))


def _flat_texture(colour: Sequence[float]) -> np.ndarray:
    c = np.asarray(colour, dtype=np.float64)[:3]
    c = c / 255.0 if c.max() > 1.0 else c
    return np.full((4, 4, 3), np.round(np.clip(c, 0, 1) * 255), dtype=np.uint8)


def _check_obj_textures(path: Path) -> None:
    """Every ``map_Kd`` of the OBJ's MTL files must exist (trimesh would silently drop it)."""
    for line in path.read_text(errors="replace").splitlines():
        if not line.startswith("mtllib"):
            continue
        mtl = path.parent / line.split(maxsplit=1)[1].strip()
        if not mtl.is_file():
            raise _fail(path, f"material library {mtl} is missing")
        for mline in mtl.read_text(errors="replace").splitlines():
            tok = mline.strip().split()
            if tok and tok[0].lower() == "map_kd" and len(tok) > 1:
                tex = mtl.parent / tok[-1]
                if not tex.is_file():
                    raise _fail(path, f"texture file {tex} (map_Kd in {mtl.name}) is missing")


def _check_gltf_textures(path: Path) -> None:
    try:
        doc = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise _fail(path, f"not valid glTF JSON ({exc})") from exc
    for key in ("images", "buffers"):
        for i, item in enumerate(doc.get(key, [])):
            uri = item.get("uri", "")
            if uri and not uri.startswith("data:") and not (path.parent / uri).is_file():
                raise _fail(path, f"{key}[{i}] file {path.parent / uri} is missing")


def _trimesh_parts(path: Path) -> list[SourcePart]:
    import trimesh

    suffix = path.suffix.lower()
    if suffix == ".obj":
        _check_obj_textures(path)
    elif suffix == ".gltf":
        _check_gltf_textures(path)
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as exc:  # noqa: BLE001 - any loader failure becomes a clear, file-named error
        raise _fail(path, f"unreadable ({type(exc).__name__}: {exc})") from exc
    parts = []
    for node in sorted(scene.graph.nodes_geometry):
        transform, geom_name = scene.graph[node]
        mesh = scene.geometry[geom_name]
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            continue
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        verts = verts @ np.asarray(transform)[:3, :3].T + np.asarray(transform)[:3, 3]
        visual = mesh.visual
        material = getattr(visual, "material", None)
        image = None
        if material is not None:
            image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
        uv = getattr(visual, "uv", None) if visual is not None and visual.kind == "texture" else None
        roughness = float(getattr(material, "roughnessFactor", None) or 0.6)
        metallic = float(getattr(material, "metallicFactor", None) or 0.0)
        if image is not None:
            if uv is None or len(uv) != len(verts):
                raise _fail(path, f"mesh {node!r} has a texture but no texture coordinates (UVs)")
            texture, uv = _rgb(image), np.asarray(uv, dtype=np.float64)
        else:
            colour = (0.7, 0.7, 0.7)
            if material is not None and getattr(material, "baseColorFactor", None) is not None:
                colour = np.asarray(material.baseColorFactor, dtype=np.float64)[:3]
            elif material is not None and getattr(material, "diffuse", None) is not None:
                colour = np.asarray(material.diffuse, dtype=np.float64)[:3]
            elif visual is not None and visual.kind == "vertex":
                colour = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3].mean(axis=0)
            elif visual is not None and visual.kind == "face":
                colour = np.asarray(visual.face_colors, dtype=np.float64)[:, :3].mean(axis=0)
            texture, uv = _flat_texture(colour), np.zeros((len(verts), 2))
        parts.append(
            SourcePart(str(node), verts, np.asarray(mesh.faces, dtype=np.int64), uv, texture, roughness, metallic)
        )
    return parts


def _usd_parts(path: Path) -> list[SourcePart]:
    from synthleak.core.usd_read import read_render_scene

    with tempfile.TemporaryDirectory(prefix="synthleak-usdz-") as tmp:
        stage = path
        if path.suffix.lower() == ".usdz":  # textures inside the package: read an unpacked copy
            try:
                with zipfile.ZipFile(path) as archive:
                    names = archive.namelist()
                    archive.extractall(tmp)
            except zipfile.BadZipFile as exc:
                raise _fail(path, f"not a valid USDZ package ({exc})") from exc
            layers = [n for n in names if n.lower().endswith((".usd", ".usda", ".usdc"))]
            if not layers:
                raise _fail(path, "the USDZ package holds no USD layer")
            stage = Path(tmp) / layers[0]
        try:
            scene = read_render_scene(stage)
        except Exception as exc:  # noqa: BLE001 - reader failures become a clear, file-named error
            raise _fail(path, f"{type(exc).__name__}: {exc}") from exc
    parts = []
    for mesh in scene.meshes:
        verts = np.asarray(mesh.vertices, dtype=np.float64)
        if mesh.texture is not None and mesh.uv is not None:
            texture, uv = np.asarray(mesh.texture, dtype=np.uint8), np.asarray(mesh.uv, dtype=np.float64)
        else:
            texture, uv = _flat_texture(mesh.base_color), np.zeros((len(verts), 2))
        parts.append(
            SourcePart(mesh.name, verts, np.asarray(mesh.faces, np.int64), uv, texture, mesh.roughness, mesh.metallic)
        )
    return parts


def read_source(path: Path) -> list[SourcePart]:
    """The textured parts of a model file in its own units and axes (USD: metres, +z up). Checks size first."""
    path = Path(path)
    if not path.is_file():
        raise _fail(path, "no such file")
    size = path.stat().st_size
    if size > MAX_IMPORT_BYTES:
        raise _fail(path, f"file is {size} bytes, over the import limit of {MAX_IMPORT_BYTES} bytes")
    suffix = path.suffix.lower()
    if suffix in TRIMESH_SUFFIXES:
        parts = _trimesh_parts(path)
    elif suffix in USD_SUFFIXES:
        parts = _usd_parts(path)
    else:
        raise _fail(path, f"unsupported format {suffix!r} (supported: {', '.join(TRIMESH_SUFFIXES + USD_SUFFIXES)})")
    if not parts or sum(len(p.faces) for p in parts) == 0:
        raise _fail(path, "no geometry (no triangle meshes with faces)")
    for p in parts:
        if not np.all(np.isfinite(p.vertices)):
            raise _fail(path, f"mesh {p.name!r} has non-finite vertex coordinates")
        if not np.all(np.isfinite(p.uv)):
            raise _fail(path, f"mesh {p.name!r} has non-finite texture coordinates")
        if p.faces.min() < 0 or p.faces.max() >= len(p.vertices):
            raise _fail(path, f"mesh {p.name!r} has face indices outside its vertices")
    return parts


# ------------------------------------------------------------------------------------------------ import
def _slug(text: str) -> str:
    slug = re.sub(r"[^a-z0-9_]+", "_", text.lower()).strip("_")
    return slug or "model"


def _library_dir(library_dir: Path | None) -> Path:
    if library_dir is not None:
        return Path(library_dir)
    from synthleak.paths import object_library_dir

    return object_library_dir()


def _toml_str(value: str) -> str:
    return json.dumps(value)  # a JSON string is a valid TOML basic string


def _toml(fields: dict[str, Any], provenance: dict[str, Any], parts: dict[str, dict[str, Any]]) -> str:
    def val(v: Any) -> str:
        if isinstance(v, str):
            return _toml_str(v)
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list | tuple):
            return "[" + ", ".join(val(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"{k} = {val(v)}" for k, v in fields.items()]
    lines += ["", "[imported]"] + [f"{k} = {val(v)}" for k, v in provenance.items()]
    for name, spec in parts.items():
        lines += ["", f"[textures.{name}]"] + [f"{k} = {val(v)}" for k, v in spec.items()]
    return "\n".join(lines) + "\n"


def import_model(
    path: Path | str,
    category: str,
    *,
    name: str | None = None,
    up: str = "z",
    front: str | None = None,
    units: str = "m",
    height: float | None = None,
    scale: float | None = None,
    symmetry: str = "none",
    support: str = "floor",
    library_dir: Path | None = None,
    overwrite: bool = False,
) -> ObjectModel:
    """Import ``path`` into ``library_dir/imported/<id>/`` (see the module docstring); returns the model.

    ``name``: the model id (default: the file stem as ``[a-z0-9_]+``); ``up`` / ``front``: the file's axes
    (``x``, ``y``, ``z`` with an optional sign; ``front`` defaults to ``+z`` for y up, else ``+y``); ``units``:
    m, cm, mm, in, ft; ``height`` (metres) or ``scale`` (factor, after unit conversion), not both;
    ``overwrite``: replace an earlier import of the same id."""
    path = Path(path)
    if units not in UNITS:
        raise ValueError(f"{path}: --units {units!r}: expected one of {', '.join(UNITS)}")
    if symmetry not in SYMMETRIES:
        raise ValueError(f"{path}: --symmetry {symmetry!r}: expected one of {', '.join(SYMMETRIES)}")
    if support not in SUPPORTS:
        raise ValueError(f"{path}: --support {support!r}: expected one of {', '.join(SUPPORTS)}")
    if height is not None and scale is not None:
        raise ValueError(f"{path}: give --height or --scale, not both")
    for flag, value in (("height", height), ("scale", scale)):
        if value is not None and not (np.isfinite(value) and value > 0):
            raise ValueError(f"{path}: --{flag} must be a positive number, got {value!r}")
    if not isinstance(category, str) or not re.fullmatch(r"[a-z0-9_]+", category):
        raise ValueError(f"{path}: --category {category!r} must match [a-z0-9_]+")
    model_id = name if name is not None else _slug(path.stem)
    if not re.fullmatch(r"[a-z0-9_]+", model_id):
        raise ValueError(f"{path}: --name {model_id!r} must match [a-z0-9_]+")
    front = default_front(up) if front is None else front
    rotation = canonical_rotation(up, front, path)
    library = _library_dir(library_dir)
    if not library.is_dir():
        raise FileNotFoundError(f"object library folder {library} does not exist")
    if (library / f"{model_id}.toml").exists() or any(_toml_id(p) == model_id for p in sorted(library.glob("*.toml"))):
        raise ValueError(f"{path}: id {model_id!r} is taken by a library model; choose another --name")
    target = library / IMPORTED_DIR / model_id
    if target.exists() and not overwrite:
        raise ValueError(f"{path}: {target} exists (imported before); pass overwrite=True / --overwrite to replace it")

    parts = read_source(path)
    factor = UNITS[units]
    verts = [(p.vertices @ rotation.T) * factor for p in parts]
    allv = np.concatenate(verts)
    lo, hi = allv.min(axis=0), allv.max(axis=0)
    origin = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    verts = [v - origin for v in verts]
    extent_z = float(hi[2] - lo[2])
    s = 1.0
    if height is not None:
        if extent_z <= 0:
            raise _fail(path, "the model is flat (zero height along --up); --height cannot scale it")
        s = float(height) / extent_z
    elif scale is not None:
        s = float(scale)
    verts = [v * s for v in verts]
    size = np.concatenate(verts).max(axis=0) - np.concatenate(verts).min(axis=0)
    if np.any(size <= 0):
        raise _fail(path, f"the model is flat along an axis (extents {size.tolist()} m); it needs a 3D size")

    table: dict[str, dict[str, Any]] = {}
    files: dict[str, bytes] = {}
    for k, (p, v) in enumerate(zip(parts, verts, strict=True)):
        part = f"part_{k:03d}"
        files[f"{part}.ply"] = ply_bytes(v, p.faces, p.uv, f"{part}.png")
        files[f"{part}.png"] = encode_png(p.texture)
        table[part] = {
            "mesh": f"{part}.ply",
            "file": f"{part}.png",
            "roughness": float(np.clip(p.roughness, 0, 1)),
            "metallic": float(np.clip(p.metallic, 0, 1)),
            "source_name": p.name,
        }
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    fields = {
        "id": model_id,
        "category": category,
        "builder": IMPORTED_BUILDER,
        "symmetry": symmetry,
        "support": support,
        "size": [float(x) for x in size],
        "scale_range": [0.9, 1.1],
        "colour_range": [0.08, 0.15, 0.15],
        "description": f"imported from {path.name}",
    }
    provenance = {"source": path.name, "sha256": digest, "up": up, "front": front, "units": units, "scale": s}
    files[f"{model_id}.toml"] = _toml(fields, provenance, table).encode()
    _write_folder(target, files)
    return parse_imported_model(target / f"{model_id}.toml")


def _toml_id(path: Path) -> str | None:
    try:
        return tomllib.loads(path.read_text()).get("id")
    except (OSError, tomllib.TOMLDecodeError):
        return None


def _write_folder(target: Path, files: dict[str, bytes]) -> None:
    """Write ``files`` into a temporary sibling folder, then rename it onto ``target`` (replacing it)."""
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".tmp-{target.name}-", dir=target.parent))
    tmp.chmod(folder_mode())  # mkdtemp makes it 0700: give the model folder a plain folder's mode
    old = None
    try:
        for name, data in files.items():
            (tmp / name).write_bytes(data)
        if target.exists():
            old = Path(tempfile.mkdtemp(prefix=f".old-{target.name}-", dir=target.parent))
            os.replace(target, old / target.name)
        os.replace(tmp, target)
    except BaseException:
        if old is not None and not target.exists():
            os.replace(old / target.name, target)
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
