"""`synthleak import`: foreign meshes into the object library, in the canonical frame, with their textures."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from synthleak.assets import importer
from synthleak.assets.importer import canonical_rotation, import_model
from synthleak.core.types import Camera, RenderMesh
from synthleak.geometry.poses import look_at
from synthleak.paths import object_library_dir
from synthleak.render.raycast import pixel_rays

MEAN = np.array([200.0, 70.0, 40.0])


def _canonical_mesh() -> trimesh.Trimesh:
    """An asymmetric textured object in the canonical frame: a body and a knob on its front (+y) side."""
    body = trimesh.creation.box((0.4, 0.3, 0.5))
    body.apply_translation((0, 0, 0.25))
    knob = trimesh.creation.box((0.1, 0.1, 0.1))
    knob.apply_translation((0.1, 0.2, 0.35))
    mesh = trimesh.util.concatenate([body, knob])
    lo, hi = mesh.bounds
    mesh.apply_translation(-np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]))  # bottom centre
    rng = np.random.default_rng(3)
    texture = np.clip(MEAN + rng.integers(-30, 31, (32, 32, 3)), 0, 255).astype(np.uint8)
    mesh.visual = trimesh.visual.TextureVisuals(uv=rng.random((len(mesh.vertices), 2)), image=Image.fromarray(texture))
    return mesh


def _library(tmp_path: Path) -> Path:
    lib = tmp_path / "library"
    lib.mkdir()
    shutil.copy(object_library_dir() / "stool_round.toml", lib / "stool_round.toml")  # a parametric model
    return lib


def _snapshot(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _export(tmp_path: Path, suffix: str, front: str = "-z") -> tuple[Path, trimesh.Trimesh]:
    """The canonical mesh written as a y-up, front -z (or ``front``), centimetre file with an offset."""
    canon = _canonical_mesh()
    rotation = canonical_rotation("y", front)  # canonical_from_file
    source = canon.copy()
    source.vertices = (np.asarray(canon.vertices) @ rotation) / 0.01 + np.array([120.0, -35.0, 48.0])
    path = tmp_path / f"chair{suffix}"
    source.export(path)
    return path, canon


def _nearest(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    d = np.linalg.norm(a[:, None, :] - b[None, :, :], axis=-1)
    return d.min(axis=1), d.argmin(axis=1)


def _render_colours(parts, camera: Camera, pose: np.ndarray) -> np.ndarray:
    """Colours seen at the hit pixels: exact ray cast + barycentric UV + nearest texel lookup."""
    mesh = trimesh.Trimesh(parts[0].vertices, parts[0].faces, process=False)
    origin, dirs = pixel_rays(camera, pose)
    tri, ray, loc = mesh.ray.intersects_id(
        np.broadcast_to(origin, dirs.shape), dirs, multiple_hits=False, return_locations=True
    )
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[tri], loc)
    uv = np.einsum("ij,ijk->ik", bary, parts[0].uv[parts[0].faces[tri]])
    tex = parts[0].texture
    h, w = tex.shape[:2]
    col = np.clip(((1.0 - uv[:, 1]) * h).astype(int), 0, h - 1)
    row = np.clip((uv[:, 0] * w).astype(int), 0, w - 1)
    return tex[col, row].astype(np.float64)


@pytest.mark.parametrize("suffix", [".obj", ".glb"])
def test_import_round_trip(tmp_path, suffix) -> None:
    from synthleak.assets.library import load_library

    lib = _library(tmp_path)
    path, canon = _export(tmp_path, suffix)
    model = import_model(path, "chair", name="my_chair", up="y", front="-z", units="cm", library_dir=lib)
    assert model.builder == "imported" and model.category == "chair" and model.params == {}
    assert np.allclose(model.size, canon.extents, atol=1e-9)
    mesh = model.build()
    verts = np.concatenate([p.vertices for p in mesh.parts])
    dist, idx = _nearest(verts, np.asarray(canon.vertices))
    assert dist.max() < 1e-6  # equals the original in the canonical frame
    dist_back, _ = _nearest(np.asarray(canon.vertices), verts)
    assert dist_back.max() < 1e-6
    uv = np.concatenate([p.uv for p in mesh.parts])
    assert np.abs(uv - np.asarray(canon.visual.uv)[idx]).max() < 1e-6  # UVs kept
    lo, hi = mesh.bounds()
    assert np.allclose([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], 0.0, atol=1e-12)
    assert load_library(lib)["my_chair"].source == model.source
    # renders with its texture: the mean colour over its mask is the texture's mean colour
    camera = Camera.from_hfov(64, 48, 50.0)
    colours = _render_colours(mesh.parts, camera, look_at((0.9, 1.6, 0.9), (0.0, 0.0, 0.25)))
    assert len(colours) > 200
    assert np.abs(colours.mean(axis=0) - mesh.parts[0].texture.reshape(-1, 3).mean(axis=0)).max() < 8.0
    assert np.abs(colours.mean(axis=0) - MEAN).max() < 10.0
    render_mesh = RenderMesh("m", 1, verts, mesh.parts[0].faces, uv, mesh.parts[0].texture)
    assert render_mesh.texture.dtype == np.uint8


def test_import_height_scale_and_variants(tmp_path) -> None:
    from synthleak.assets.variants import variant

    lib = _library(tmp_path)
    path, canon = _export(tmp_path, ".obj")
    model = import_model(path, "chair", up="y", front="-z", units="cm", height=1.0, library_dir=lib)
    assert model.model_id == "chair" and model.size[2] == pytest.approx(1.0)
    assert model.size[0] == pytest.approx(canon.extents[0] / canon.extents[2])
    with pytest.raises(ValueError, match="exists"):
        import_model(path, "chair", up="y", front="-z", units="cm", library_dir=lib)
    again = import_model(path, "chair", up="y", front="-z", units="cm", scale=2.0, library_dir=lib, overwrite=True)
    assert again.size[2] == pytest.approx(2 * canon.extents[2])
    v = variant(again, seed=4, magnitude=1.0, kinds=("colour", "scale"))
    built = v.build()
    assert np.allclose(built.extents(), np.asarray(again.size) * np.asarray(v.scale))
    assert not np.array_equal(built.parts[0].texture, again.build().parts[0].texture)  # recoloured
    with pytest.warns(UserWarning, match="shape variants are not available"):
        variant(again, seed=4, magnitude=1.0, kinds=("colour", "scale", "shape"))
    with pytest.raises(KeyError, match="no shape parameters"):
        again.build({"seat_height": 0.4})


def test_import_usd(tmp_path) -> None:
    """A USD file is read through synthleak's stage reader (its own metersPerUnit / upAxis applied)."""
    from test_foreign_stage import write_asset

    asset = write_asset(tmp_path)  # y up, centimetres, textured cube 40 x 20 x 60 cm standing on y = 0
    model = import_model(asset, "box", name="usd_box", library_dir=_library(tmp_path))
    assert np.allclose(sorted(model.size), [0.2, 0.4, 0.6], atol=1e-6)
    assert model.size[2] == pytest.approx(0.2)  # the stage's up axis (y) became +z
    part = model.build().parts[0]
    assert part.texture.shape == (16, 16, 3) and np.ptp(part.uv) > 0.5
    from pxr import Sdf, UsdUtils

    package = tmp_path / "box.usdz"  # the texture lives inside the package
    assert UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(asset)), str(package))
    packed = import_model(package, "box", name="usdz_box", library_dir=tmp_path / "library")
    assert np.allclose(packed.size, model.size, atol=1e-9)
    assert np.array_equal(packed.build().parts[0].texture, part.texture)


def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


BAD = {
    "no geometry": ("pts.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n", "no geometry"),
    "non-finite": ("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 1\nf 1 2 3\n", "non-finite"),
    "texture without uv": (
        "nouv.obj",
        "mtllib ok.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 1\nf 1 2 3\n",
        "no texture coordinates",
    ),
    "missing texture": (
        "miss.obj",
        "mtllib miss.mtl\nusemtl m\nv 0 0 0\nv 1 0 0\nv 0 1 1\nvt 0 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n",
        "missing",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_leave_the_library_unchanged(tmp_path, case) -> None:
    lib = _library(tmp_path)
    import_model(_export(tmp_path, ".obj")[0], "chair", name="kept", library_dir=lib)
    before = _snapshot(lib)
    Image.fromarray(np.zeros((4, 4, 3), np.uint8)).save(tmp_path / "ok.png")
    _write(tmp_path / "ok.mtl", "newmtl m\nKd 1 0 0\nmap_Kd ok.png\n")
    _write(tmp_path / "miss.mtl", "newmtl m\nKd 1 0 0\nmap_Kd not_there.png\n")
    name, text, message = BAD[case]
    path = _write(tmp_path / name, text)
    with pytest.raises(ValueError, match=message) as info:
        import_model(path, "chair", library_dir=lib)
    assert str(path) in str(info.value)
    assert _snapshot(lib) == before


def test_oversize_and_flag_errors(tmp_path, monkeypatch) -> None:
    lib = _library(tmp_path)
    path, _ = _export(tmp_path, ".glb")
    before = _snapshot(lib)
    monkeypatch.setattr(importer, "MAX_IMPORT_BYTES", 100)
    with pytest.raises(ValueError, match="over the import limit") as info:
        import_model(path, "chair", library_dir=lib)
    assert str(path) in str(info.value)
    monkeypatch.undo()
    for kwargs, message in (
        ({"up": "y", "front": "y"}, "perpendicular"),
        ({"units": "furlong"}, "--units"),
        ({"height": 1.0, "scale": 2.0}, "not both"),
        ({"symmetry": "3"}, "--symmetry"),
        ({"name": "stool_round"}, "taken by a library model"),
        ({"name": "Bad Name"}, "--name"),
    ):
        with pytest.raises(ValueError, match=message):
            import_model(path, "chair", library_dir=lib, **kwargs)
    with pytest.raises(ValueError, match="unsupported format"):
        import_model(_write(tmp_path / "x.fbx", "x"), "chair", library_dir=lib)
    assert _snapshot(lib) == before
    assert not list(lib.rglob(".tmp-*"))


def test_the_library_lists_imported_models(tmp_path) -> None:
    """`synthleak import`, then `synthleak objects` (table and --json) lists the model: through the real CLI."""
    import json
    import os
    import subprocess
    import sys

    lib = _library(tmp_path)
    path, _ = _export(tmp_path, ".glb")
    env = {**os.environ, "SYNTHLEAK_OBJECT_LIBRARY": str(lib), "COLUMNS": "200"}

    def cli(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "synthleak.cli", *args], capture_output=True, text=True,
                              env=env, timeout=300)

    result = cli("import", str(path), "--category", "crate", "--name", "my_crate", "--up", "y", "--front=-z",
                 "--units", "cm")
    assert result.returncode == 0, result.stderr
    listed = cli("objects", "--json")
    assert listed.returncode == 0, listed.stderr
    rows = {row["id"]: row for row in json.loads(listed.stdout)}
    assert set(rows) == {"stool_round", "my_crate"}
    assert rows["my_crate"]["builder"] == "imported" and rows["my_crate"]["category"] == "crate"
    assert rows["my_crate"]["textures"] == {"part_000": "imported"}
    table = cli("objects")
    assert table.returncode == 0, table.stderr
    assert "my_crate" in table.stdout and "stool_round" in table.stdout and "imported" in table.stdout


@pytest.mark.parametrize(("up", "front"), [("y", "+z"), ("-y", "+z"), ("z", "+y"), ("x", "+y")])
def test_the_default_front_follows_the_up_axis(up, front) -> None:
    """glTF is y up and faces +z: --up y alone imports it; z up (the canonical frame) keeps front +y."""
    from synthleak.assets.importer import default_front

    assert default_front(up) == front
    assert np.allclose(canonical_rotation(up), canonical_rotation(up, front))


def test_import_gltf_with_only_the_up_axis(tmp_path) -> None:
    """`synthleak import model.glb --up y` (no --front): the model faces +y in the library, as it faced +z."""
    import os
    import subprocess
    import sys

    lib = _library(tmp_path)
    path, canon = _export(tmp_path, ".glb", front="+z")
    env = {**os.environ, "SYNTHLEAK_OBJECT_LIBRARY": str(lib)}
    result = subprocess.run([sys.executable, "-m", "synthleak.cli", "import", str(path), "--category", "crate",
                             "--up", "y", "--units", "cm"], capture_output=True, text=True, env=env, timeout=300)
    assert result.returncode == 0, result.stderr
    from synthleak.assets.library import load_library

    verts = np.concatenate([p.vertices for p in load_library(lib)["chair"].build().parts])
    dist, _ = _nearest(verts, np.asarray(canon.vertices))
    assert dist.max() < 1e-6  # the knob on the front (+y) side is where it was in the canonical mesh


def test_a_bad_imported_toml_names_the_file_and_the_key(tmp_path) -> None:
    """The imported builder reads its TOML with typed tables: a bad edit names the file and the key."""
    from synthleak.assets.library import load_library
    from synthleak.assets.model import BUILDERS

    assert BUILDERS["imported"].variant_kinds == ("colour", "scale")
    lib = _library(tmp_path)
    toml = Path(import_model(_export(tmp_path, ".obj")[0], "chair", name="kept", library_dir=lib).source)
    good = toml.read_text()
    for text, key in (
        (good.replace('mesh = "part_000.ply"', 'mesh = "gone.ply"'), "textures.part_000.mesh: file"),
        (good.replace('category = "chair"', 'category = ""'), "category: '' must match"),
        (good.replace('symmetry = "none"', 'symmetry = "3"'), "symmetry: unknown name '3'"),
        (good.replace('builder = "imported"', 'builder = "imported_"'), "builder: unknown builder 'imported_'"),
        (good + '\n[textures.part_001]\nmesh = "part_000.ply"\n', "textures.part_001.file: missing"),
    ):
        toml.write_text(text)
        with pytest.raises(ValueError) as info:
            load_library(lib)
        assert f"{toml}: {key}" in str(info.value)
    toml.write_text(good)
    assert load_library(lib)["kept"].textures["part_000"].mesh == "part_000.ply"
