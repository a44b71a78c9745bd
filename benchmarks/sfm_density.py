"""How dense an attacker orbit SfM needs: SfM of every attacker orbit of a finished study, on all its frames and
on every k-th frame, with registration, misregistered views, scale error and build time per object.

Usage:
    python benchmarks/sfm_density.py STUDY_DIR [--steps 1,2] [--workdir /tmp/sfm_density] [--seed 2023]

Reads ``STUDY_DIR/dataset`` only; the SfM models go to ``--workdir`` (cached by content: a second run reports
the build time recorded the first time). COLMAP logs to stderr; the table goes to stdout.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from synthleak.attack.local_model import cached_sfm_local_poses
from synthleak.core.dataset import load_sequence, read_index


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("--steps", default="1,2", help="orbit subsampling steps (1: every frame)")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/sfm_density"))
    parser.add_argument("--seed", type=int, default=2023)
    args = parser.parse_args()
    dataset = args.study / "dataset"
    steps = [int(s) for s in args.steps.split(",")]
    print("| object | frames | registered | misregistered | scale error % | object points | seconds | problem |")
    print("|---|---|---|---|---|---|---|---|")
    for obj in read_index(dataset / "stages")["attacker_objects"]:
        seq = load_sequence(dataset / "attackers" / obj["id"])
        extents = seq.objects_by_id()[seq.target_instance_id].extents
        for step in steps:
            frames = list(seq.frames)[::step]
            model = cached_sfm_local_poses(seq, extents, args.workdir / f"{obj['id']}_every{step}", seed=args.seed,
                                           frames=frames)
            stats = model.stats
            scale = 100 * stats.get("scale_error", math.nan)
            print(f"| {obj['id']} | {len(frames)} | {len(model.registered)} | {len(stats.get('misregistered') or [])} "
                  f"| {scale:+.1f} | {stats.get('n_object_points', 0)} | {stats.get('seconds', math.nan)} | "
                  f"{'' if model.ok else model.message} |", flush=True)


if __name__ == "__main__":
    main()
