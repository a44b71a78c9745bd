"""Evaluation: symmetry-aware metrics, exact 3D IoU, tables, defense sweep, plots, results files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synthleak.evaluate import plots
from synthleak.evaluate.defense_sweep import defense_tradeoff, passes_defense, qualifying_instances
from synthleak.evaluate.metrics import (
    iou_3d,
    rotation_block,
    success_at,
    success_rates,
    translation_error_m,
)
from synthleak.evaluate.tables import (
    COLUMNS,
    apply_presence_decisions,
    placement_stats,
    placement_summary,
    presence_pr_per_object,
    presence_pr_per_room,
    random_guess_precision,
    read_results,
    table1_markdown,
    table2_markdown,
    write_results,
)
from synthleak.geometry.poses import make_pose, rotation_error_deg


def rz(deg: float) -> np.ndarray:
    return Rotation.from_euler("z", deg, degrees=True).as_matrix()


R_GT = Rotation.from_euler("zyx", [33, 12, -7], degrees=True).as_matrix()

# ------------------------------------------------------------------------------------------- metrics


def test_rotation_error_symmetries():
    assert rotation_error_deg(R_GT @ rz(180), R_GT, "2") == pytest.approx(0.0, abs=1e-5)
    assert rotation_error_deg(R_GT @ rz(180), R_GT, "none") == pytest.approx(180.0, abs=1e-5)
    assert rotation_error_deg(R_GT @ rz(90), R_GT, "4") == pytest.approx(0.0, abs=1e-5)
    assert rotation_error_deg(R_GT @ rz(90), R_GT, "2") == pytest.approx(90.0, abs=1e-5)
    assert rotation_error_deg(R_GT @ rz(100), R_GT, "4") == pytest.approx(10.0, abs=1e-5)
    for angle in (17.0, 123.0, 271.0):
        assert rotation_error_deg(R_GT @ rz(angle), R_GT, "z") == pytest.approx(0.0, abs=1e-5)
    tilt = Rotation.from_euler("x", 10, degrees=True).as_matrix()
    assert rotation_error_deg(R_GT @ rz(50) @ tilt, R_GT, "z") == pytest.approx(10.0, abs=1e-5)
    as_poses = rotation_error_deg(make_pose(R_GT @ tilt, [1, 2, 3]), make_pose(R_GT, [0, 0, 0]))
    assert as_poses == pytest.approx(10.0)
    with pytest.raises(ValueError, match="symmetry"):
        rotation_error_deg(R_GT, R_GT, "3")


def test_rotation_block_divides_out_a_similarity_scale():
    sim = make_pose(2.5 * (R_GT @ rz(30)), [1, 2, 3])
    np.testing.assert_allclose(rotation_block(sim, "sim"), R_GT @ rz(30), atol=1e-12)
    assert rotation_error_deg(rotation_block(sim, "sim"), R_GT) == pytest.approx(30.0)
    with pytest.raises(ValueError, match="sim: non-finite"):
        rotation_block(np.full((4, 4), np.nan), "sim")
    with pytest.raises(ValueError, match="m: rotation block has determinant"):
        rotation_block(-np.eye(3), "m")
    with pytest.raises(ValueError, match="r_a: expected a 3x3 rotation or 4x4 pose"):
        rotation_error_deg(np.eye(2), R_GT)


def test_translation_error_uses_box_centre():
    gt = make_pose(np.eye(3), [1.0, 2.0, 0.0])
    flipped = make_pose(Rotation.from_euler("x", 180, degrees=True).as_matrix(), [1.0, 2.0, 0.0])
    # same origin, but the box hangs downwards: centres (1,2,1) vs (1,2,-1)
    assert translation_error_m(flipped, gt, [0.5, 0.5, 2.0]) == pytest.approx(2.0)
    assert translation_error_m(make_pose(np.eye(3), [1.3, 2.4, 0.0]), gt, [1, 1, 1]) == pytest.approx(0.5)
    # a smaller attacker object on the same origin: centre heights 0.5 vs 1.0
    assert translation_error_m(gt, gt, [1, 1, 2], extents_est=[1, 1, 1]) == pytest.approx(0.5)


def test_iou_3d_exact_values():
    ext = [1.0, 1.0, 1.0]
    base = make_pose(R_GT, [0.3, -0.2, 0.5])
    assert iou_3d(base, ext, base, ext) == pytest.approx(1.0, abs=1e-9)
    shifted = base.copy()
    shifted[:3, 3] += R_GT[:, 0] * 0.5  # half a box along its own x axis
    assert iou_3d(base, ext, shifted, ext) == pytest.approx(1.0 / 3.0, abs=1e-9)
    far = base.copy()
    far[:3, 3] += [5.0, 0.0, 0.0]
    assert iou_3d(base, ext, far, ext) == 0.0
    touching = base.copy()
    touching[:3, 3] += R_GT[:, 0] * 1.0
    assert iou_3d(base, ext, touching, ext) == pytest.approx(0.0, abs=1e-9)
    # unit square prism vs the same turned 45° about z: octagon of area 2(√2 − 1), IoU = 1/√2
    turned = make_pose(rz(45), [0, 0, 0])
    assert iou_3d(np.eye(4), ext, turned, ext) == pytest.approx(1.0 / math.sqrt(2.0), abs=1e-9)
    # nested: a box inside a 2x larger one
    assert iou_3d(np.eye(4), [2, 2, 2], np.eye(4), [1, 1, 1]) == pytest.approx(1.0 / 8.0, abs=1e-9)


def test_success_at():
    assert success_at(5.0, 0.2) == [True, True, True]
    assert success_at(20.0, 0.2) == [False, True, True]
    assert success_at(45.0, 1.0) == [False, False, True]
    assert success_at(math.nan, 0.1) == [False, False, False]
    assert success_rates([5.0, 20.0, math.nan, 90.0], [0.1, 0.4, math.nan, 0.1]) == [0.25, 0.5, 0.5]


# ------------------------------------------------------------------------------------------- tables


def _row(room, obj, present, decision, **kw):
    row = {
        "room": room, "object": obj, "model_id": obj, "category": "chair", "tier": "sift", "aligner": "alg1",
        "delta_r_deg": 10.0, "delta_t_m": 0.25, "present_gt": present, "eps": 0.3, "decision": decision,
        "n_queries": 20, "n_localized": 10, "rot_err_deg": math.nan, "trans_err_m": math.nan,
        "iou3d": math.nan, "scene_from_object_est": None, "magnitude": None, "kind": None,
    }
    row.update(kw)
    return row


HAND_ROWS = [
    # r0: TP A, FP B, FN C, TN D -> P 0.5, R 0.5
    _row("r0", "A", True, True), _row("r0", "B", False, True),
    _row("r0", "C", True, False), _row("r0", "D", False, False),
    # r1: TP A, TP B, TN C, FP D -> P 2/3, R 1
    _row("r1", "A", True, True), _row("r1", "B", True, True),
    _row("r1", "C", False, False), _row("r1", "D", False, True),
]


def test_table1_hand_computed():
    pr = {r["room"]: r for r in presence_pr_per_room(HAND_ROWS)}
    assert (pr["r0"]["precision"], pr["r0"]["recall"]) == (0.5, 0.5)
    assert pr["r1"]["precision"] == pytest.approx(2 / 3) and pr["r1"]["recall"] == 1.0
    assert (pr["all"]["tp"], pr["all"]["fp"], pr["all"]["fn"]) == (3, 2, 1)
    md = table1_markdown(HAND_ROWS)
    assert "| r0 | 0.50 | 0.50 |" in md
    assert "| r1 | 0.67 | 1.00 |" in md
    assert "| all | 0.60 | 0.75 |" in md
    assert "tier `sift`, aligner `alg1`" in md and "| room | 10°, 0.25m P | 10°, 0.25m R |" in md
    assert random_guess_precision(HAND_ROWS) == 0.5
    per_obj = {r["object"]: r for r in presence_pr_per_object(HAND_ROWS)}
    # C: present in r0 only, never decided present -> P 0 (paper convention), R 0
    assert (per_obj["C"]["precision"], per_obj["C"]["recall"]) == (0.0, 0.0)
    # D: absent everywhere, one false positive -> P 0, R undefined
    assert per_obj["D"]["precision"] == 0.0 and math.isnan(per_obj["D"]["recall"])
    assert "| A | 1.00 | 1.00 |" in table2_markdown(HAND_ROWS)


def test_apply_presence_decisions_matches_leave_one_scene_out():
    rows = [
        _row("r0", "A", True, None, eps=0.5), _row("r1", "A", True, None, eps=0.9),
        _row("r2", "A", False, None, eps=0.1), _row("r3", "A", False, None, eps=0.2),
        _row("r4", "A", False, None, eps=0.3),
        # another configuration must not leak into the first one's medians
        _row("r0", "A", True, None, eps=0.5, tier="sp"), _row("r1", "A", True, None, eps=0.45, tier="sp"),
        _row("r2", "A", False, None, eps=0.0, tier="sp"),
    ]
    decided = {(r["tier"], r["room"]): r for r in apply_presence_decisions(rows)}
    assert decided[("sift", "r0")]["decision"] is False  # eps+ 0.9, eps- 0.2
    assert decided[("sift", "r1")]["decision"] is True
    assert decided[("sp", "r0")]["decision"] is True  # eps+ 0.45, eps- 0.0
    assert decided[("sp", "r0")]["eps_plus"] == pytest.approx(0.45)
    assert all(r["decision"] is None for r in rows)  # input untouched


def test_placement_stats_and_summary():
    rows = [
        _row("r0", "A", True, True, rot_err_deg=5.0, trans_err_m=0.1, iou3d=0.6),
        _row("r1", "A", True, False, rot_err_deg=20.0, trans_err_m=0.4, iou3d=0.2),
        _row("r2", "A", True, True),  # present, no estimate: infinite errors, IoU 0
        _row("r3", "A", False, True, rot_err_deg=1.0, trans_err_m=0.01),  # not present: not scored
    ]
    (all_pairs,) = placement_stats(rows)
    assert all_pairs["n"] == 3 and all_pairs["n_placed"] == 2
    assert all_pairs["median_rot_err_deg"] == 20.0 and all_pairs["median_trans_err_m"] == 0.4
    assert all_pairs["median_iou3d"] == 0.2
    assert all_pairs["success_10deg_0.25m"] == pytest.approx(1 / 3)
    assert all_pairs["success_30deg_0.5m"] == pytest.approx(2 / 3)
    (decided,) = placement_stats(rows, decided_only=True)
    assert decided["n"] == 2 and decided["success_10deg_0.25m"] == 0.5
    md = placement_summary(rows)
    assert "all GT-present pairs" in md and "decided present" in md and "| sift | alg1 |" in md


def test_write_results_deterministic(tmp_path):
    rows = [dict(r, extra_note="x", scene_from_object_est=np.eye(4)) for r in HAND_ROWS[:2]]
    csv_a, json_a = write_results(rows, tmp_path / "a")
    csv_b, json_b = write_results(rows, tmp_path / "b")
    assert csv_a.read_bytes() == csv_b.read_bytes() and json_a.read_bytes() == json_b.read_bytes()
    header = csv_a.read_text().splitlines()[0].split(",")
    assert header == [*COLUMNS, "extra_note"]
    back = read_results(json_a)
    assert math.isnan(back[0]["iou3d"]) and back[0]["scene_from_object_est"][0] == [1.0, 0.0, 0.0, 0.0]
    assert back[0]["present_gt"] is True and back[0]["magnitude"] is None


# ------------------------------------------------------------------------------------------- defense

QUERIES = [
    {"room": "r0", "tier": "sift", "genuine": True, "attacker_object": None, "success_without_defense": True,
     "inlier_instance_counts": {"1": 100, "2": 50, "3": 20, "4": 5}},
    {"room": "r0", "tier": "sift", "genuine": True, "attacker_object": None, "success_without_defense": True,
     "inlier_instance_counts": {1: 40, 2: 40}},
    {"room": "r0", "tier": "sift", "genuine": True, "attacker_object": None, "success_without_defense": False,
     "inlier_instance_counts": {1: 10}},
    {"room": "r0", "tier": "sift", "genuine": False, "attacker_object": "a1", "success_without_defense": True,
     "inlier_instance_counts": {5: 200, 6: 15}},
    {"room": "r0", "tier": "sift", "genuine": False, "attacker_object": "a2", "success_without_defense": True,
     "inlier_instance_counts": {5: 100, 6: 30, 7: 12}},
]


def test_defense_sweep_hand_checked():
    assert qualifying_instances(QUERIES[0]["inlier_instance_counts"], 0.1) == 3
    assert qualifying_instances(QUERIES[0]["inlier_instance_counts"], 0.3) == 2
    assert qualifying_instances({}, 0.1) == 0 and not passes_defense({}, 0.1, 1)
    assert qualifying_instances({0: 500, 3: 10, 4: 2}, 0.1) == 2  # background 0 never counts
    assert passes_defense({"3": 10, "4": 2}, 0.2, 2) and not passes_defense({"3": 10, "4": 1}, 0.2, 2)
    out = defense_tradeoff(QUERIES, min_fractions=[0.1, 0.3], min_instances=[2, 3])
    got = {(r["tier"], r["min_fraction"], r["min_instances"]): r for r in out}
    r = got[("sift", 0.1, 2)]
    assert (r["n_genuine"], r["n_attacker"]) == (2, 2)  # the unlocalized genuine query is not counted
    assert (r["genuine_kept"], r["attacker_rejected"]) == (1.0, 0.5)
    assert (got[("sift", 0.1, 3)]["genuine_kept"], got[("sift", 0.1, 3)]["attacker_rejected"]) == (0.5, 0.5)
    assert (got[("sift", 0.3, 3)]["genuine_kept"], got[("sift", 0.3, 3)]["attacker_rejected"]) == (0.0, 1.0)
    assert got[("all", 0.3, 3)]["attacker_rejected"] == 1.0
    with pytest.raises(ValueError, match="inlier_instance_counts"):
        defense_tradeoff([{**QUERIES[0], "inlier_instance_counts": {1: -3}}])


# ------------------------------------------------------------------------------------------- plots


def _is_png(path) -> bool:
    data = path.read_bytes()
    return data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000


def test_plots_write_pngs(tmp_path):
    rows = []
    for tier in ("sift", "sp"):
        for k, r in enumerate(HAND_ROWS):
            rows.append(dict(r, tier=tier, rot_err_deg=3.0 * k, trans_err_m=0.05 * k, magnitude=0.2 * (k % 3),
                             kind="shape"))
    paths = [
        plots.plot_presence_pr(presence_pr_per_room(rows), tmp_path / "pr.png"),
        plots.plot_placement_cdfs(rows, tmp_path / "cdf.png"),
        plots.plot_defense_tradeoff(defense_tradeoff(QUERIES), tmp_path / "defense.png"),
        plots.plot_leakage_vs_magnitude(rows, tmp_path / "sweep.png"),
    ]
    objects = [("chair", make_pose(rz(30), [1.0, 1.0, 0.0]), [0.5, 0.6, 0.9]),
               ("table", make_pose(np.eye(3), [3.0, 2.0, 0.0]), [1.2, 0.8, 0.75])]
    estimates = [("chair", make_pose(rz(50), [1.2, 1.1, 0.0]), [0.5, 0.6, 0.9]), ("table", None, [1, 1, 1])]
    cams = np.array([make_pose(np.eye(3), [-1.0, -2.0, -1.5])])
    paths.append(plots.plot_room_topdown((5.0, 4.0, 2.6), objects, estimates, cams, tmp_path / "room.png"))
    for path in paths:
        assert _is_png(path), path
    again = plots.plot_room_topdown((5.0, 4.0, 2.6), objects, estimates, cams, tmp_path / "room2.png")
    assert again.read_bytes() == paths[-1].read_bytes()


def test_recall_funnel_counts_each_step() -> None:
    """Present pairs only, one per (tier, room, object) at the first aligner/thresholds; each step counted."""
    from synthleak.evaluate.attack_pairs import server_funnel
    from synthleak.evaluate.tables import recall_funnel, recall_funnel_markdown

    records = [  # one pair's query log: 3 sent, 2 localized, 1 of them mostly on instance 7
        {"success": True, "inlier_instance_counts": {"7": 40, "3": 12}, "retrieved": ["m0", "m2"]},
        {"success": True, "inlier_instance_counts": {"3": 30, "7": 30},  # tie: the lower id wins, not 7
         "retrieved": ["m1"]},
        {"success": False, "inlier_instance_counts": {}, "retrieved": ["m2", "m1"]},
    ]
    visible = {"m0": {3}, "m1": {3}, "m2": {3, 7}}  # only m2 sees instance 7: queries 0 and 2 retrieve it
    assert server_funnel(records, 7, {7: 120, 3: 50}, {}, visible) == {
        "map_points_on_target": 120, "n_retrieved_target": 2, "n_target_top": 1, "n_lookalike_top": None}
    assert server_funnel(records, 7, None, {}) == {"map_points_on_target": None, "n_retrieved_target": None,
                                                   "n_target_top": 1, "n_lookalike_top": None}
    # an absent pair: the localized queries whose inliers lie mostly on a look-alike of the queried object
    assert server_funnel(records, None, {7: 1}, {3: "shares_sku"}, visible) == {
        "map_points_on_target": None, "n_retrieved_target": None, "n_target_top": None, "n_lookalike_top": 1}
    assert server_funnel(records, None, {7: 1}, {})["n_lookalike_top"] == 0
    remote = [{k: v for k, v in q.items() if k != "retrieved"} for q in records]  # a server names no images
    assert server_funnel(remote, 7, {7: 120}, {}, visible)["n_retrieved_target"] is None
    with pytest.raises(ValueError, match="'m9' is not an image of this map"):
        server_funnel([{**records[0], "retrieved": ["m9"]}], 7, None, {}, visible)

    def row(obj, present, points, localized, top, decision, aligner="alg1", magnitude=None, retrieved=None):
        return {"tier": "sift", "room": "r0", "object": obj, "aligner": aligner, "delta_r_deg": 10.0,
                "delta_t_m": 0.25, "present_gt": present, "map_points_on_target": points, "n_queries": 10,
                "n_localized": localized, "n_target_top": top, "decision": decision, "magnitude": magnitude,
                "n_retrieved_target": retrieved}

    rows = [row("a", True, 300, 4, 3, True, retrieved=9), row("b", True, 0, 0, 0, False, retrieved=0),
            row("c", True, 80, 2, 0, False, retrieved=5),
            row("d", False, None, 1, None, True),                     # absent pair: not counted
            row("a", True, 300, 4, 3, False, aligner="robust"),       # other aligner: not counted twice
            row("e", True, 50, 5, 5, True, magnitude=0.25)]           # variant sweep row: left out
    (funnel,) = recall_funnel(rows)
    assert funnel["present pairs"] == 3 and funnel["object in map"] == 2 and funnel["median map points"] == 80
    assert funnel["a query localized"] == 2 and funnel["localized on the object"] == 1
    assert funnel["decided present (alg1, 10°, 0.25m)"] == 1
    # the queries: 30 sent, 14 retrieve a map image seeing the object, 6 localized, 3 mostly on it
    assert (funnel["queries sent"], funnel["retrieved images see the object"], funnel["queries localized"],
            funnel["queries on the object"]) == (30, 14, 6, 3)
    assert "| sift | 3 | 2 | 80 | 2 | 1 | 1 | 30 | 14 | 6 | 3 |" in recall_funnel_markdown(rows)
    unknown = [{**r, "n_retrieved_target": None} if r["object"] == "b" else r for r in rows]  # one unknown
    assert recall_funnel(unknown)[0]["retrieved images see the object"] == "–"
