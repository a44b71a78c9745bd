"""The hard world: shared material SKUs, distractors, clutter, home layouts, furniture views, close-ups."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from synthleak.assets.library import load_library
from synthleak.assets.materials import FAMILIES, UNIQUE, assign_materials, model_skus, with_materials
from synthleak.assets.variants import variant, variant_from_record
from synthleak.config import load_config
from synthleak.core.types import Camera, InstanceInfo, Light, RenderMesh, RenderScene
from synthleak.geometry.poses import look_at, make_pose
from synthleak.render.mitsuba_backend import MitsubaRenderer
from synthleak.scene.generate import write_study_stages

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def library():
    return load_library()


def _config(base: str = "ci-tiny", **scenes):
    config = load_config(base)
    return dataclasses.replace(config, scenes=dataclasses.replace(config.scenes, **scenes))


# ------------------------------------------------------------------------------------------ clean world


def test_clean_knobs_give_the_stages_of_before(tmp_path):
    """material_sharing 0, no distractors, no clutter, scatter layout: the stages of before the knobs existed,
    byte for byte (the library pinned to the models it had then)."""
    expected = json.loads((DATA / "ci-tiny-clean-stages.json").read_text())
    config = _config(models=expected["models"], material_sharing=0.0, distractors=(0, 0), clutter=0.0,
                     layout="scatter")
    write_study_stages(config, tmp_path, progress=False)
    files = {p.relative_to(tmp_path).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
             for p in sorted(tmp_path.rglob("*")) if p.is_file()}
    assert files == expected["files"]


# ------------------------------------------------------------------------------------------ materials


def test_material_assignment_is_seeded_and_nested(library):
    furniture = [m for m in library.values() if getattr(m, "role", "furniture") == "furniture"]
    low = {m.model_id: assign_materials(m, 3, 0.3) for m in furniture}
    high = {m.model_id: assign_materials(m, 3, 0.8) for m in furniture}
    assert low == {m.model_id: assign_materials(m, 3, 0.3) for m in furniture}  # deterministic
    shared_low = {(mid, s) for mid, a in low.items() for s, sku in a.items() if sku != UNIQUE}
    shared_high = {(mid, s) for mid, a in high.items() for s, sku in a.items() if sku != UNIQUE}
    assert shared_low < shared_high  # a slot shared at 0.3 stays shared, with the same SKU, at 0.8
    assert all(low[mid][s] == high[mid][s] for mid, s in shared_low)
    assert not any(sku != UNIQUE for m in furniture for sku in assign_materials(m, 3, 0.0).values())
    other_seed = {m.model_id: assign_materials(m, 4, 0.8) for m in furniture}
    assert other_seed != high
    # SKUs are shared between models: with sharing 1 some SKU appears on several models
    everything = [sku for m in furniture for sku in assign_materials(m, 3, 1.0).values() if sku != UNIQUE]
    assert max(everything.count(s) for s in set(everything)) >= 3


def test_sku_textures_are_one_texture_and_recorded(library):
    a = with_materials(library["table_coffee"], {"top": "laminate/oak_natural"})
    b = with_materials(library["table_side"], {"top": "laminate/oak_natural"})
    assert a.material_texture("top") is b.material_texture("top")
    assert not np.array_equal(a.material_texture("legs"), b.material_texture("legs"))
    assert a.textures["top"].texel_scale == FAMILIES["laminate"][0].texel_scale
    v = variant(a, seed=11, magnitude=0.5)
    record = v.record()
    assert record["materials"] == {"top": "laminate/oak_natural"} == model_skus(a)
    rebuilt = variant_from_record(record, library)
    np.testing.assert_array_equal(rebuilt.build().parts[0].texture, v.build().parts[0].texture)
    # a colour variant still recolours the shared texture
    assert not np.array_equal(v.build().parts[0].texture, variant(a, 11, 0.0).build().parts[0].texture)
    with pytest.raises(KeyError, match="no material slot"):
        with_materials(library["table_side"], {"seat": "laminate/birch"})


def _top_view(model, renderer: MitsubaRenderer, camera: Camera) -> np.ndarray:
    """A render looking straight down at the model's top from 0.6 m above it (the top fills the view)."""
    mesh = variant(model, 0, 0.0).build()
    meshes = [RenderMesh(p.name, 100, p.vertices, p.faces, p.uv, p.texture, roughness=p.roughness)
              for p in mesh.parts]
    height = float(mesh.extents()[2])
    info = InstanceInfo(100, model.model_id, model.model_id, model.category, "none", "object", np.eye(4),
                        mesh.extents())
    light = Light("sun", "sphere", make_pose(np.eye(3), [0.3, -0.4, height + 2.0]), 20.0)
    scene = RenderScene(meshes, [light], {100: info}, ambient=0.3)
    renderer.prepare(scene)
    eye = np.array([0.0, 0.0, height + 0.6])
    return renderer.render(camera, look_at(eye, eye - [0.0, 0.0, 1.0], up=(0.0, 1.0, 0.0)), 0).rgb


def _homography_inliers(img_a: np.ndarray, img_b: np.ndarray) -> int:
    sift = cv2.SIFT_create(4000)
    ka, da = sift.detectAndCompute(cv2.cvtColor(img_a, cv2.COLOR_RGB2GRAY), None)
    kb, db = sift.detectAndCompute(cv2.cvtColor(img_b, cv2.COLOR_RGB2GRAY), None)
    if da is None or db is None:
        return 0
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [m for m, n in (p for p in pairs if len(p) == 2) if m.distance < 0.8 * n.distance]
    if len(good) < 4:
        return 0
    src = np.float32([ka[m.queryIdx].pt for m in good])
    dst = np.float32([kb[m.trainIdx].pt for m in good])
    _, mask = cv2.findHomography(src, dst, cv2.USAC_MAGSAC, 3.0, maxIters=5000, confidence=0.9999)
    return int(mask.sum()) if mask is not None else 0


def test_shared_sku_gives_shared_local_features(library):
    """Two products sharing a laminate show the same print: SIFT matches between renders of their tops verified
    by a homography; with their own textures they share (almost) nothing."""
    renderer = MitsubaRenderer(spp=4, integrator="direct", max_depth=2)
    camera = Camera.from_hfov(640, 480, 65.0)
    shared = {"top": "laminate/oak_natural"}  # dark and white foils have less texture: fewer matches
    coffee, side = library["table_coffee"], library["table_side"]
    same = _homography_inliers(_top_view(with_materials(coffee, shared), renderer, camera),
                               _top_view(with_materials(side, shared), renderer, camera))
    unique = _homography_inliers(_top_view(coffee, renderer, camera), _top_view(side, renderer, camera))
    assert same >= 100, same
    assert unique < 10, unique


# ------------------------------------------------------------------------------------------ scenes


@pytest.fixture(scope="module")
def hard_stages(tmp_path_factory):
    config = _config(material_sharing=1.0, distractors=(2, 2), clutter=1.5, layout="home")
    out = tmp_path_factory.mktemp("hard-stages")
    write_study_stages(config, out, progress=False)
    return config, out, json.loads((out / "index.json").read_text())


def test_distractors_are_never_attacker_objects(hard_stages, library):
    _, _, index = hard_stages
    attacked = {a["model_id"] for a in index["attacker_objects"]}
    categories = {library[m].category for m in attacked}
    skus = {s for a in index["attacker_objects"] for s in a.get("skus", {}).values()}
    for room in index["rooms"]:
        assert room["distractors"], room["name"]
        for d in room["distractors"]:
            assert d["model_id"] not in attacked
            assert 300 <= d["instance_id"] < 1000
            # look-alikes first: the selected models' categories or SKUs
            assert d["category"] in categories or skus & set(d.get("skus", {}).values())
        present = {o["model_id"] for o in room["objects"]}
        for a in index["attacker_objects"]:
            assert (room["name"] in a["present_in"]) == (a["model_id"] in present)


def test_skus_are_recorded_in_index_stage_and_attacker(hard_stages):
    from synthleak.scene.usd_read import read_scene_spec

    _, out, index = hard_stages
    by_model = {a["model_id"]: a for a in index["attacker_objects"]}
    room = index["rooms"][0]
    spec = read_scene_spec(out / room["stage"])
    recorded = {o.instance_id: o.variant_params.get("materials", {}) for o in spec.objects}
    for obj in room["objects"]:
        assert obj["skus"] == recorded[obj["instance_id"]] == by_model[obj["model_id"]]["skus"]
    attacker = read_scene_spec(out / by_model[room["objects"][0]["model_id"]]["stage"])
    target = next(o for o in attacker.objects if o.instance_id == 100)
    assert target.variant_params["materials"] == room["objects"][0]["skus"]


def _room_spec(config, k: int = 0):
    from synthleak.scene.compose import compose_room
    from synthleak.scene.plan import plan_study

    library = load_library()
    return compose_room(plan_study(config, library).rooms[k], library)


def test_props_and_distractors_obey_the_placement_rules():
    """Clutter props and distractors stand on floors, hang on walls or stand on furniture tops, inside the
    room, without intersecting anything (rugs excepted: furniture stands on them)."""
    from test_scene import _check_room

    config = _config(material_sharing=1.0, distractors=(2, 3), clutter=2.0, layout="home",
                     room_size_x=(4.5, 5.0), room_size_y=(4.0, 4.5))
    supports = set()
    for k in (0, 1):
        spec = _room_spec(config, k)
        props = [o for o in spec.objects if o.role == "prop"]
        assert len(props) >= 10
        assert all(o.instance_id >= 1000 for o in props)
        assert any(300 <= o.instance_id < 1000 for o in spec.objects)
        supports |= {p.support for p in props}
        supported_by = {int(i): int(h) for i, h in spec.metadata["supported_by"].items()}
        _check_room(spec.objects, spec.room_size, supported_by)
    assert supports == {"floor", "wall", "surface"}


def test_home_layout_backs_furniture_against_walls_and_faces_chairs_to_tables():
    """Cupboards, beds, sofas, shelves, desks stand with their back to a wall, facing the room; chairs at a
    table face it; yaws follow the walls."""
    from synthleak.scene.placement import HOME_RULES

    wall_backed = {c for c, (rule, _) in HOME_RULES.items() if rule == "wall"}
    config = _config("study-small", distractors=(3, 3), layout="home", models=[
        "wardrobe", "sofa_2seat", "bookcase", "desk", "table_dining", "chair_ladderback", "chest_drawers",
        "bed_double", "chair_upholstered", "lamp_floor", "armchair"], objects_per_room=(5, 6))
    checked = at_table = 0
    for k in range(3):
        spec = _room_spec(config, k)
        x, y, _ = spec.room_size
        tables = [o for o in spec.objects if o.category in ("table", "desk")]
        for o in spec.objects:
            if o.role != "object" or o.support != "floor":
                continue
            pose = o.world_from_object
            yaw = np.degrees(np.arctan2(pose[1, 0], pose[0, 0]))
            assert min(abs((yaw - a + 180) % 360 - 180) for a in (0, 90, 180, 270)) < 10, o.name
            if o.category in wall_backed:
                back = pose[:3, :3] @ np.array([0.0, -1.0, 0.0])
                centre = pose[:3, 3] + pose[:3, :3] @ np.array([0.0, -0.5 * o.object_extents()[1], 0.0])
                gap = min(x / 2 - centre[0] if back[0] > 0.5 else np.inf, x / 2 + centre[0] if back[0] < -0.5
                          else np.inf, y / 2 - centre[1] if back[1] > 0.5 else np.inf,
                          y / 2 + centre[1] if back[1] < -0.5 else np.inf)
                assert gap < 0.1, (o.name, gap)
                checked += 1
            if o.category == "chair" and tables:
                front = pose[:3, :3] @ np.array([0.0, 1.0, 0.0])
                to_table = min((t.world_from_object[:3, 3] - pose[:3, 3] for t in tables),
                               key=lambda d: np.linalg.norm(d[:2]))
                if np.linalg.norm(to_table[:2]) < 1.5:
                    assert front[:2] @ to_table[:2] > 0, o.name
                    at_table += 1
    assert checked >= 6 and at_table >= 1


# ------------------------------------------------------------------------------------------ end to end


@pytest.fixture(scope="module")
def hard_study(tmp_path_factory):
    """The ci-tiny-hard study (shared SKUs everywhere, distractors, clutter, home layout, furniture
    walk-through, close-ups): real renders, real SIFT maps and localizations."""
    from synthleak.study import run_study

    out = tmp_path_factory.mktemp("ci-tiny-hard")
    config = load_config("ci-tiny-hard")
    run_study(config, out, progress=False, workers=1)
    return config, out


@pytest.mark.slow
def test_an_absent_object_localizes_on_an_instance_sharing_its_sku(hard_study):
    from synthleak.core.dataset import read_index
    from synthleak.evaluate.lookalikes import lookalike_ids, top_instance
    from synthleak.study import read_query_log

    _, out = hard_study
    index = read_index(out / "dataset" / "stages")
    rooms = {r["name"]: r for r in index["rooms"]}
    hits = []
    for log in sorted((out / "queries").glob("*/*/queries.jsonl")):
        for q in read_query_log(log):
            if q["genuine"] or not q["success"]:
                continue
            obj = next(a for a in index["attacker_objects"] if a["id"] == q["attacker_object"])
            if q["room"] in obj["present_in"]:
                continue
            top = top_instance(q["inlier_instance_counts"])
            if lookalike_ids(obj, rooms[q["room"]]).get(top) == "shares_sku":
                hits.append((q["room"], obj["id"], top))
    assert hits, "no absent object localized on an instance sharing its SKU"
    rows = json.loads((out / "results" / "results.json").read_text())
    absent = [r for r in rows if not r["present_gt"]]
    assert {r["absent_kind"] for r in absent} <= {"shares_sku", "same_category", "unrelated"}
    assert any(r["n_lookalike_top"] > 0 and r["absent_kind"] == "shares_sku" for r in absent)


@pytest.mark.slow
def test_hard_world_report_coverage_masks_and_bop(hard_study):
    """The walk-through sees furniture (coverage from the GT masks), props and distractors are in the masks,
    the BOP GT and the plan view, close-ups are held-out queries, and the report has the new sections."""
    from synthleak.core.dataset import load_sequence, read_index
    from synthleak.evaluate.coverage import sequence_coverage
    from synthleak.inspect.plan_view import footprints
    from synthleak.render.pipeline import load_stage

    _, out = hard_study
    index = read_index(out / "dataset" / "stages")
    for room in index["rooms"]:
        seq = load_sequence(out / "dataset" / "scenes" / room["name"])
        coverage = sequence_coverage(seq)
        assert coverage["share_below_10pct"] <= 0.10, (room["name"], coverage)
        assert coverage["closeups"] >= 1 and set(seq.split["closeup"]) <= set(seq.split["query"])
        added = {o["instance_id"] for o in room["distractors"] + room["props"]}
        assert added and any(i >= 1000 for i in added)
        seen = set()
        for frame in seq.frames:
            seen |= set(np.unique(seq.instance(frame)).tolist())
        assert len(added & seen) >= len(added) // 2, (room["name"], sorted(added - seen))
        gt = json.loads((seq.root / "bop" / "scene_gt.json").read_text())
        assert added <= {e["obj_id"] for e in gt["0"]}
        assert added <= set(footprints(load_stage(out / "dataset" / "stages" / room["stage"])))
    report = (out / "report.md").read_text()
    for section in ("## The world", "## Where presence is lost", "## Where false presence comes from",
                    "## Presence by kind of absent pair", "genuine_closeup_kept"):
        assert section in report
    world = json.loads((out / "results" / "world.json").read_text())
    assert world["knobs"]["material_sharing"] == 1.0 and len(world["rooms"]) == len(index["rooms"])


@pytest.mark.slow
def test_world_sweep_runs_a_study_per_value(tmp_path):
    """``[sweep] material_sharing`` re-makes rooms and attackers per value and reports P/R against it."""
    from synthleak.config import config_from_dict
    from synthleak.study import run_study

    config = config_from_dict({
        "name": "sweep-tiny", "seed": 3,
        "scenes": {"rooms": 2, "objects_per_room": [2, 2], "room_size_x": [3.5, 3.5], "room_size_y": [3.0, 3.0],
                   "room_height": [2.5, 2.5], "lights_per_room": [2, 2], "distractors": [1, 1], "clutter": 0.5,
                   "layout": "home"},
        "render": {"width": 160, "height": 120, "spp": 1, "scene_frames": 10, "attacker_frames": 4,
                   "walkthrough": "furniture"},
        "localize": {"tiers": ["sift"], "retrieval": "exhaustive"},
        "attack": {"aligners": ["alg1"], "thresholds": [[30.0, 0.5]]},
        "sweep": {"material_sharing": [0.0, 1.0]},
    })
    report = run_study(config, tmp_path, progress=False, workers=1)
    rows = json.loads((tmp_path / "results" / "sweep_world.json").read_text())
    assert {(r["sweep_param"], r["sweep_value"]) for r in rows} == {("material_sharing", 0.0),
                                                                   ("material_sharing", 1.0)}
    shared = [json.loads((tmp_path / "sweep" / f"material_sharing-{v}" / "dataset" / "stages" / "index.json"
                          ).read_text()) for v in ("0", "1")]
    assert not any(o.get("skus") for r in shared[0]["rooms"] for o in r["objects"])
    assert all(o.get("skus") for r in shared[1]["rooms"] for o in r["objects"])
    assert (tmp_path / "plots" / "leakage_vs_world.png").stat().st_size > 10_000
    assert "## Leakage against the hard-world knobs" in report.read_text()


def test_furniture_walkthrough_and_closeups_stand_in_free_space(tmp_path):
    """Every camera of the tour and of the close-ups stands inside the room and outside every piece of floor
    furniture, looks at something that is not the room shell, and the same seed gives the same poses."""
    from synthleak.core.usd_read import read_render_scene
    from synthleak.geometry.poses import camera_centre
    from synthleak.render.furniture_views import _floor_footprints, closeup_views, furniture_walkthrough
    from synthleak.render.raycast import RaycastGT
    from synthleak.render.trajectories import _clearance, room_bounds
    from synthleak.scene.usd_write import write_stage
    from synthleak.seeding import make_rng

    config = _config(material_sharing=0.5, distractors=(2, 2), clutter=1.0, layout="home")
    write_stage(_room_spec(config, 0), tmp_path / "room.usda")
    scene = read_render_scene(tmp_path / "room.usda")
    tour = furniture_walkthrough(scene, 30, make_rng(1, "tour"))
    again = furniture_walkthrough(scene, 30, make_rng(1, "tour"))
    assert len(tour) == 30 and all(np.array_equal(a, b) for a, b in zip(tour, again, strict=True))
    close = closeup_views(scene, 6, make_rng(1, "close"))
    assert len(close) == 6
    lo, hi = room_bounds(scene)
    footprints = _floor_footprints(scene)
    tracer = RaycastGT(scene.meshes)
    shell = [i for i, info in scene.instances.items() if info.role == "shell"]
    camera = Camera.from_hfov(64, 48, 65.0)
    for pose in [*tour, *close]:
        centre = camera_centre(pose)
        assert np.all(centre > lo + 0.2) and np.all(centre < hi - 0.2)
        assert _clearance(centre[None, :2], footprints)[0] > 0.1
        _, inst = tracer.render(camera, pose)
        assert ((inst > 0) & ~np.isin(inst, shell)).mean() > 0.05
    for pose in close:  # a close-up: the nearest furniture or prop surface in the centre of the view is near
        depth, _ = tracer.render(camera, pose)
        assert np.nanmin(np.where(np.isfinite(depth), depth, np.nan)[16:32, 20:44]) < 2.0
