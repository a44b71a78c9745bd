"""The presence classifier beyond ε: attacker-side trial features, leave-one-scene-out decisions, and a proof
that the evaluated room's ground truth never reaches its features or its decision."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synthleak.attack.presence import decide_presence, presence_margin
from synthleak.attack.presence_classifier import attacker_view, classifier_decisions, trial_matrix
from synthleak.attack.presence_features import FAR_M, TRIAL_FEATURES, attack_features
from synthleak.attack.run import run_attack
from synthleak.geometry.poses import invert, look_at, make_pose

THRESHOLDS = [(10.0, 0.25), (30.0, 0.5), (60.0, 2.0)]


def _orbit(n: int) -> dict[str, np.ndarray]:
    """``cam_from_object`` of ``n`` cameras on a circle 2 m around the object, 1 m up."""
    return {f"{k:06d}.png": look_at([2 * math.cos(2 * math.pi * k / n), 2 * math.sin(2 * math.pi * k / n), 1.0],
                                    [0.0, 0.0, 0.3]) for k in range(n)}


def test_features_see_a_second_placement_and_the_residual_spread():
    """Six server poses agree on placement A, three on a placement B 2 m away, three are not localized:
    ε = 6/12, the second-best hypothesis holds 3/12, noise-free inliers have no residual spread."""
    local = _orbit(12)
    a = make_pose(Rotation.from_euler("z", 30, degrees=True).as_matrix(), [1.0, 2.0, 0.0])
    b = make_pose(Rotation.from_euler("z", 120, degrees=True).as_matrix(), [-1.0, 0.0, 0.0])
    names = sorted(local)
    server: dict[str, np.ndarray | None] = {n: local[n] @ invert(a) for n in names[:6]}
    server |= {n: local[n] @ invert(b) for n in names[6:9]} | {n: None for n in names[9:]}
    alignments = [run_attack(local, server, "alg1", dr, dt) for dr, dt in THRESHOLDS]
    features = attack_features(local, server, alignments, THRESHOLDS)
    assert [f.eps for f in alignments] == [0.5, 0.5, 0.5]
    for trial in features:
        assert set(trial) == set(TRIAL_FEATURES)
        assert trial["second_eps"] == pytest.approx(3 / 12)
        assert trial["rot_spread"] < 1e-6 and trial["trans_spread"] < 1e-6
        assert trial["disagree_rot_deg"] < 1e-4 and trial["disagree_trans_m"] < 1e-9
    # noisy server poses: the inliers spread and the placement moves with the thresholds
    rng = np.random.default_rng(0)
    noisy = {n: (p if p is None else make_pose(
        Rotation.from_rotvec(rng.normal(0, np.radians(3), 3)).as_matrix() @ p[:3, :3], p[:3, 3] + rng.normal(
            0, 0.05, 3))) for n, p in server.items()}
    alignments = [run_attack(local, noisy, "alg1", dr, dt) for dr, dt in THRESHOLDS]
    tight, _, loose = attack_features(local, noisy, alignments, THRESHOLDS)
    assert 0.05 < tight["rot_spread"] < 1.0 and 0.05 < tight["trans_spread"] < 1.0
    assert tight["disagree_rot_deg"] > 0.0 and tight["disagree_trans_m"] > 0.0


def test_a_missing_placement_disagrees_with_any_other():
    local = _orbit(4)
    nothing = {n: None for n in local}
    empty = run_attack(local, nothing, "alg1", 10.0, 0.25)
    one = {sorted(local)[0]: local[sorted(local)[0]]}
    placed = run_attack(local, one, "alg1", 30.0, 0.5)
    both = attack_features(local, one, [run_attack(local, one, "alg1", 10.0, 0.25), placed], THRESHOLDS[:2])
    assert both[0]["disagree_rot_deg"] < 1e-4 and both[0]["disagree_trans_m"] < 1e-9
    neither = attack_features(local, nothing, [empty, empty], THRESHOLDS[:2])
    assert neither[0] == {"second_eps": 0.0, "rot_spread": 1.0, "trans_spread": 1.0, "disagree_rot_deg": 0.0,
                        "disagree_trans_m": 0.0}
    from synthleak.attack.presence_features import placement_disagreement

    assert placement_disagreement([empty, placed]) == [(180.0, FAR_M), (180.0, FAR_M)]
    with pytest.raises(ValueError, match="one alignment per threshold pair"):
        attack_features(local, nothing, [empty], THRESHOLDS)


def test_presence_margin_is_the_eps_rule_signed():
    rng = np.random.default_rng(1)
    for _ in range(500):
        eps = float(rng.choice([0.0, 0.25, 0.5, rng.random()]))
        plus = None if rng.random() < 0.2 else float(rng.random())
        minus = None if rng.random() < 0.2 else float(rng.random())
        assert (presence_margin(eps, plus, minus) > 0) == decide_presence(eps, plus, minus), (eps, plus, minus)


def _row(room: str, obj: str, present: bool, eps: float, localized: int, **extra) -> dict:
    return {"room": room, "object": obj, "tier": "sift", "aligner": "alg1", "delta_r_deg": 10.0, "delta_t_m": 0.25,
            "magnitude": None, "kind": None, "present_gt": present, "eps": eps, "n_queries": 12,
            "n_localized": localized, "second_eps": 0.0, "rot_spread": 0.2 if localized else 1.0,
            "trans_spread": 0.2 if localized else 1.0, "disagree_rot_deg": 0.0, "disagree_trans_m": 0.0, **extra}


def test_classifier_learns_from_other_rooms_and_falls_back_on_one_class():
    rows = []
    for r in range(4):
        for o in range(6):
            present = o % 3 == r % 3
            rows.append(_row(f"room_{r}", f"obj_{o}", present, 0.5 if present else 0.0, 6 if present else 0))
    out = classifier_decisions(rows, [False] * len(rows))
    assert [d["decision_clf"] for d in out] == [r["present_gt"] for r in rows]
    assert all(not d["clf_fallback"] and 0.0 <= d["clf_score"] <= 1.0 for d in out)
    # every training room absent: the ε rule's decision is kept
    lonely = [_row("room_0", "obj_0", True, 0.5, 6), _row("room_1", "obj_0", False, 0.0, 0),
              _row("room_2", "obj_0", False, 0.0, 0)]
    out = classifier_decisions(lonely, [True, False, True])
    assert out[0] == {"clf_score": None, "decision_clf": True, "clf_fallback": True}
    assert not out[1]["clf_fallback"] and not out[2]["clf_fallback"]


def test_results_rows_carry_both_rules_and_the_config_picks_one():
    from synthleak.evaluate.tables import apply_presence_decisions, presence_rule_comparison, presence_rules_markdown

    rows = []
    for r in range(3):
        for o in range(4):
            present = o == r  # obj_3 is present nowhere: the ε rule says present iff ε > ε⁻
            rows.append(_row(f"room_{r}", f"obj_{o}", present, 0.5 if present else (0.1 if o == 3 else 0.0),
                             6 if present else (1 if o == 3 else 0), model_id="m", category="c"))
    by_eps, by_clf = apply_presence_decisions(rows), apply_presence_decisions(rows, "classifier")
    assert [r["decision"] for r in by_eps] == [r["decision_eps"] for r in by_eps]
    assert [r["decision"] for r in by_clf] == [r["decision_clf"] for r in by_clf]
    assert [r["decision_clf"] for r in by_eps] == [r["decision_clf"] for r in by_clf]
    (table,) = presence_rule_comparison(by_eps)
    eps_fp = sum(r["decision_eps"] and not r["present_gt"] for r in by_eps)
    clf_tp = sum(r["decision_clf"] and r["present_gt"] for r in by_eps)
    assert table["TP/FP eps"] == f"3/{eps_fp}" and table["TP/FP clf"].startswith(f"{clf_tp}/")
    assert table["n_pairs"] == 12 and table["wins"] in ("eps", "classifier", "tie")
    assert "| sift | alg1 | 10°, 0.25m |" in presence_rules_markdown(by_eps)
    with pytest.raises(ValueError, match="unknown rule"):
        apply_presence_decisions(rows, "vote")
    bare = [{k: v for k, v in r.items() if k not in TRIAL_FEATURES} for r in rows]
    assert "decision_clf" not in apply_presence_decisions(bare)[0]
    with pytest.raises(ValueError, match="no trial features"):
        apply_presence_decisions(bare, "classifier")


def test_features_ignore_every_ground_truth_column():
    rows = [_row("room_0", "obj_0", True, 0.5, 6, rot_err_deg=1.0, n_target_top=5, map_points_on_target=300),
            _row("room_1", "obj_0", False, 0.0, 0, rot_err_deg=None, n_target_top=None, absent_kind="unrelated")]
    flipped = [{**r, "present_gt": not r["present_gt"], "rot_err_deg": 99.0, "n_target_top": 0,
                "map_points_on_target": 0, "absent_kind": "shares_sku"} for r in rows]
    assert [attacker_view(r) for r in rows] == [attacker_view(r) for r in flipped]
    assert np.array_equal(trial_matrix(rows)[0], trial_matrix(flipped)[0])


# ------------------------------------------------------------------------ the real study path, GT changed


def _flip_ground_truth(study: Path, room: str) -> None:
    """In the study's dataset: every attacker object present in ``room`` becomes absent and every absent one
    present (on an object instance of the room), and the room's objects move 1 m."""
    index_path = study / "dataset" / "stages" / "index.json"
    index = json.loads(index_path.read_text())
    objects_path = study / "dataset" / "scenes" / room / "objects.json"
    objects = json.loads(objects_path.read_text())
    instance = next(i["instance_id"] for i in objects["instances"] if i["role"] == "object")
    for obj in index["attacker_objects"]:
        if room in obj["present_in"]:
            del obj["present_in"][room]
        else:
            obj["present_in"][room] = instance
    index_path.write_text(json.dumps(index))
    for inst in objects["instances"]:
        if inst["role"] == "object":
            inst["world_from_object"][0][3] += 1.0
    objects_path.write_text(json.dumps(objects))


def _attack(study: Path) -> list[dict]:
    from synthleak.config import load_config
    from synthleak.study import StudyPaths, attack_rows

    logs = {("sift", log.parent.name): log for log in sorted((study / "queries" / "sift").glob("*/queries.jsonl"))}
    return attack_rows(load_config("ci-tiny"), StudyPaths(study), logs)


def test_the_evaluated_rooms_ground_truth_moves_neither_its_features_nor_its_decision(ci_tiny_study, tmp_path):
    """The real attack path on ci-tiny: change room_000's ground truth (presence and object poses) and its
    rows' features, classifier scores and decisions stay; change the other room's and room_000's scores move
    (its model is trained there), so the check can fail."""
    keep = ("images", "depth", "instance", "features", "plots", "bop")
    copy = tmp_path / "study"
    shutil.copytree(ci_tiny_study, copy, ignore=shutil.ignore_patterns(*keep))
    before = _attack(copy)
    _flip_ground_truth(copy, "room_000")
    after = _attack(copy)
    assert len(before) == len(after)
    evaluated = [(b, a) for b, a in zip(before, after, strict=True) if b["room"] == "room_000"]
    assert evaluated and any(b["present_gt"] != a["present_gt"] for b, a in evaluated)  # the GT did change
    columns = ("decision_clf", "clf_score", "decision_eps", "eps", *TRIAL_FEATURES)
    for b, a in evaluated:
        assert [b[c] for c in columns] == [a[c] for c in columns], b["object"]
    rows_b, rows_a = [b for b, _ in evaluated], [a for _, a in evaluated]
    assert np.array_equal(trial_matrix(rows_b)[0], trial_matrix(rows_a)[0])

    _flip_ground_truth(copy, "room_001")  # the training room of room_000
    trained_elsewhere = [r for r in _attack(copy) if r["room"] == "room_000"]
    assert any(a["clf_score"] != t["clf_score"] for a, t in zip(rows_a, trained_elsewhere, strict=True))
