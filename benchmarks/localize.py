"""Localization throughput per tier at 480x360 and 640x480: queries per second, time split, mapping time.

    python benchmarks/localize.py                      # synthetic textured box room (embree ray cast), both sizes
    python benchmarks/localize.py --sizes 640x480 --tiers sift xfeat
    python benchmarks/localize.py --scene DATASET/scenes/room_000 --tiers sift orb

For each size and tier: build the map (reports seconds per 100 database images), localize every held-out query
(reports queries/s, feature extraction seconds per image, matcher seconds per matched image pair, the split
between retrieval + matching and PnP, and how many localized). Tiers whose dependencies or weights are missing
are listed as skipped with the reason. torch runs with ``$SYNTHLEAK_TORCH_THREADS`` threads (default 1, as in a
study's workers).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre
from synthleak.localize import TIERS, Localizer, build_map
from synthleak.localize import testscene as ts


def synthetic_scene(root: Path, frames: int, width: int, height: int) -> Path:
    camera = Camera.from_hfov(width, height, 65.0)
    return ts.write_sequence(root / "room_000", ts.make_room(seed=0), camera, ts.walkthrough_poses(frames))


def bench_tier(scene: Path, tier: str, work: Path, config: LocalizeConfig, weights: Path | None) -> dict:
    t0 = time.perf_counter()
    map_dir = build_map(scene, tier, work / tier, config, progress=False, weights_dir=weights)
    map_s = time.perf_counter() - t0
    seq = load_sequence(scene)
    loc = Localizer.load(map_dir, config, weights_dir=weights)
    loc.localize(seq.rgb(seq.query_frames[0]))  # warm-up
    matcher, pair_s = loc.matcher, []

    def timed_matcher(a, b):
        start = time.perf_counter()
        out = matcher(a, b)
        pair_s.append(time.perf_counter() - start)
        return out

    loc.matcher = timed_matcher
    rows, errors = [], []
    for frame in seq.query_frames:
        result = loc.localize(seq.rgb(frame))
        rows.append(result.timings)
        if result.success:
            errors.append(np.linalg.norm(camera_centre(result.cam_from_world)
                                         - camera_centre(seq.cam_from_world[frame])))
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("features", "matching", "pnp", "total")}
    return {"map_per_100": map_s / len(seq.map_frames) * 100, "qps": 1.0 / mean["total"], **mean,
            "pair_s": float(np.mean(pair_s)), "pairs_per_query": len(pair_s) / len(rows),
            "localized": f"{len(errors)}/{len(rows)}",
            "median_cm": float(np.median(errors) * 100) if errors else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", type=Path, help="a dataset sequence folder (default: synthetic box room)")
    parser.add_argument("--tiers", nargs="+", default=list(TIERS))
    parser.add_argument("--frames", type=int, default=40, help="synthetic walk-through frames")
    parser.add_argument("--sizes", nargs="+", default=["480x360", "640x480"], help="synthetic image sizes, WxH")
    parser.add_argument("--retrieval", default="exhaustive", choices=["exhaustive", "bow"])
    parser.add_argument("--top-k", type=int, default=10, help="retrieved images (bow, and learned matchers)")
    parser.add_argument("--max-keypoints", type=int, default=4096, help="capped by each tier's keypoint budget")
    parser.add_argument("--weights-dir", type=Path, help="folder searched for weight files before the packages")
    args = parser.parse_args()
    console = Console(width=170)
    config = LocalizeConfig(retrieval=args.retrieval, top_k=args.top_k, max_keypoints=args.max_keypoints)
    columns = ("size", "tier", "queries/s", "features s/image", "matching s/pair", "pairs/query",
               "retrieval+matching s", "PnP s", "localized", "median err cm", "mapping s / 100 images")
    table = Table(title=f"localization, retrieval={args.retrieval}, top_k={args.top_k}, "
                        f"max_keypoints={args.max_keypoints} (capped per tier)")
    for col in columns:
        table.add_column(col, justify="right")
    with tempfile.TemporaryDirectory() as tmp:
        sizes = [None] if args.scene is not None else [tuple(int(v) for v in s.split("x")) for s in args.sizes]
        for size in sizes:
            work = Path(tmp) / ("scene" if size is None else f"{size[0]}x{size[1]}")
            scene = args.scene
            if size is not None:
                t0 = time.perf_counter()
                scene = synthetic_scene(work / "scene", args.frames, *size)
                console.print(f"rendered {args.frames} synthetic frames at {size[0]}x{size[1]} "
                              f"in {time.perf_counter() - t0:.1f} s")
            seq = load_sequence(scene)
            label = f"{seq.camera.width}x{seq.camera.height}"
            console.print(f"{label}: {len(seq.map_frames)} map images, {len(seq.query_frames)} queries")
            for tier in args.tiers:
                try:
                    r = bench_tier(scene, tier, work, config, args.weights_dir)
                except (ImportError, FileNotFoundError, RuntimeError) as exc:
                    console.print(f"{tier}: skipped: {exc}")
                    table.add_row(label, tier, "skipped", *[""] * (len(columns) - 3))
                    continue
                row = (label, tier, f"{r['qps']:.2f}", f"{r['features']:.3f}", f"{r['pair_s']:.3f}",
                       f"{r['pairs_per_query']:.1f}", f"{r['matching']:.3f}", f"{r['pnp']:.3f}", r["localized"],
                       f"{r['median_cm']:.2f}", f"{r['map_per_100']:.1f}")
                table.add_row(*row)
                console.print(" | ".join(row))  # partial results survive an interrupted run
    console.print(table)


if __name__ == "__main__":
    main()
