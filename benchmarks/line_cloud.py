"""Point PnP vs the line-cloud solver (Speciale et al. CVPR 2019) on the same 2D-3D matches: ms per query.

    python benchmarks/line_cloud.py                       # ray-cast box room, 320x240, 24 frames, sift
    python benchmarks/line_cloud.py --frames 40 --size 480x360 --repeat 5

Rows ``scene``: the held-out queries of a ray-cast box room (:mod:`synthleak.localize.testscene`), matched once
against a point map and a line map built from the same triangulation (the same matches: asserted), then
``Localizer.pose_from_matches`` timed on each (pycolmap ``estimate_and_refine_absolute_pose`` vs p6L LO-RANSAC +
refinement; ``ok p/l``: localized by each server's success rule, the line server's from
:func:`~synthleak.localize.line_cloud.line_min_inliers`). Rows ``wrong room``: views of another box room against
the same maps (no true pose: both run to their trial caps). Rows ``synthetic``: 300 matches with 1 px noise and a
given outlier fraction, both at 12 px. The issue's target: a line query costs at most 3x a point query (the
caption's ``line/point`` on the scene rows).

Columns ``+2v``: the same servers with two-view verification (``[localize] two_view_min_inliers``, default 15
here: ``--two-view``): ``verify ms`` is the essential-matrix check of the query's pairs (once per query; both
servers would run it), ``point+2v`` / ``line+2v`` the check plus the pose from the matches it keeps; a view of
another room keeps none and costs the check alone. ``match ms``: matching the query against its retrieved map
images (the same for every server); ``query line+2v/point``: a whole query's time, matching included, of the
verified line server over the unverified point server.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import pycolmap
from rich.console import Console
from rich.table import Table

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import load_sequence, pycolmap_camera
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, look_at, rotation_error_deg
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.line_cloud import LineRansacOptions, estimate_pose_from_lines, lift_to_lines
from synthleak.seeding import make_rng


def _timed(fn, repeat: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times)), out


def _errors(pose: np.ndarray | None, gt: np.ndarray) -> tuple[float, float]:
    if pose is None:
        return float("nan"), float("nan")
    return (float(np.linalg.norm(camera_centre(pose) - camera_centre(gt))),
            rotation_error_deg(pose[:3, :3], gt[:3, :3]))


def bench_scene(work: Path, frames: int, size: tuple[int, int], repeat: int, wrong_views: int,
                two_view: int) -> list[dict]:
    camera = Camera.from_hfov(*size, 65.0)
    scene = ts.write_sequence(work / "room_000", ts.make_room(seed=0), camera, ts.walkthrough_poses(frames),
                              query_every=4)
    other = ts.write_sequence(work / "room_other", ts.make_room(seed=11), camera,
                              ts.walkthrough_poses(max(wrong_views, 2)), query_every=1)
    base = dict(max_keypoints=2048, pairs_per_image=8)
    points_cfg, lines_cfg = LocalizeConfig(**base), LocalizeConfig(**base, representation="line-cloud")
    points = Localizer.load(build_map(scene, "sift", work / "points", points_cfg, progress=False), points_cfg)
    lines = Localizer.load(build_map(scene, "sift", work / "lines", lines_cfg, progress=False), lines_cfg)
    seq, wrong, rows = load_sequence(scene), load_sequence(other), []
    cases = [("scene", seq, frame) for frame in seq.query_frames]
    cases += [("wrong room", wrong, frame) for frame in wrong.frames[:wrong_views]]
    for kind, s, frame in cases:
        query = points.extractor(s.rgb(frame))
        corr = points.correspondences(query, points.candidates(query))
        assert np.array_equal(corr, lines.correspondences(query, lines.candidates(query))), "different matches"
        gt = s.cam_from_world[frame]
        row = {"case": f"{kind} {frame}", "matches": len(corr)}
        for name, loc in (("point", points), ("line", lines)):
            ms, result = _timed(lambda loc=loc, q=query, c=corr: loc.pose_from_matches(q, c, camera), repeat)
            dist, angle = _errors(result.cam_from_world, gt)
            row |= {f"{name}_ms": ms, f"{name}_inliers": result.num_inliers, f"{name}_ok": result.success,
                    f"{name}_cm": 100 * dist, f"{name}_deg": angle}
        candidates = lines.candidates(query)
        row["match_ms"], matches = _timed(lambda q=query, c=candidates: lines.pair_matches(q, c), repeat)
        row["verify_ms"], kept = _timed(lambda q=query, c=candidates, m=matches: lines.verify_pairs(
            q, c, m, camera, two_view), repeat)
        row["kept"], before = len(kept), len(corr)
        for name, loc in (("point", points), ("line", lines)):
            ms, result = _timed(lambda loc=loc, q=query, k=kept, n=before: loc.pose_from_matches(q, k, camera, n),
                                repeat)
            row[f"{name}_v_ms"], row[f"{name}_v_ok"] = row["verify_ms"] + ms, result.success
        rows.append(row)
    return rows


def bench_synthetic(outliers: float, repeat: int, max_error_px: float = 12.0) -> dict:
    camera = Camera.from_hfov(320, 240, 65.0)
    rng = make_rng(0, "bench-line-cloud", outliers)
    gt = look_at([2.5, -2.0, 1.4], [2.3, 2.0, 1.1])
    pts = rng.uniform([0.0, 0.0, 0.0], [5.0, 4.0, 2.6], (3000, 3))
    pc = pts @ gt[:3, :3].T + gt[:3, 3]
    uv = pc[:, :2] / pc[:, 2:3] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    seen = (pc[:, 2] > 0.3) & np.all((uv > 0) & (uv < [camera.width, camera.height]), axis=1)
    pts, uv = pts[seen][:300], uv[seen][:300] + rng.normal(0.0, 1.0, (min(300, int(seen.sum())), 2))
    bad = rng.random(len(uv)) < outliers
    uv[bad] = rng.uniform([0, 0], [camera.width, camera.height], (int(bad.sum()), 2))
    d, a = lift_to_lines(pts, 1)
    cam = pycolmap_camera(camera)
    options = pycolmap.AbsolutePoseEstimationOptions()
    options.ransac.max_error, options.ransac.random_seed = max_error_px, 0
    row = {"case": f"synthetic {outliers:.0%} outliers", "matches": len(uv)}
    for name, fn in (
        ("point", lambda: pycolmap.estimate_and_refine_absolute_pose(uv, pts, cam, options)),
        ("line", lambda: estimate_pose_from_lines(uv, d, a, camera, LineRansacOptions(max_error_px), 0)),
    ):
        ms, est = _timed(fn, repeat)
        pose = None
        if est is not None:
            pose = np.eye(4)
            pose[:3] = est["cam_from_world"].matrix()
        dist, angle = _errors(pose, gt)
        row |= {f"{name}_ms": ms, f"{name}_inliers": int(np.sum(est["inlier_mask"])) if est else 0,
                f"{name}_ok": est is not None, f"{name}_cm": 100 * dist, f"{name}_deg": angle}
    return row


def _median_ratio(rows: list[dict], prefix: str, line: str = "line") -> str:
    """Median point and ``line`` (``line``: unverified, ``line_v``: with the check) ms of the rows ``prefix``."""
    group = [r for r in rows if r["case"].startswith(prefix)]
    if not group:
        return f"{prefix}: none"
    p, q = (float(np.median([r[f"{k}_ms"] for r in group])) for k in ("point", line))
    ratio = float(np.median([r[f"{line}_ms"] / r["point_ms"] for r in group]))
    return f"{prefix} median: point {p:.1f} ms, {line} {q:.1f} ms, {line}/point {ratio:.1f}x"


def _query_ratio(row: dict) -> float:
    """A whole query's time, matching included: the verified line server's over the (unverified) point server's."""
    return (row["match_ms"] + row["line_v_ms"]) / (row["match_ms"] + row["point_ms"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--frames", type=int, default=24)
    parser.add_argument("--size", default="320x240")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--wrong-views", type=int, default=3, help="views of another room (0: none)")
    parser.add_argument("--no-synthetic", action="store_true")
    parser.add_argument("--two-view", type=int, default=15, help="two_view_min_inliers of the +2v columns")
    args = parser.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        rows = bench_scene(Path(tmp), args.frames, size, args.repeat, args.wrong_views, args.two_view)
    if not args.no_synthetic:
        rows += [bench_synthetic(f, args.repeat) for f in (0.1, 0.3, 0.5)]
    table = Table(title="pose from the same matches: point PnP (pycolmap) vs line cloud (p6L LO-RANSAC)")
    for col in ("case", "matches", "point ms", "line ms", "line/point", "inliers p/l", "ok p/l",
                "error p (cm, deg)", "error l (cm, deg)", "kept", "verify ms", "point+2v ms", "line+2v ms",
                "line+2v/point", "ok p/l +2v", "match ms", "query line+2v/point"):
        table.add_column(col, justify="left" if col == "case" else "right")
    for r in rows:
        verified = ["-"] * 8
        if "kept" in r:
            verified = [str(r["kept"]), f"{r['verify_ms']:.1f}", f"{r['point_v_ms']:.1f}", f"{r['line_v_ms']:.1f}",
                        f"{r['line_v_ms'] / r['point_ms']:.1f}x",
                        f"{'y' if r['point_v_ok'] else 'n'}/{'y' if r['line_v_ok'] else 'n'}",
                        f"{r['match_ms']:.1f}", f"{_query_ratio(r):.1f}x"]
        table.add_row(r["case"], str(r["matches"]), f"{r['point_ms']:.1f}", f"{r['line_ms']:.1f}",
                      f"{r['line_ms'] / r['point_ms']:.1f}x", f"{r['point_inliers']}/{r['line_inliers']}",
                      f"{'y' if r['point_ok'] else 'n'}/{'y' if r['line_ok'] else 'n'}",
                      f"{r['point_cm']:.2f}, {r['point_deg']:.3f}", f"{r['line_cm']:.2f}, {r['line_deg']:.3f}",
                      *verified)
    table.caption = "; ".join([_median_ratio(rows, "scene") + " (target <= 3x)", _median_ratio(rows, "wrong room"),
                               _median_ratio(rows, "scene", "line_v") + " (+2v)",
                               _median_ratio(rows, "wrong room", "line_v") + " (+2v)",
                               *(f"{prefix} median whole query (matching included), line+2v/point "
                                 f"{np.median([_query_ratio(r) for r in rows if r['case'].startswith(prefix)]):.1f}x"
                                 for prefix in ("scene", "wrong room")), "ms: median of the repeats"])
    Console(width=200).print(table)


if __name__ == "__main__":
    main()
