"""Object library: every model (furniture and props) builds to its declared size with sane meshes, variants
behave, textures carry enough texture for SIFT (checked on an embree ray-cast view of each model's front)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

from synthleak.assets import primitives as prim
from synthleak.assets.builders import base as builders_base
from synthleak.assets.catalog import objects_rows, objects_table
from synthleak.assets.library import by_role, get_model, load_library
from synthleak.assets.mesh import ObjectMesh
from synthleak.assets.model import ObjectModel, ParamRange
from synthleak.assets.textures import TEXTURE_KINDS, hsv_shift, make_texture
from synthleak.assets.variants import VARIANT_KINDS, variant, variant_from_record
from synthleak.seeding import make_rng

LIB = load_library()
IDS = list(LIB)
FURNITURE = by_role(LIB, "furniture")
PROPS = by_role(LIB, "prop")
PROP_IDS = list(PROPS)


# ------------------------------------------------------------------------------------------ ray caster
def render_front(
    mesh: ObjectMesh,
    width: int = 640,
    height: int = 480,
    hfov_deg: float = 65.0,
    azimuth_deg: float = 25.0,
    elevation_deg: float = 20.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Embree ray cast of ``mesh`` seen from its front (+y side), textured by barycentric UV lookup with
    Lambert shading on a flat grey background. Returns (RGB uint8 image, object mask)."""
    V = np.concatenate([p.vertices for p in mesh.parts])
    offs = np.cumsum([0] + [len(p.vertices) for p in mesh.parts[:-1]])
    F = np.concatenate([p.faces + o for p, o in zip(mesh.parts, offs, strict=True)])
    UV = np.concatenate([p.uv for p in mesh.parts])
    part_of_face = np.concatenate([np.full(len(p.faces), i) for i, p in enumerate(mesh.parts)])
    tm = trimesh.Trimesh(V, F, process=False)
    lo, hi = mesh.bounds()
    centre = 0.5 * (lo + hi)
    radius = 0.5 * float(np.linalg.norm(hi - lo))
    az, el = np.deg2rad(azimuth_deg), np.deg2rad(elevation_deg)
    back = np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])  # camera -> +y side
    f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
    vfov_half = np.arctan(0.5 * height / f)
    fwd = -back
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])

    def fits(dist: float) -> bool:  # all bounding-box corners inside the central 90% of the image
        rel = corners - (centre + back * dist)
        zc = rel @ fwd
        return bool(
            np.all(zc > 0)
            and np.all(np.abs(rel @ right) / zc * f < 0.45 * width)
            and np.all(np.abs(rel @ up) / zc * f < 0.45 * height)
        )

    near, far = 0.0, radius / np.sin(vfov_half) * 1.05
    for _ in range(30):  # the closest distance at which the whole box is in view
        mid = 0.5 * (near + far)
        near, far = (near, mid) if fits(mid) else (mid, far)
    eye = centre + back * far
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d = (
        fwd[None]
        + ((u.ravel() - width / 2) / f)[:, None] * right[None]
        - ((v.ravel() - height / 2) / f)[:, None] * up
    )
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    origins = np.broadcast_to(eye, d.shape)
    tri, ray, loc = RayMeshIntersector(tm).intersects_id(
        origins, d, multiple_hits=False, return_locations=True
    )
    img = np.full((height * width, 3), 128.0)
    bary = trimesh.triangles.points_to_barycentric(tm.triangles[tri], loc)
    uv = np.einsum("ij,ijk->ik", bary, UV[F[tri]])
    normals = tm.face_normals[tri]
    normals *= -np.sign(np.einsum("ij,ij->i", normals, d[ray]))[:, None]
    light = np.array([-0.4, 0.6, 0.7])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(normals @ light, 0, 1)
    for pi, part in enumerate(mesh.parts):
        sel = part_of_face[tri] == pi
        th, tw = part.texture.shape[:2]
        col = np.clip(np.rint(uv[sel, 0] * (tw - 1)), 0, tw - 1).astype(int)
        row = np.clip(np.rint((1 - uv[sel, 1]) * (th - 1)), 0, th - 1).astype(int)
        img[ray[sel]] = part.texture[row, col] * shade[sel, None]
    mask = np.zeros(height * width, bool)
    mask[ray] = True
    return np.clip(img, 0, 255).astype(np.uint8).reshape(height, width, 3), mask.reshape(height, width)


def sift_count(img: np.ndarray) -> int:
    return len(cv2.SIFT_create().detect(cv2.cvtColor(img, cv2.COLOR_RGB2GRAY), None))


# ------------------------------------------------------------------------------------------ library
def test_library_size_and_categories():
    assert len(FURNITURE) >= 30
    assert len({m.category for m in FURNITURE.values()}) >= 12
    assert sorted(IDS) == IDS
    assert len(FURNITURE) + len(PROPS) == len(LIB)
    for m in LIB.values():
        assert m.symmetry in {"none", "2", "4", "z"}
        assert m.support in {"floor", "wall", "ceiling", "surface"}
        assert Path(m.source).is_file()
    supports = {m.support for m in FURNITURE.values()}
    assert supports == {"floor", "wall", "ceiling", "surface"}
    for m in FURNITURE.values():  # furniture files live at the top level (or imported/), without a role key
        assert Path(m.source).parent.name != "props", m.model_id


def test_get_model_unknown_lists_close_names():
    assert get_model(IDS[0]).model_id == IDS[0]
    with pytest.raises(KeyError, match="chair"):
        get_model("chair_ladderbak")


def _write(tmp_path: Path, text: str) -> Path:
    (tmp_path / "bad.toml").write_text(text)
    return tmp_path


GOOD = Path(LIB["chair_ladderback"].source).read_text()


@pytest.mark.parametrize(
    "edit,key",
    [
        (lambda s: s.replace('symmetry = "none"', 'symmetry = "3"'), "symmetry"),
        (
            lambda s: s.replace("seat_height = { default = 0.46,", "seat_height = { default = 0.9,"),
            "params.seat_height",
        ),
        (lambda s: s.replace('kind = "wood"', 'kind = "woood"'), "textures.frame.kind"),
        (
            lambda s: s.replace("[params]", "[params]\nbogus = { default = 1, min = 0, max = 2 }"),
            "params.bogus",
        ),
        (lambda s: s.replace("size = [0.46, 0.50, 0.92]", "size = [0.46, 0.50]"), "size"),
        (lambda s: s.replace('builder = "chair_ladderback"', 'builder = "chair_ladder"'), "builder"),
        (lambda s: s.replace('support = "floor"\n', ""), "support: missing"),
        (lambda s: s.replace('id = "chair_ladderback"', 'id = "Chair"'), "id: 'Chair' must match"),
        (lambda s: s.replace('kind = "wood"', 'kind = "wood"\ntexel_scale = 20'), "textures.frame.texel_scale: must"),
        (lambda s: s.replace('kind = "wood"', 'kind = "wood"\nsku = "laminate/birch"'), "textures.frame.sku"),
        (lambda s: s.replace('kind = "wood"', 'kind = "wood"\nshine = 1'), "textures.frame.shine: unknown key"),
        (lambda s: s.replace("seat_height = { default = 0.46,", "seat_height = { default = true,"),
         "params.seat_height.default: expected a number"),
        (lambda s: s.replace("scale_range = [0.92, 1.08]", "scale_range = [1.1, 1.2]"), "scale_range: need 0 < min"),
        (lambda s: s + "\n[imported]\nsource = 'x'\n", "imported: unknown key"),
    ],
)
def test_bad_toml_names_file_and_key(tmp_path, edit, key):
    d = _write(tmp_path, edit(GOOD))
    with pytest.raises(ValueError) as e:
        load_library(d)
    assert "bad.toml" in str(e.value) and key in str(e.value)


def test_catalog_rows_and_table():
    rows = objects_rows(LIB)
    assert [r["id"] for r in rows] == IDS
    json.dumps(rows)
    r = rows[IDS.index("chair_ladderback")]
    assert r["params"]["n_slats"]["integer"] is True and r["scale_range"] == list(
        LIB["chair_ladderback"].scale_range
    )
    assert {r["id"]: r["role"] for r in rows} == {k: m.role for k, m in LIB.items()}
    table = objects_table(LIB)
    assert table.row_count == len(LIB)
    assert "role" in [c.header for c in table.columns]
    assert f"{len(FURNITURE)} furniture, {len(PROPS)} props" in str(table.title)


# ------------------------------------------------------------------------------------------ meshes
def _check_part_mesh(part, model_id: str) -> None:
    assert part.vertices.dtype == np.float64 and part.vertices.shape[1] == 3
    assert part.faces.dtype == np.int64 and part.faces.min() >= 0 and part.faces.max() < len(part.vertices)
    assert part.uv.shape == (len(part.vertices), 2)
    assert part.uv.min() >= 0.0 and part.uv.max() <= 1.0, (model_id, part.name)
    assert part.texture.dtype == np.uint8 and part.texture.ndim == 3 and part.texture.shape[2] == 3
    # every primitive is a closed, consistently wound body with outward normals (positive volume)
    tm = trimesh.Trimesh(part.vertices, part.faces, process=True)
    for body in tm.split(only_watertight=False):
        assert body.is_watertight, (model_id, part.name)
        assert body.is_winding_consistent, (model_id, part.name)
        assert body.volume > 0, (model_id, part.name)


@pytest.mark.parametrize("model_id", IDS)
def test_model_builds_to_declared_size(model_id):
    m = LIB[model_id]
    mesh = m.build()
    assert isinstance(mesh, ObjectMesh) and mesh.parts
    np.testing.assert_allclose(mesh.extents(), m.size, rtol=0.01)
    lo, hi = mesh.bounds()
    np.testing.assert_allclose([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], 0.0, atol=1e-9)
    assert sum(len(p.faces) for p in mesh.parts) < 20000
    for part in mesh.parts:
        _check_part_mesh(part, model_id)
        assert 256 <= part.texture.shape[0] <= 512 and part.texture.shape[0] == part.texture.shape[1]
    # every material slot the toml declares is used by the builder
    assert {p.name for p in mesh.parts} == set(m.textures)


def test_shape_extremes_keep_declared_size_and_closed_meshes():
    """Builders' rule: shape parameters change proportions inside the declared box, never the box."""
    for m in LIB.values():
        for pick in (lambda r: r.min, lambda r: r.max):
            mesh = m.build({k: pick(r) for k, r in m.params.items()})
            np.testing.assert_allclose(mesh.extents(), m.size, rtol=0.01, err_msg=m.model_id)
            for part in mesh.parts:
                assert np.isfinite(part.vertices).all() and part.uv.min() >= 0 and part.uv.max() <= 1


@pytest.mark.parametrize("model_id", IDS)
def test_model_front_has_sift_keypoints(model_id):
    img, mask = render_front(LIB[model_id].build())
    assert mask.mean() > 0.03  # the object is in view (thin lamps cover ~4%)
    n = sift_count(img)
    assert n >= 150, f"{model_id}: only {n} SIFT keypoints on its front view"


def test_support_surfaces_inside_object():
    kinds_with_tops = {"table", "coffee_table", "side_table", "bedside_table", "shelf", "cupboard", "desk"}
    for m in LIB.values():
        v = variant(m, 0, 0.0)
        ext = v.extents()
        for s in v.support_surfaces():
            assert 0 < s.z <= ext[2] + 1e-9
            assert -ext[0] / 2 - 1e-9 <= s.x_min < s.x_max <= ext[0] / 2 + 1e-9
            assert -ext[1] / 2 - 1e-9 <= s.y_min < s.y_max <= ext[1] / 2 + 1e-9
        if m.category in kinds_with_tops:
            assert v.support_surfaces(), m.model_id
        if m.category in {"chair", "stool", "lamp", "bicycle", "wall_hanging", "vase"}:
            assert not v.support_surfaces(), m.model_id


def test_wall_and_ceiling_conventions():
    for m in LIB.values():
        mesh = m.build()
        V = np.concatenate([p.vertices for p in mesh.parts])
        if m.support == "wall":  # a flat back at y = -depth / 2
            tm = trimesh.Trimesh(
                V,
                np.concatenate(
                    [
                        p.faces + o
                        for p, o in zip(
                            mesh.parts,
                            np.cumsum([0] + [len(p.vertices) for p in mesh.parts[:-1]]),
                            strict=True,
                        )
                    ]
                ),
            )
            back = np.abs(tm.triangles_center[:, 1] + m.size[1] / 2) < 1e-6
            assert tm.area_faces[back].sum() > 0.3 * m.size[0] * m.size[2] * 0.5, m.model_id
        if m.support == "ceiling":  # a flat top (canopy) at z = height
            top = np.abs(V[:, 2] - m.size[2]) < 1e-6
            assert top.sum() >= 3, m.model_id


# ------------------------------------------------------------------------------------------ variants
def test_variant_magnitude_zero_is_the_model():
    for mid in IDS:
        m = LIB[mid]
        base = m.build()
        v = variant(m, seed=11, magnitude=0.0)
        assert v.scale == (1.0, 1.0, 1.0) and v.colour_shift == (0.0, 0.0, 0.0)
        assert v.shape_params == m.default_params()
        built = v.build()
        assert len(built.parts) == len(base.parts)
        for a, b in zip(base.parts, built.parts, strict=True):
            assert np.array_equal(a.vertices, b.vertices) and np.array_equal(a.faces, b.faces)
            assert np.array_equal(a.uv, b.uv)
            assert a.texture.tobytes() == b.texture.tobytes()


def test_variant_parameters_in_range_and_growing():
    mags = [0.1, 0.25, 0.5, 0.75, 1.0, 1.5]
    for mid in IDS:
        m = LIB[mid]
        prev = None
        for mag in mags:
            vs = [variant(m, seed, mag) for seed in range(6)]
            for v in vs:
                for k, val in v.shape_params.items():
                    r = m.params[k]
                    assert r.min <= val <= r.max
                    if r.integer:
                        assert val == round(val)
                lo, hi = m.scale_range
                assert all(lo <= s <= hi for s in v.scale)
                assert all(abs(c) <= r + 1e-12 for c, r in zip(v.colour_shift, m.colour_range, strict=True))
                if m.symmetry in ("z", "4"):
                    assert v.scale[0] == v.scale[1]
            dev = (
                np.mean([np.abs(np.asarray(v.scale) - 1).mean() for v in vs]),
                np.mean([np.abs(v.colour_shift).mean() for v in vs]),
                np.mean(
                    [
                        np.mean(
                            [
                                abs(v.shape_params[k] - r.default) / max(r.max - r.min, 1e-9)
                                for k, r in m.params.items()
                            ]
                            or [0.0]
                        )
                        for v in vs
                    ]
                ),
            )
            if prev is not None:
                assert dev[0] >= prev[0] and dev[1] >= prev[1] and dev[2] >= prev[2] - 1e-12
                if mag <= 1.0:
                    assert dev[0] > prev[0] and dev[1] > prev[1]
            prev = dev


def test_variant_kinds_alone_and_together():
    m = LIB["chair_ladderback"]
    only_colour = variant(m, 5, 0.8, ["colour"])
    assert only_colour.scale == (1.0, 1.0, 1.0) and only_colour.shape_params == m.default_params()
    assert any(only_colour.colour_shift)
    np.testing.assert_array_equal(only_colour.build().parts[0].vertices, m.build().parts[0].vertices)
    assert only_colour.build().parts[0].texture.tobytes() != m.build().parts[0].texture.tobytes()
    only_scale = variant(m, 5, 0.8, ["scale"])
    assert only_scale.colour_shift == (0.0, 0.0, 0.0) and only_scale.scale != (1.0, 1.0, 1.0)
    np.testing.assert_allclose(only_scale.extents(), np.asarray(m.size) * only_scale.scale, rtol=1e-9)
    only_shape = variant(m, 5, 0.8, ["shape"])
    assert only_shape.shape_params != m.default_params() and only_shape.scale == (1.0, 1.0, 1.0)
    together = variant(m, 5, 0.8)
    assert together.scale == only_scale.scale and together.colour_shift == only_colour.colour_shift
    assert together.shape_params == only_shape.shape_params
    with pytest.raises(ValueError):
        variant(m, 5, 0.5, ["texture"])
    with pytest.raises(ValueError):
        variant(m, 5, -0.1)


def test_variant_record_roundtrip_and_determinism():
    for mid in IDS[::3]:
        m = LIB[mid]
        v = variant(m, 42, 0.7)
        rec = json.loads(json.dumps(v.record()))
        assert rec["model_id"] == mid and rec["seed"] == 42 and rec["kinds"] == list(VARIANT_KINDS)
        assert set(rec["shape_params"]) == set(m.params)
        again = variant(m, 42, 0.7)
        rebuilt = variant_from_record(rec, LIB)
        a, b, c = v.build(), again.build(), rebuilt.build()
        for pa, pb, pc in zip(a.parts, b.parts, c.parts, strict=True):
            assert np.array_equal(pa.vertices, pb.vertices) and np.array_equal(pa.vertices, pc.vertices)
            assert pa.texture.tobytes() == pb.texture.tobytes() == pc.texture.tobytes()
        other = variant(m, 43, 0.7)
        assert other.record() != v.record()


def test_scaled_variant_support_surfaces_follow_scale():
    m = LIB["table_dining"]
    v0, v = variant(m, 3, 0.0), variant(m, 3, 1.0, ["scale"])
    (s0,), (s1,) = v0.support_surfaces(), v.support_surfaces()
    assert s1.z == pytest.approx(s0.z * v.scale[2]) and s1.x_max == pytest.approx(s0.x_max * v.scale[0])
    assert s0.z == pytest.approx(m.size[2])


# ------------------------------------------------------------------------------------------ textures
@pytest.mark.parametrize("kind", TEXTURE_KINDS)
def test_texture_kinds(kind):
    t1 = make_texture(kind, make_rng(1, kind), (0.6, 0.4, 0.3), 256)
    t2 = make_texture(kind, make_rng(1, kind), (0.6, 0.4, 0.3), 256)
    assert t1.dtype == np.uint8 and t1.shape == (256, 256, 3)
    assert t1.tobytes() == t2.tobytes()
    assert t1.std() > 2.0  # not a flat colour
    if kind != "glass":
        assert sift_count(make_texture(kind, make_rng(2, kind), (0.6, 0.4, 0.3), 512)) >= 40, kind


def test_texture_errors_and_hsv_shift():
    with pytest.raises(ValueError):
        make_texture("chrome", make_rng(0), (0.5, 0.5, 0.5))
    t = make_texture("pattern", make_rng(0), (0.2, 0.4, 0.7), 256)
    assert hsv_shift(t, 0, 0, 0).tobytes() == t.tobytes()
    s = hsv_shift(t, 0.5, 0.0, 0.0)
    assert s.shape == t.shape and s.dtype == np.uint8 and np.abs(s.astype(int) - t).mean() > 10
    brighter = hsv_shift(t, 0.0, 0.0, 0.2)
    assert brighter.mean() > t.mean()


# ------------------------------------------------------------------------------------------ primitives
def test_primitives_closed_and_uv_density():
    tex = np.zeros((64, 64, 3), np.uint8)
    parts = [
        prim.box("b", (2.3, 0.4, 0.1), (0, 0, 0), tex, texel_scale=0.5),
        prim.cylinder("c", 0.3, 1.0, (0, 0, 0), tex, texel_scale=0.5),
        prim.torus("t", 0.4, 0.05, (0, 0, 0), tex, texel_scale=0.5),
        prim.sphere("s", 0.2, (0, 0, 0), tex),
        prim.rounded_box("r", (1.2, 0.6, 0.2), (0, 0, 0), 0.05, tex, texel_scale=0.5),
        prim.bar("bar", (0, 0, 0), (0.3, 0.4, 1.0), 0.02, tex),
        prim.revolve(
            "v", [(0, 0), (0.1, 0), (0.12, 0.2), (0.05, 0.3), (0.045, 0.3), (0.1, 0.02), (0, 0.02)], tex
        ),
        prim.extrude("e", [(0, 0), (1, 0), (0.5, 0.8)], 0.1, tex),
    ]
    path = [(0.1 * np.cos(t), 0.0, 0.2 + 0.1 * np.sin(t)) for t in np.linspace(-np.pi / 2, np.pi / 2, 9)]
    parts.append(prim.tube("tube", path, 0.01, tex, segments=8))
    for p in parts:
        _check_part_mesh(p, "primitive")
    # a planar tube with segments % 4 == 0 has ring points exactly in and across its plane: at the apex of
    # the arc (tangent along z) the tube reaches x = 0.1 + r exactly, and y spans exactly +-r
    tube = parts[-1]
    np.testing.assert_allclose(tube.vertices[:, 0].max(), 0.11, atol=1e-12)
    np.testing.assert_allclose([tube.vertices[:, 1].min(), tube.vertices[:, 1].max()], [-0.01, 0.01], atol=1e-12)
    assert 0.09 <= tube.vertices[:, 2].min() < 0.1 and 0.3 < tube.vertices[:, 2].max() <= 0.31
    with pytest.raises(ValueError, match="repeated"):
        prim.tube("bad", [(0, 0, 0), (0, 0, 0), (1, 0, 0)], 0.01, tex)
    # density: on the long box the texture spans <= texel_scale metres per unit of uv (no smearing)
    b = parts[0]
    tri = b.vertices[b.faces]
    uvt = b.uv[b.faces]
    e3 = np.linalg.norm(tri[:, 1] - tri[:, 0], axis=1)
    e2 = np.linalg.norm(uvt[:, 1] - uvt[:, 0], axis=1)
    ok = e2 > 1e-9
    np.testing.assert_allclose(e3[ok] / e2[ok], 0.5, rtol=0.01)
    np.testing.assert_allclose(b.vertices.max(0) - b.vertices.min(0), (2.3, 0.4, 0.1))


def test_param_range_dataclass():
    r = ParamRange(3, 2, 5, integer=True)
    assert r.clip(4.6) == 5 and r.clip(9) == 5
    assert isinstance(LIB["bookcase"], ObjectModel)
    with pytest.raises(KeyError):
        LIB["bookcase"].build({"n_shelfs": 3})


# ------------------------------------------------------------------------------------------ props
PROP_CATEGORIES = {
    "book",
    "magazine",
    "box",
    "cushion",
    "rug",
    "poster",
    "framed_print",
    "cup",
    "bowl",
    "basket",
    "plant_prop",
    "shoes",
    "bin",
    "bottle",
    "candle",
    "laptop",
    "toy",
    "blanket",
}


def test_prop_library():
    """At least 18 props, all in ``object_library/props/``, in prop categories of their own, on floors,
    surfaces and walls."""
    assert len(PROPS) >= 18
    for m in PROPS.values():
        assert m.role == "prop" and Path(m.source).parent.name == "props", m.model_id
        assert m.support in {"floor", "surface", "wall"}, m.model_id
    assert {m.category for m in PROPS.values()} == PROP_CATEGORIES
    assert not PROP_CATEGORIES & {m.category for m in FURNITURE.values()}
    assert {m.support for m in PROPS.values()} == {"floor", "surface", "wall"}
    for m in PROPS.values():
        if m.category == "rug":  # flat floor coverings of 1.2-2.4 m at every scale
            assert m.support == "floor" and m.size[2] * m.scale_range[1] <= 0.02
            assert max(m.size[:2]) * m.scale_range[0] >= 1.2 and max(m.size[:2]) * m.scale_range[1] <= 2.4
        if m.category in {"poster", "framed_print"}:
            assert m.support == "wall"


@pytest.mark.parametrize("model_id", PROP_IDS)
def test_prop_builds_exactly_small_and_textured(model_id):
    """Extents == size at the defaults and at the min and max of every shape parameter, bottom-centre
    origin, closed parts, < 2,000 triangles, every material drawn with its texture, no support surfaces."""
    m = PROPS[model_id]
    for pick in (None, lambda r: r.min, lambda r: r.max):
        params = None if pick is None else {k: pick(r) for k, r in m.params.items()}
        mesh = m.build(params)
        np.testing.assert_allclose(mesh.extents(), m.size, rtol=1e-9, atol=1e-12, err_msg=model_id)
        lo, hi = mesh.bounds()
        np.testing.assert_allclose([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], 0.0, atol=1e-12)
        assert sum(len(p.faces) for p in mesh.parts) < 2000, model_id
        assert {p.name for p in mesh.parts} == set(m.textures), model_id
        for part in mesh.parts:
            _check_part_mesh(part, model_id)
            assert part.texture.shape == (m.texture_size, m.texture_size, 3)
            assert part.texture.tobytes() == m.material_texture(part.name).tobytes()
    assert m.texture_size in (128, 256, 512)
    assert not variant(m, 0, 0.0).support_surfaces()


def test_prop_layouts_need_little_fitting(monkeypatch):
    """Builders that map their layout onto the declared box (``props._fit_box``) lay it out within 6 % of the
    box on every axis, at the defaults and at the parameter extremes (no visibly stretched items)."""
    from synthleak.assets.builders import props

    ratios: list[np.ndarray] = []
    fit = props._fit_box

    def spy(b, W, D, H):  # noqa: ANN001, ANN202, N803 - same signature as props._fit_box
        V = np.concatenate([q.vertices for qs in b.parts.values() for q in qs])
        ratios.append((V.max(0) - V.min(0)) / np.array([W, D, H]))
        return fit(b, W, D, H)

    monkeypatch.setattr(props, "_fit_box", spy)
    for m in PROPS.values():
        for pick in (None, lambda r: r.min, lambda r: r.max):
            ratios.clear()
            m.build(None if pick is None else {k: pick(r) for k, r in m.params.items()})
            for r in ratios:
                assert np.all(np.abs(r - 1) <= 0.06), (m.model_id, r)


def _props_dir_with(tmp_path: Path, text: str) -> Path:
    (tmp_path / "props").mkdir()
    (tmp_path / "props" / "bad.toml").write_text(text)
    return tmp_path


def test_prop_role_key_is_checked(tmp_path):
    good = Path(PROPS["mug"].source).read_text()
    assert 'role = "prop"' in good
    d = _props_dir_with(tmp_path, good.replace('role = "prop"\n', ""))  # a props/ model must say it is one
    with pytest.raises(ValueError) as e:
        load_library(d)
    assert "bad.toml: role:" in str(e.value)
    (d / "props" / "bad.toml").write_text(good.replace('role = "prop"', 'role = "clutter"'))
    with pytest.raises(ValueError, match="role"):
        load_library(d)
    (d / "props" / "bad.toml").write_text(good)
    shutil.copy(LIB["chair_ladderback"].source, d / "chair_ladderback.toml")
    lib = load_library(d)
    assert [(k, m.role) for k, m in lib.items()] == [("chair_ladderback", "furniture"), ("mug", "prop")]
    (d / "mug.toml").write_text(good)  # ids are unique over the top level and props/
    with pytest.raises(ValueError, match="duplicate id 'mug'"):
        load_library(d)


def test_by_role():
    assert by_role(LIB, "prop") == PROPS and list(by_role(LIB, "furniture")) == list(FURNITURE)
    with pytest.raises(ValueError, match="role"):
        by_role(LIB, "clutter")


def test_objects_cli_lists_props_with_role(capsys):
    from synthleak.cli import main

    assert main(["objects", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    roles = {r["id"]: r["role"] for r in rows}
    assert roles == {k: m.role for k, m in LIB.items()}
    assert {k for k, r in roles.items() if r == "prop"} == set(PROPS)
    assert main(["objects", "--json", "--role", "prop"]) == 0
    assert [r["id"] for r in json.loads(capsys.readouterr().out)] == PROP_IDS
    assert main(["objects", "--role", "prop"]) == 0  # captured stdout is no terminal: a header, a line per model
    header, *lines = capsys.readouterr().out.splitlines()
    role = header.split("\t").index("role")
    assert [line.split("\t")[0] for line in lines] == PROP_IDS
    assert {line.split("\t")[role] for line in lines} == {"prop"}


def test_library_loaded_twice_builds_identical_meshes():
    """Determinism: a fresh load with a cold texture cache rebuilds every prop byte for byte (textures from
    the model id, layouts from the per-model builder rng)."""
    first = {k: m.build() for k, m in PROPS.items()}
    builders_base._cached_texture.cache_clear()
    again = by_role(load_library(), "prop")
    assert list(again) == PROP_IDS
    for k, mesh in first.items():
        other = again[k].build()
        assert [p.name for p in mesh.parts] == [p.name for p in other.parts]
        for a, b in zip(mesh.parts, other.parts, strict=True):
            assert a.vertices.tobytes() == b.vertices.tobytes() and a.faces.tobytes() == b.faces.tobytes()
            assert a.uv.tobytes() == b.uv.tobytes() and a.texture.tobytes() == b.texture.tobytes()
