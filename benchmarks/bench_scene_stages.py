"""Time stage generation for a paper-sized study (7 rooms x 4-10 objects, ~38 distinct models).

Usage: python benchmarks/bench_scene_stages.py [OUT_DIR] [--seed N]
Prints wall time for a cold run, a re-run (skips unchanged stages) and per-stage sizes.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from synthleak.config import config_from_dict
from synthleak.scene.generate import write_study_stages


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("out", nargs="?", type=Path, default=None)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="synthleak-stages-"))
    config = config_from_dict(
        {
            "name": "bench-paper",
            "seed": args.seed,
            "scenes": {"rooms": 7, "objects_per_room": [4, 10], "distinct_objects": 38},
        }
    )
    t0 = time.perf_counter()
    index_path = write_study_stages(config, out, progress=True)
    cold = time.perf_counter() - t0
    t0 = time.perf_counter()
    write_study_stages(config, out, progress=False)
    warm = time.perf_counter() - t0
    index = json.loads(index_path.read_text())
    objects = sum(len(r["objects"]) for r in index["rooms"])
    dropped = sum(len(r["dropped"]) for r in index["rooms"])
    size_mb = sum(p.stat().st_size for p in out.rglob("*") if p.is_file()) / 1e6
    textures = len(list((out / "textures").iterdir()))
    print(f"out: {out}")
    print(
        f"rooms: {len(index['rooms'])}, placed objects: {objects} (dropped {dropped}), "
        f"attacker objects (distinct models): {len(index['attacker_objects'])}"
    )
    print(f"cold run: {cold:.1f} s   re-run (all skipped): {warm:.2f} s")
    print(f"files: {size_mb:.1f} MB, {textures} textures")


if __name__ == "__main__":
    main()
