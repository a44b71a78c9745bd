"""RANSAC PnP (src/synthleak/localize/pnp.py): both solvers recover a known ``cam_from_world`` from matches with
outliers, agree on the inliers, refuse a hopeless match set, and are chosen by ``[localize] pnp_solver``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from synthleak.config import ConfigError, load_config
from synthleak.core.types import Camera
from synthleak.geometry.poses import rotation_error_deg
from synthleak.localize.pnp import PNP_SOLVERS, estimate_pose

CAMERA = Camera.from_hfov(640, 480, 65.0)


def _problem(seed: int, n: int = 400, outliers: float = 0.6, noise_px: float = 0.5):
    """Points in front of a known camera, their projections with noise, a share replaced by random pixels."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    cam_from_world = np.eye(4)
    cam_from_world[:3, :3] = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    cam_from_world[:3, 3] = rng.normal(0, 0.5, 3)
    in_cam = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2, 6, n)])
    world = (in_cam - cam_from_world[:3, 3]) @ cam_from_world[:3, :3]
    pixels = np.column_stack([CAMERA.fx * in_cam[:, 0] / in_cam[:, 2] + CAMERA.cx,
                              CAMERA.fy * in_cam[:, 1] / in_cam[:, 2] + CAMERA.cy]) + rng.normal(0, noise_px, (n, 2))
    bad = rng.random(n) < outliers
    pixels[bad] = rng.uniform([0, 0], [CAMERA.width, CAMERA.height], (int(bad.sum()), 2))
    return pixels, world, cam_from_world, ~bad


@pytest.mark.parametrize("solver", PNP_SOLVERS)
def test_each_solver_recovers_cam_from_world_among_outliers(solver):
    pixels, world, truth, inlier = _problem(1)
    est = estimate_pose(pixels, world, CAMERA, 4.0, seed=0, solver=solver)
    assert est is not None
    assert rotation_error_deg(est.cam_from_world[:3, :3], truth[:3, :3]) < 0.05
    assert np.linalg.norm(est.cam_from_world[:3, 3] - truth[:3, 3]) < 5e-3
    assert np.sum(est.inlier_mask & ~inlier) <= 3 and np.sum(inlier & ~est.inlier_mask) <= 0.02 * inlier.sum()
    again = estimate_pose(pixels, world, CAMERA, 4.0, seed=0, solver=solver)
    assert again.cam_from_world.tobytes() == est.cam_from_world.tobytes()  # seeded: the same bits


def test_the_solvers_agree_on_the_inliers():
    pixels, world, _, _ = _problem(2, outliers=0.8)
    colmap, poselib = (estimate_pose(pixels, world, CAMERA, 4.0, 0, s) for s in ("colmap", "poselib"))
    assert abs(int(colmap.inlier_mask.sum()) - int(poselib.inlier_mask.sum())) <= 3


@pytest.mark.parametrize("solver", PNP_SOLVERS)
def test_chance_matches_give_no_pose_or_a_handful_of_inliers(solver):
    rng = np.random.default_rng(3)
    pixels = rng.uniform([0, 0], [640, 480], (60, 2))
    world = rng.uniform([-2, -2, 2], [2, 2, 6], (60, 3))
    est = estimate_pose(pixels, world, CAMERA, 2.0, 0, solver)
    assert est is None or est.inlier_mask.sum() < 15  # below any server's min inliers


def test_an_unknown_solver_is_named():
    with pytest.raises(ValueError, match=r"unknown PnP solver 'epnp' \(known: colmap, poselib\)"):
        estimate_pose(np.zeros((5, 2)), np.ones((5, 3)), CAMERA, 4.0, 0, "epnp")


def test_a_config_names_an_unknown_solver_with_its_file_and_key(tmp_path: Path):
    path = tmp_path / "bad.toml"
    path.write_text('extends = "ci-tiny"\n[localize]\npnp_solver = "epnp"\n')
    with pytest.raises(ConfigError, match=r"bad\.toml.*localize\.pnp_solver: unknown name 'epnp'"):
        load_config(path)
    assert load_config("ci-tiny").localize.pnp_solver == "colmap"  # HLoc's own call by default
    path.write_text('extends = "ci-tiny"\n[localize]\npnp_solver = "poselib"\n')
    assert load_config(path).localize.pnp_solver == "poselib"
