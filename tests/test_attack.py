"""Attack: pose alignment (Alg. 1, Sim(3), robust) and the presence decision, on synthetic pose sets."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from synthleak.attack.align import (
    align_alg1,
    align_robust,
    align_sim3,
    aligner_names,
    get_aligner,
    residuals,
    umeyama,
)
from synthleak.attack.local_model import metric_scale_from_points, oracle_local_poses
from synthleak.attack.presence import PresenceRecord, decide_presence, leave_one_scene_out
from synthleak.attack.run import run_attack
from synthleak.evaluate.score import score_placement
from synthleak.geometry.poses import camera_centre, invert, look_at, make_pose
from synthleak.seeding import make_rng

N_CAMS = 50
OUTLIER_FRACTION = 0.4
SCENE_FROM_OBJECT = make_pose(
    Rotation.from_euler("zyx", [70, 5, -3], degrees=True).as_matrix(), [2.0, -1.0, 0.1]
)


def ring_poses(n: int = N_CAMS, radius: float = 2.5) -> np.ndarray:
    """cam_from_object of cameras on a wavy ring around an object at the origin."""
    poses = []
    for k in range(n):
        a = 2 * np.pi * k / n
        eye = [radius * np.cos(a), radius * np.sin(a), 1.2 + 0.3 * np.sin(3 * a)]
        poses.append(look_at(eye, [0.0, 0.0, 0.4]))
    return np.array(poses)


def server_poses(
    local: np.ndarray,
    scene_from_object: np.ndarray,
    seed: int,
    rot_noise_deg: float = 1.0,
    centre_noise_m: float = 0.02,
    outlier_fraction: float = OUTLIER_FRACTION,
) -> tuple[np.ndarray, np.ndarray]:
    """Noisy cam_from_scene (similarity-aware) and the inlier mask; outliers are random poses."""
    rng = make_rng(seed, "test_attack", "server")
    n = len(local)
    outliers = np.zeros(n, dtype=bool)
    outliers[rng.choice(n, size=int(round(outlier_fraction * n)), replace=False)] = True
    sr = scene_from_object[:3, :3]
    scale = np.cbrt(np.linalg.det(sr))
    rot_so = sr / scale
    out = []
    for pose, is_out in zip(local, outliers, strict=True):
        if is_out:
            rot = Rotation.random(random_state=int(rng.integers(2**31))).as_matrix()
            centre = rng.normal(0.0, 3.0, 3)
        else:
            rotvec = rng.normal(size=3) * np.radians(rot_noise_deg) / np.sqrt(3)
            d_rot = Rotation.from_rotvec(rotvec).as_matrix()
            rot = d_rot @ pose[:3, :3] @ rot_so.T
            centre = sr @ camera_centre(pose) + scene_from_object[:3, 3]
            centre = centre + rng.normal(size=3) * centre_noise_m / np.sqrt(3)
        out.append(make_pose(rot, -rot @ centre))
    return np.array(out), ~outliers


def pose_errors(est: np.ndarray, gt: np.ndarray) -> tuple[float, float]:
    s_est, s_gt = np.cbrt(np.linalg.det(est[:3, :3])), np.cbrt(np.linalg.det(gt[:3, :3]))
    rot = Rotation.from_matrix((est[:3, :3] / s_est) @ (gt[:3, :3] / s_gt).T).magnitude()
    return float(np.degrees(rot)), float(np.linalg.norm(est[:3, 3] - gt[:3, 3]))


def test_conventions_hypothesis_is_scene_from_object():
    """cam_from_scene = cam_from_object @ object_from_scene; Alg. 1 lines 5-6 give back scene_from_object."""
    local = ring_poses(5)
    object_from_scene = invert(SCENE_FROM_OBJECT)
    server = np.array([p @ object_from_scene for p in local])
    for loc, srv in zip(local, server, strict=True):
        r, t, r_hat, t_hat = loc[:3, :3], loc[:3, 3], srv[:3, :3], srv[:3, 3]
        np.testing.assert_allclose(r_hat.T @ r, SCENE_FROM_OBJECT[:3, :3], atol=1e-12)
        np.testing.assert_allclose(r_hat.T @ (t - t_hat), SCENE_FROM_OBJECT[:3, 3], atol=1e-12)
        # the wrong transposes must NOT work
        assert np.abs(r @ r_hat.T - SCENE_FROM_OBJECT[:3, :3]).max() > 1e-3
    # the inlier residuals vanish for exact data, and the centre residual is a camera-centre distance
    d_r, d_t = residuals(local, server, SCENE_FROM_OBJECT)
    assert d_r.max() < 1e-5 and d_t.max() < 1e-9
    shifted = SCENE_FROM_OBJECT.copy()
    shifted[:3, 3] += [0.3, 0.0, 0.4]
    _, d_t = residuals(local, server, shifted)
    np.testing.assert_allclose(d_t, 0.5, atol=1e-9)
    result = align_alg1(local, server, 1.0, 0.01)
    np.testing.assert_allclose(result.scene_from_object, SCENE_FROM_OBJECT, atol=1e-9)
    assert result.eps == 1.0 and result.hypothesis == 0


def test_alg1_recovers_pose_with_outliers():
    local = ring_poses()
    server, inlier_mask = server_poses(local, SCENE_FROM_OBJECT, seed=1)
    result = align_alg1(local, server, 5.0, 0.15)
    rot, trans = pose_errors(result.scene_from_object, SCENE_FROM_OBJECT)
    assert rot < 2.0 and trans < 0.03
    assert abs(result.eps - inlier_mask.mean()) <= 0.05
    assert set(result.inliers.tolist()) <= set(np.nonzero(inlier_mask)[0].tolist())
    assert result.scale == 1.0 and result.n_localized == N_CAMS


def test_eps_counts_unlocalized_images_in_n():
    local = ring_poses()
    server, inlier_mask = server_poses(local, SCENE_FROM_OBJECT, seed=2)
    result = align_alg1(local, server, 5.0, 0.15, n_total=2 * N_CAMS)
    assert result.n_total == 2 * N_CAMS and result.n_localized == N_CAMS
    assert abs(result.eps - inlier_mask.sum() / (2 * N_CAMS)) <= 0.03
    with pytest.raises(ValueError, match="n_total"):
        align_alg1(local, server, 5.0, 0.15, n_total=N_CAMS - 1)


@pytest.mark.parametrize("scale", [0.5, 2.0])
def test_sim3_recovers_scale_and_pose(scale):
    truth = SCENE_FROM_OBJECT.copy()
    truth[:3, :3] *= scale
    local = ring_poses()
    server, inlier_mask = server_poses(local, truth, seed=3)
    result = align_sim3(local, server, 5.0, 0.15 * scale)
    assert abs(result.scale / scale - 1.0) < 0.02
    rot, trans = pose_errors(result.scene_from_object, truth)
    assert rot < 2.0 and trans < 0.03 * scale
    assert abs(result.eps - inlier_mask.mean()) <= 0.05


def test_robust_at_least_as_accurate_as_alg1():
    local = ring_poses()
    errors = {"alg1": [], "robust": []}
    for seed in range(5):
        server, inlier_mask = server_poses(local, SCENE_FROM_OBJECT, seed=10 + seed)
        for name, fn in (("alg1", align_alg1), ("robust", align_robust)):
            result = fn(local, server, 5.0, 0.15)
            errors[name].append(pose_errors(result.scene_from_object, SCENE_FROM_OBJECT))
            assert abs(result.eps - inlier_mask.mean()) <= 0.05
    alg1, robust = np.mean(errors["alg1"], axis=0), np.mean(errors["robust"], axis=0)
    assert robust[0] <= alg1[0] and robust[1] <= alg1[1]
    assert robust[0] < 2.0 and robust[1] < 0.03


def test_sim3_degenerate_inputs():
    local = ring_poses(6)
    same = np.repeat(local[:1] @ invert(SCENE_FROM_OBJECT), 6, axis=0)  # every server centre identical
    result = align_sim3(local, same, 5.0, 0.1)
    assert result.scene_from_object is None and result.eps == 0.0
    one = align_sim3(local[:1], local[:1] @ invert(SCENE_FROM_OBJECT), 5.0, 0.1, n_total=4)
    assert one.eps == 0.25 and one.extra["scale_observable"] is False
    np.testing.assert_allclose(one.scene_from_object, SCENE_FROM_OBJECT, atol=1e-9)
    a = align_sim3(ring_poses(), server_poses(ring_poses(), SCENE_FROM_OBJECT, seed=4)[0], 5.0, 0.15,
                   max_pairs=200, seed=3)
    b = align_sim3(ring_poses(), server_poses(ring_poses(), SCENE_FROM_OBJECT, seed=4)[0], 5.0, 0.15,
                   max_pairs=200, seed=3)
    np.testing.assert_array_equal(a.scene_from_object, b.scene_from_object)  # seeded pair sample
    assert pose_errors(a.scene_from_object, SCENE_FROM_OBJECT)[1] < 0.03


def test_alg1_tie_breaks_to_first_index_and_is_deterministic():
    local = ring_poses(4)
    truth_b = SCENE_FROM_OBJECT.copy()
    truth_b[:3, 3] += [5.0, 0.0, 0.0]
    server = np.array(
        [local[0] @ invert(SCENE_FROM_OBJECT), local[1] @ invert(SCENE_FROM_OBJECT),
         local[2] @ invert(truth_b), local[3] @ invert(truth_b)]
    )
    first = align_alg1(local, server, 2.0, 0.1)
    again = align_alg1(local, server, 2.0, 0.1)
    assert first.hypothesis == 0 and first.inliers.tolist() == [0, 1]
    np.testing.assert_array_equal(first.scene_from_object, again.scene_from_object)


def test_empty_and_bad_input():
    for name in aligner_names():
        result = get_aligner(name)(np.zeros((0, 4, 4)), np.zeros((0, 4, 4)), 10.0, 0.25, n_total=20)
        assert result.scene_from_object is None and result.eps == 0.0 and result.n_total == 20, name
    local = ring_poses(3)
    bad = local.copy()
    bad[1, 0, 3] = np.nan
    with pytest.raises(ValueError, match="server_cam_from_scene"):
        align_alg1(local, bad, 10.0, 0.25)
    with pytest.raises(ValueError, match="vs"):
        align_alg1(local, local[:2], 10.0, 0.25)
    with pytest.raises(ValueError, match="delta_t_m"):
        align_robust(local, local, 10.0, 0.0)
    with pytest.raises(ValueError, match="aligner"):
        get_aligner("nope")


# ------------------------------------------------------------------------------------------- presence


def test_decide_presence_hand_examples():
    assert decide_presence(0.5, 0.6, 0.1) is True  # closer to eps+
    assert decide_presence(0.2, 0.6, 0.1) is False  # closer to eps-
    assert decide_presence(0.35, 0.6, 0.1) is False  # exact tie -> absent
    assert decide_presence(0.15, None, 0.1) is True  # no eps+: eps > eps-
    assert decide_presence(0.1, None, 0.1) is False
    assert decide_presence(0.31, 0.6, None) is True  # no eps-: eps- = 0, eps > eps+/2
    assert decide_presence(0.29, 0.6, None) is False
    assert decide_presence(0.01, None, None) is True and decide_presence(0.0, None, None) is False
    with pytest.raises(ValueError, match="eps_plus"):
        decide_presence(0.5, 1.5, 0.1)


def test_leave_one_scene_out_excludes_test_room():
    # object "chair": present in r0 (eps 0.5) and r1 (eps 0.9); absent in r2 (0.1), r3 (0.2), r4 (0.3).
    # For r0: eps+ = median{0.9} = 0.9, eps- = median{0.1,0.2,0.3} = 0.2;
    # |0.5-0.9| = 0.4 > |0.5-0.2| = 0.3 -> absent.
    # Including r0 itself would give eps+ = median{0.5,0.9} = 0.7, |0.5-0.7| = 0.2 < 0.3 -> present.
    recs = [
        PresenceRecord("r0", "chair", 0.5, True),
        PresenceRecord("r1", "chair", 0.9, True),
        PresenceRecord("r2", "chair", 0.1, False),
        PresenceRecord("r3", "chair", 0.2, False),
        PresenceRecord("r4", "chair", 0.3, False),
        PresenceRecord("r0", "lamp", 0.4, True),  # lamp present only in r0: no eps+ for r0
        PresenceRecord("r1", "lamp", 0.1, False),
        PresenceRecord("r2", "lamp", 0.3, False),
    ]
    dec = {(d.room, d.object): d for d in leave_one_scene_out(recs)}
    d = dec[("r0", "chair")]
    assert d.eps_plus == pytest.approx(0.9) and d.eps_minus == pytest.approx(0.2) and d.decision is False
    assert dec[("r1", "chair")].decision is True  # eps+ 0.5, eps- 0.2, eps 0.9
    # r4 chair: eps+ = 0.7, eps- = median{0.1,0.2} = 0.15, eps 0.3: |0.3-0.7|=0.4 > 0.15 -> absent
    assert dec[("r4", "chair")].eps_minus == pytest.approx(0.15) and dec[("r4", "chair")].decision is False
    lamp = dec[("r0", "lamp")]
    assert lamp.eps_plus is None and lamp.eps_minus == pytest.approx(0.2) and lamp.decision is True
    # r2 lamp: eps+ = 0.4 (r0), eps- = 0.1 (r1); eps 0.3 -> |0.1| < |0.2| -> present (a false positive)
    assert dec[("r2", "lamp")].decision is True
    with pytest.raises(ValueError, match="duplicate"):
        leave_one_scene_out(recs + [PresenceRecord("r0", "lamp", 0.1, True)])


# ------------------------------------------------------------------------------------------- local model


def _box_surface_points(extents, n: int, seed: int) -> np.ndarray:
    """Points on the sides and top of a canonical box (origin at the bottom centre; no underside)."""
    rng = make_rng(seed, "test_attack", "box")
    ex, ey, ez = extents
    pts = rng.uniform([-ex / 2, -ey / 2, 0.0], [ex / 2, ey / 2, ez], size=(n, 3))
    face = rng.integers(0, 5, n)
    pts[face == 0, 0] = -ex / 2
    pts[face == 1, 0] = ex / 2
    pts[face == 2, 1] = -ey / 2
    pts[face == 3, 1] = ey / 2
    pts[face == 4, 2] = ez
    return pts


def test_metric_scale_and_umeyama():
    extents = np.array([0.9, 0.45, 1.1])
    pts = _box_surface_points(extents, 3000, seed=0)
    # an arbitrary SfM frame: rotated, shifted, 0.37 units per metre
    rot = Rotation.from_euler("xyz", [20, -40, 75], degrees=True).as_matrix()
    sfm = 0.37 * pts @ rot.T + [4.0, -2.0, 1.0]
    strays = make_rng(1, "test_attack", "strays").normal(0.0, 2.0, (30, 3)) + [4.0, -2.0, 1.0]
    scale = metric_scale_from_points(np.vstack([sfm, strays]), extents)  # 1% stray background points
    assert abs(scale * 0.37 - 1.0) < 0.02
    s, r, t = umeyama(sfm, pts)
    np.testing.assert_allclose(s, 1 / 0.37, rtol=1e-9)
    np.testing.assert_allclose(r, rot.T, atol=1e-9)
    np.testing.assert_allclose(sfm @ (s * r).T + t, pts, atol=1e-9)
    assert math.isnan(metric_scale_from_points(sfm[:5], extents))


def test_attack_in_a_local_frame_scores_through_object_from_local():
    """Local poses in an SfM frame: alignment gives scene_from_local; object_from_local brings it back."""
    cam_from_object = ring_poses(30)
    object_from_local = make_pose(Rotation.from_euler("z", 130, degrees=True).as_matrix(), [0.4, 0.1, -0.2])
    local = {f"{k:06d}.png": p @ object_from_local for k, p in enumerate(cam_from_object)}
    server = {f"{k:06d}.png": p @ invert(SCENE_FROM_OBJECT) for k, p in enumerate(cam_from_object)}
    server["000003.png"] = None  # not localized
    result = run_attack(local, server, "alg1", 5.0, 0.1, n_sent=40)
    assert result.n_total == 40 and result.n_localized == 29 and result.eps == pytest.approx(29 / 40)
    scene_from_local = result.scene_from_object
    np.testing.assert_allclose(scene_from_local, SCENE_FROM_OBJECT @ object_from_local, atol=1e-9)
    scored = score_placement(scene_from_local, SCENE_FROM_OBJECT, [0.5, 0.5, 0.8], [0.5, 0.5, 0.8],
                             object_from_local=object_from_local)
    assert scored["rot_err_deg"] < 1e-5 and scored["trans_err_m"] < 1e-9
    assert scored["iou3d"] == pytest.approx(1.0, abs=1e-9)
    absent = score_placement(scene_from_local, None, None, [0.5, 0.5, 0.8])
    assert math.isnan(absent["rot_err_deg"]) and absent["scene_from_object_est"] is not None
    with pytest.raises(ValueError, match="server_poses"):
        run_attack({}, {"x.png": np.eye(4)}, "alg1", 5.0, 0.1)


def test_oracle_local_poses_needs_an_object_frame_sequence():
    poses = {"000000.png": ring_poses(1)[0]}
    seq = SimpleNamespace(root=Path("a01"), frame="object", frames=list(poses), cam_from_object=poses)
    got = oracle_local_poses(seq)
    np.testing.assert_array_equal(got["000000.png"], poses["000000.png"])
    with pytest.raises(ValueError, match="frame"):
        oracle_local_poses(SimpleNamespace(**{**seq.__dict__, "frame": "world"}))
