"""Sweep the defense threshold X (paper Sec. 6, Fig. 6) over a finished study's query logs and plot it.

The server's defense answers a query only if at least k scene instances each hold a fraction X of the PnP
inliers of the instance holding most. Every query log line keeps its inlier counts per instance, so the
defense replays offline for any (X, k): the fraction of genuine queries it keeps and of attacker queries it
rejects, among those the server localized. Written to a PNG with matplotlib (object API, no pyplot).

    python examples/04_sweep_and_plot.py                      # runs the ci-tiny study into runs/examples/study
    python examples/04_sweep_and_plot.py --study STUDY --min-instances 3 --png runs/examples/defense_x.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

from matplotlib.figure import Figure

from synthleak.config import load_config
from synthleak.evaluate.defense_sweep import defense_tradeoff
from synthleak.study import defense_queries, run_study


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="ci-tiny", help="config of the study run when --study is not given")
    parser.add_argument("--out", type=Path, default=Path("runs/examples"), help="OUT/study (no --study)")
    parser.add_argument("--study", type=Path, help="a finished study folder (its queries/<tier>/<room>/ logs)")
    parser.add_argument("--min-instances", type=int, nargs="+", default=[2, 3, 4], help="k, one curve pair each")
    parser.add_argument("--fractions", type=float, nargs="+", default=[round(0.05 * i, 2) for i in range(1, 11)],
                        help="the values of X swept")
    parser.add_argument("--png", type=Path, help="default: OUT/defense_sweep.png")
    args = parser.parse_args(argv)
    study = args.study or args.out / "study"
    if args.study is None:
        run_study(load_config(args.preset), study, progress=False)  # resumable: a finished study is reused

    logs = {(p.parent.parent.name, p.parent.name): p for p in sorted(study.glob("queries/*/*/queries.jsonl"))}
    queries = defense_queries(logs)  # one dict per logged query: genuine?, localized?, inliers per instance
    print(f"{len(logs)} servers, {sum(q['genuine'] for q in queries)} genuine and "
          f"{sum(not q['genuine'] for q in queries)} attacker queries")
    rows = defense_tradeoff(queries, args.fractions, args.min_instances, by=())  # pooled over tiers and rooms
    print(f"localized without the defense: {rows[0]['n_genuine']} genuine, {rows[0]['n_attacker']} attacker")

    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    print("   k      X  genuine_kept  attacker_rejected")
    for i, k in enumerate(args.min_instances):
        curve = [r for r in rows if r["min_instances"] == k]
        for r in curve:
            print(f"{k:4d} {r['min_fraction']:6.2f} {r['genuine_kept']:13.3f} {r['attacker_rejected']:18.3f}")
        xs = [r["min_fraction"] for r in curve]
        ax.plot(xs, [r["genuine_kept"] for r in curve], "-o", color=f"C{i}", label=f"genuine kept, k={k}")
        ax.plot(xs, [r["attacker_rejected"] for r in curve], "--s", color=f"C{i}", label=f"attacker rejected, k={k}")
    ax.set(xlabel="X (fraction of the top instance's inliers)", ylabel="fraction of localized queries",
           ylim=(-0.05, 1.05), title=f"Query defense over {study.name}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=len(args.min_instances), loc="upper center", bbox_to_anchor=(0.5, -0.15))
    png = args.png or args.out / "defense_sweep.png"
    png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(png, dpi=110, bbox_inches="tight")
    print(f"wrote {png}")


if __name__ == "__main__":
    main()
