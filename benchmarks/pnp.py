"""Pose-solver cost on a finished study's own queries: COLMAP's RANSAC PnP (pycolmap) with the photo's OPENCV
camera on distorted keypoints, the same on undistorted keypoints with the pinhole camera (what the servers run),
and poselib's LO-RANSAC under COLMAP's stopping rule (same threshold, confidence, trial cap and multiplier).

    python benchmarks/pnp.py runs/study-small --queries 40
    python benchmarks/pnp.py runs/study-small --servers xfeat@hloc --queries 20

Per server: ms per solve (mean over the sampled attacker and genuine queries), mean 2D-3D matches and inliers,
and how many queries' acceptance (inliers >= the server's min inliers) differs from the distorted-camera solve.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pycolmap

from synthleak.config import load_config
from synthleak.core.dataset import load_sequence, pycolmap_camera
from synthleak.localize.feature_files import load_features
from synthleak.localize.localizer import RANSAC_SEED, Localizer, undistorted_keypoints
from synthleak.localize.servers import server_by_name
from synthleak.study.paths import StudyPaths


def _colmap(points2d: np.ndarray, points3d: np.ndarray, camera, max_error: float) -> tuple[int, float]:
    options = pycolmap.AbsolutePoseEstimationOptions()
    options.ransac.max_error = max_error
    options.ransac.random_seed = RANSAC_SEED
    start = time.perf_counter()
    est = pycolmap.estimate_and_refine_absolute_pose(points2d, points3d, pycolmap_camera(camera), options)
    elapsed = time.perf_counter() - start
    return (0 if est is None else int(np.sum(est["inlier_mask"]))), elapsed


def _poselib(points2d: np.ndarray, points3d: np.ndarray, camera, max_error: float) -> tuple[int, float]:
    import poselib

    cam = {"model": "PINHOLE", "width": camera.width, "height": camera.height,
           "params": [camera.fx, camera.fy, camera.cx, camera.cy]}
    ransac = {"max_reproj_error": max_error, "max_iterations": 10000, "min_iterations": 100,
              "success_prob": 0.99999, "dyn_num_trials_mult": 3.0, "seed": RANSAC_SEED}
    start = time.perf_counter()
    _, info = poselib.estimate_absolute_pose(points2d, points3d, cam, ransac, {})
    elapsed = time.perf_counter() - start
    return int(info["num_inliers"]), elapsed


def _inputs(case: tuple, undistort: bool) -> tuple:
    """(keypoints, points, camera) of a case, the keypoints undistorted for the pinhole camera if asked."""
    keypoints, points, camera = case
    if undistort:
        keypoints, camera = undistorted_keypoints(keypoints, camera)
    return keypoints, points, camera


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path, help="a finished study folder (its run.json names the config)")
    parser.add_argument("--servers", nargs="*", help="server names (default: every server of the study)")
    parser.add_argument("--queries", type=int, default=30, help="queries sampled per server (spread over its logs)")
    parser.add_argument("--room", default=None, help="one room (default: the first)")
    args = parser.parse_args()
    run = json.loads((args.study / "run.json").read_text())["runs"][-1]
    config = load_config(run["config"])
    paths = StudyPaths(args.study)
    servers = server_by_name(config.localize)
    print(f"# benchmarks/pnp.py {args.study} ({run['config']})")
    print(f"{'server':<14} {'queries':>7} {'matches':>8} {'solver':<22} {'ms':>8} {'inliers':>8} {'moved':>6}")
    for name in args.servers or list(servers):
        server = servers[name]
        room = args.room or sorted(p.name for p in (args.study / "maps" / name).iterdir() if p.is_dir())[0]
        loc = Localizer.load(paths.map_dir(name, room), server.localize(config.localize))
        log = [json.loads(line) for line in paths.query_log(name, room).read_text().splitlines() if line.strip()]
        picked = [log[int(i)] for i in np.linspace(0, len(log) - 1, min(args.queries, len(log)))]
        cases = []
        for q in picked:
            features, _ = load_features(paths.features_file(server.tier, q["sequence"], q["frame"]))
            camera = load_sequence(paths.sequence(q["sequence"], q["genuine"])).camera_of(q["frame"])
            corr, _ = loc.verified_correspondences(features, loc.candidates(features), camera)
            if len(corr) >= 3:
                cases.append((features.keypoints[corr[:, 0]], loc.data.xyz[corr[:, 1]], camera))
        if not cases:
            continue
        solvers = {"colmap, distorted": (_colmap, False), "colmap, pinhole": (_colmap, True)}
        try:
            import poselib  # noqa: F401

            solvers["poselib, pinhole"] = (_poselib, True)
        except ImportError:
            pass
        reference = None
        for label, (solve, undistort) in solvers.items():
            out = [solve(*_inputs(case, undistort), loc.max_error_px) for case in cases]
            accepted = np.array([n >= loc.min_inliers for n, _ in out])
            moved = 0 if reference is None else int(np.sum(accepted != reference))
            reference = accepted if reference is None else reference
            print(f"{name:<14} {len(cases):>7} {np.mean([len(c[0]) for c in cases]):>8.0f} {label:<22} "
                  f"{1e3 * np.mean([t for _, t in out]):>8.1f} {np.mean([n for n, _ in out]):>8.1f} {moved:>6}")


if __name__ == "__main__":
    main()
