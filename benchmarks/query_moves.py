"""Which queries' outcomes moved between two runs of one study (e.g. before and after a change of the pose solver).

    python benchmarks/query_moves.py runs/before runs/after

Per server: queries in both logs, localized in each, queries localized in one run only (each way), the median
and largest change of inliers where both localized, and the rotation / translation between the two poses; then
per server and attack thresholds the presence precision / recall of the paper's Alg. 1 in each run. The two runs
must be of the same config and renders (the script says where the dataset manifests differ).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from synthleak.evaluate.tables import precision_recall, read_results
from synthleak.geometry.poses import rotation_error_deg


def _logs(study: Path) -> dict[str, dict[tuple, dict]]:
    out: dict[str, dict[tuple, dict]] = {}
    for log in sorted(study.glob("queries/*/*/queries.jsonl")):
        for line in log.read_text().splitlines():
            if line.strip():
                q = json.loads(line)
                out.setdefault(q["tier"], {})[(q["room"], q["sequence"], q["frame"])] = q
    return out


def _same_renders(a: Path, b: Path) -> bool:
    manifests = [p / "dataset" / "manifest.json" for p in (a, b)]
    return all(m.is_file() for m in manifests) and manifests[0].read_bytes() == manifests[1].read_bytes()


def _median(values: list[float]) -> float:
    return float(np.median(values)) if values else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path)
    parser.add_argument("after", type=Path)
    args = parser.parse_args()
    print(f"# benchmarks/query_moves.py {args.before} {args.after}")
    print(f"# renders: {'the same bytes' if _same_renders(args.before, args.after) else 'DIFFERENT manifests'}")
    before, after = _logs(args.before), _logs(args.after)
    print(f"{'server':<14} {'queries':>7} {'loc_a':>6} {'loc_b':>6} {'a_only':>6} {'b_only':>6} "
          f"{'d_inl_med':>9} {'d_inl_max':>9} {'rot_med':>8} {'t_med_m':>8}")
    for server in sorted(set(before) & set(after)):
        a, b = before[server], after[server]
        keys = sorted(set(a) & set(b))
        loc_a = {k for k in keys if a[k]["success"]}
        loc_b = {k for k in keys if b[k]["success"]}
        both = sorted(loc_a & loc_b)
        d_inl = [abs(a[k]["num_inliers"] - b[k]["num_inliers"]) for k in both]
        poses = [(np.array(a[k]["cam_from_world"]), np.array(b[k]["cam_from_world"])) for k in both]
        rot = [rotation_error_deg(pa[:3, :3], pb[:3, :3]) for pa, pb in poses]
        trans = [float(np.linalg.norm(pa[:3, 3] - pb[:3, 3])) for pa, pb in poses]
        print(f"{server:<14} {len(keys):>7} {len(loc_a):>6} {len(loc_b):>6} {len(loc_a - loc_b):>6} "
              f"{len(loc_b - loc_a):>6} {_median(d_inl):>9.1f} {max(d_inl, default=0):>9} {_median(rot):>8.4f} "
              f"{_median(trans):>8.4f}")
    rows = {name: read_results(p / "results" / "results.json") for name, p in (("a", args.before), ("b", args.after))
            if (p / "results" / "results.json").is_file()}
    if len(rows) == 2:
        print(f"\n{'server':<14} {'thresholds':<12} {'P/R a':>11} {'P/R b':>11}")
        groups = sorted({(r["tier"], r["delta_r_deg"], r["delta_t_m"]) for r in rows["a"] if r["aligner"] == "alg1"})
        for tier, dr, dt in groups:
            pr = {}
            for name, rs in rows.items():
                sel = [r for r in rs if r["aligner"] == "alg1" and (r["tier"], r["delta_r_deg"], r["delta_t_m"]) ==
                       (tier, dr, dt)]
                counts = precision_recall(sel)
                pr[name] = f"{counts['precision']:.2f}/{counts['recall']:.2f}"
            print(f"{tier:<14} {f'{dr:g}/{dt:g}':<12} {pr['a']:>11} {pr['b']:>11}")


if __name__ == "__main__":
    main()
