"""Localization throughput per tier at 640x480: queries per second, time split, mapping time.

    python benchmarks/localize.py                      # synthetic textured box room (embree ray cast)
    python benchmarks/localize.py --scene DATASET/scenes/room_000 --tiers sift orb

For each tier: build the map (reports seconds per 100 database images), localize every held-out query
(reports queries/s, the split between feature extraction, retrieval + matching and PnP, and how many
localized). Tiers whose dependencies or weights are missing are listed as skipped with the reason.
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
from synthleak.geometry.poses import camera_centre
from synthleak.localize import TIERS, Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.sequence import read_sequence
from synthleak.render.base import Camera


def synthetic_scene(root: Path, frames: int, width: int, height: int) -> Path:
    camera = Camera.from_hfov(width, height, 65.0)
    return ts.write_sequence(root / "room_000", ts.make_room(seed=0), camera, ts.walkthrough_poses(frames))


def bench_tier(scene: Path, tier: str, work: Path, config: LocalizeConfig, weights: Path | None) -> dict:
    t0 = time.perf_counter()
    map_dir = build_map(scene, tier, work / tier, config, progress=False, weights_dir=weights)
    map_s = time.perf_counter() - t0
    seq = read_sequence(scene)
    loc = Localizer.load(map_dir, config, weights_dir=weights)
    loc.localize(seq.rgb(seq.query_frames[0]))  # warm-up
    rows, errors = [], []
    for frame in seq.query_frames:
        result = loc.localize(seq.rgb(frame))
        rows.append(result.timings)
        if result.success:
            errors.append(np.linalg.norm(camera_centre(result.cam_from_world)
                                         - camera_centre(seq.cam_from_world[frame])))
    mean = {k: float(np.mean([r[k] for r in rows])) for k in ("features", "matching", "pnp", "total")}
    return {"map_per_100": map_s / len(seq.map_frames) * 100, "qps": 1.0 / mean["total"], **mean,
            "localized": f"{len(errors)}/{len(rows)}",
            "median_cm": float(np.median(errors) * 100) if errors else float("nan")}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--scene", type=Path, help="a dataset sequence folder (default: synthetic box room)")
    parser.add_argument("--tiers", nargs="+", default=list(TIERS))
    parser.add_argument("--frames", type=int, default=40, help="synthetic walk-through frames")
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--retrieval", default="exhaustive", choices=["exhaustive", "bow"])
    parser.add_argument("--max-keypoints", type=int, default=4096)
    parser.add_argument("--weights-dir", type=Path, help="DISK/LightGlue weights (disk-lightglue tier)")
    args = parser.parse_args()
    console = Console(width=150)
    config = LocalizeConfig(retrieval=args.retrieval, max_keypoints=args.max_keypoints)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        scene = args.scene
        if scene is None:
            t0 = time.perf_counter()
            scene = synthetic_scene(work / "scene", args.frames, args.width, args.height)
            console.print(f"rendered {args.frames} synthetic frames at {args.width}x{args.height} "
                          f"in {time.perf_counter() - t0:.1f} s")
        seq = read_sequence(scene)
        table = Table(title=f"localization, {seq.camera.width}x{seq.camera.height}, "
                            f"{len(seq.map_frames)} map "
                            f"images, {len(seq.query_frames)} queries, retrieval={args.retrieval}, "
                            f"max_keypoints={args.max_keypoints}")
        for col in ("tier", "queries/s", "features s", "retrieval+matching s", "PnP s", "localized",
                    "median err cm", "mapping s / 100 images"):
            table.add_column(col, justify="right")
        for tier in args.tiers:
            try:
                r = bench_tier(scene, tier, work, config, args.weights_dir)
            except (ImportError, FileNotFoundError, RuntimeError) as exc:
                console.print(f"{tier}: skipped: {exc}")
                table.add_row(tier, "skipped", "", "", "", "", "", "")
                continue
            row = (tier, f"{r['qps']:.2f}", f"{r['features']:.3f}", f"{r['matching']:.3f}", f"{r['pnp']:.3f}",
                   r["localized"], f"{r['median_cm']:.2f}", f"{r['map_per_100']:.1f}")
            table.add_row(*row)
            console.print(" | ".join(row))  # partial results survive an interrupted run
        console.print(table)


if __name__ == "__main__":
    main()
