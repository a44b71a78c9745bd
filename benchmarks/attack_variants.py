"""Attack a finished study again with other aligners / local models, on its query logs, and print them side by side.

Usage:
    python benchmarks/attack_variants.py STUDY_DIR CONFIG [--aligners alg1,robust,pivot,upright]
                                         [--local-model oracle|sfm] [--compare-oracle] [--rebuild-sfm]

Reads ``STUDY_DIR`` (dataset, maps, queries; nothing is written there except SfM models under
``STUDY_DIR/sfm`` with ``--local-model sfm``). Prints, per tier and threshold pair and pooled over the threshold
pairs: presence P/R, success at (10°, 0.25 m) over the GT-present pairs, median rotation / translation error over
the pairs every variant placed. ``--compare-oracle`` puts the oracle local model beside the SfM one;
``--rebuild-sfm`` times SfM from scratch (otherwise cached models report the build time they recorded).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import time
from pathlib import Path

from synthleak.attack.align import get_aligner
from synthleak.attack.local_poses import sfm_model
from synthleak.config import load_config
from synthleak.core.dataset import load_sequence, read_index
from synthleak.errors import SynthleakError
from synthleak.evaluate.compare import side_by_side_markdown
from synthleak.evaluate.sfm_summary import sfm_objects_markdown
from synthleak.study import StudyPaths, attack_rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("config")
    parser.add_argument("--aligners", default="alg1,robust,pivot,upright")
    parser.add_argument("--local-model", default="oracle", choices=["oracle", "sfm"])
    parser.add_argument("--compare-oracle", action="store_true")
    parser.add_argument("--rebuild-sfm", action="store_true")
    args = parser.parse_args()
    paths = StudyPaths(args.study)
    aligners = args.aligners.split(",")
    try:  # bad input: one line naming it, before any work
        config = load_config(args.config)
        for aligner in aligners:
            get_aligner(aligner)
        rooms = read_index(paths.dataset / "stages")["rooms"]
    except (SynthleakError, ValueError) as exc:
        parser.error(str(exc))
    logs = {(tier, room["name"]): paths.query_log(tier, room["name"])
            for tier in config.localize.tiers for room in rooms}
    missing = [str(p) for p in logs.values() if not p.is_file()]
    if missing:
        raise SystemExit(f"{args.study}: no query logs for {missing[:3]} (run the study first)")

    def rows_for(local_model: str) -> list[dict]:
        cfg = dataclasses.replace(config, attack=dataclasses.replace(config.attack, aligners=aligners,
                                                                     local_model=local_model))
        return attack_rows(cfg, paths, logs)

    if args.local_model == "sfm":
        objects = read_index(paths.dataset / "stages")["attacker_objects"]
        if args.rebuild_sfm:
            shutil.rmtree(paths.sfm, ignore_errors=True)
        start = time.perf_counter()
        models = {o["id"]: sfm_model(load_sequence(paths.attacker(o["id"])), paths.sfm_dir(o["id"]), config.seed)
                  for o in objects}
        print(f"## SfM local models ({time.perf_counter() - start:.1f} s now; build seconds per object below)\n")
        print(sfm_objects_markdown(models))
    rows = rows_for(args.local_model)
    if args.compare_oracle and args.local_model == "sfm":
        oracle = rows_for("oracle")
        for aligner in aligners:
            variants = {"oracle": [r for r in oracle if r["aligner"] == aligner],
                        "sfm": [r for r in rows if r["aligner"] == aligner]}
            print(f"## {aligner}: oracle vs SfM, per threshold pair\n")
            print(side_by_side_markdown(variants, variant_label="local model"))
            print(f"## {aligner}: oracle vs SfM, pooled over the threshold pairs\n")
            print(side_by_side_markdown(variants, ("tier",), variant_label="local model"))
    by_aligner = {a: [r for r in rows if r["aligner"] == a] for a in aligners}
    print(f"## Aligners ({args.local_model} local model), per threshold pair\n")
    print(side_by_side_markdown(by_aligner, variant_label="aligner"))
    print(f"## Aligners ({args.local_model} local model), pooled over the threshold pairs\n")
    print(side_by_side_markdown(by_aligner, ("tier",), variant_label="aligner"))
    pooled = {a: [dict(r, pooled="all tiers") for r in v] for a, v in by_aligner.items()}
    print(f"## Aligners ({args.local_model} local model), pooled over tiers and threshold pairs\n")
    print(side_by_side_markdown(pooled, ("pooled",), variant_label="aligner"))


if __name__ == "__main__":
    main()
