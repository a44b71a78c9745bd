"""The paper's stricter-threshold defense, measured: leakage and utility of strict servers per PnP threshold.

Chelani et al. (CVPR 2023, supplementary, "Impact of changing the inlier threshold") localized attacker
queries with HLoc at 12 px and at 5, 2 and 1 px and judged the alignments by eye ("a more rigorous
experimentation against this defence would definitely be more insightful"). This script measures it on one
finished study: for each threshold it runs the study's config again in a copy of the study folder with
``[localize] pnp_max_error_px`` set and only the named strict servers; the renders, maps and query features are
reused (their content keys do not hold the threshold), the queries, attack and report are redone.

Usage:
    python benchmarks/pnp_threshold.py STUDY_DIR CONFIG --px 12,8,4,2 [--servers sift,xfeat] [--out DIR]

``DIR`` (default ``STUDY_DIR-pnp``) holds one copy per threshold (``px-<value>``), kept: a rerun resumes them.
Prints per server and threshold: genuine queries localized (all / close-ups) and their median error, attacker
queries localized over present / absent pairs, presence precision and recall and objects placed by Alg. 1 at the
study's first threshold pair, and the share of localized attacker queries mostly on the room's shell.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import shutil
from pathlib import Path
from typing import Any

from synthleak.config import StudyConfig, load_config
from synthleak.errors import ConfigError
from synthleak.evaluate.doc_blocks import markdown_table
from synthleak.evaluate.results_page import results_summary
from synthleak.localize.servers import server_by_name
from synthleak.provenance import config_key, read_run_record


def threshold_config(config: StudyConfig, px: float, servers: list[str]) -> StudyConfig:
    """``config`` with strict servers ``servers`` only, at PnP threshold ``px`` (pixels)."""
    localize = dataclasses.replace(config.localize, pnp_max_error_px=float(px), servers=list(servers))
    return dataclasses.replace(config, localize=localize, name=f"{config.name}-pnp{px:g}px")


def run_threshold(study: Path, config: StudyConfig, px: float, servers: list[str], out: Path,
                  workers: int) -> dict[str, Any]:
    """Queries, attack and report of ``servers`` at ``px`` in ``out`` (a copy of ``study`` made once); the
    finished study's :func:`results_summary`."""
    from synthleak.study import run_study

    if not out.exists():
        shutil.copytree(study, out, symlinks=True, ignore=shutil.ignore_patterns(".study.lock"))
    run_study(threshold_config(config, px, servers), out, progress=False, workers=workers)
    return results_summary(out)


def rows_of(summary: dict[str, Any], px: float) -> list[dict[str, Any]]:
    """One row per server of a :func:`results_summary`: utility, leakage and shell share at ``px``."""
    shell = {r["tier"]: r for r in summary["shell"]}
    out = []
    for s in summary["servers"]:
        sh = shell.get(s["server"], {})
        out.append({"server": s["server"], "px": px, "genuine": s["genuine_localized"],
                    "closeups": s["closeups_localized"], "rot": s["median_rot_err_deg"],
                    "trans": s["median_trans_err_m"], "present": s["attacker_localized_present"],
                    "absent": s["attacker_localized_absent"], "precision": s["precision"], "recall": s["recall"],
                    "placed": s["placed_alg1"], "shell": sh.get("n_shell_top_all", 0),
                    "localized": sh.get("n_localized_all", 0)})
    return out


def _f(value: Any) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.3f}"


def print_table(rows: list[dict[str, Any]]) -> None:
    header = ["server", "PnP px", "genuine localized", "close-ups localized", "median genuine error (° / m)",
              "attacker localized, present / absent", "P / R", "placed (Alg. 1)", "mostly on the room's shell"]
    print(markdown_table(header, [
        [r["server"], f"{r['px']:g}", _f(r["genuine"]), _f(r["closeups"]), f"{_f(r['rot'])} / {_f(r['trans'])}",
         f"{_f(r['present'])} / {_f(r['absent'])}", f"{_f(r['precision'])} / {_f(r['recall'])}", _f(r["placed"]),
         f"{r['shell']} of {r['localized']}"]
        for r in sorted(rows, key=lambda r: (r["server"], -r["px"]))]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path, help="a finished synthleak study folder (renders, maps, features)")
    parser.add_argument("config", help="the config it was run with (a preset name or a TOML path)")
    parser.add_argument("--px", default="12,8,4,2", help="comma-separated PnP thresholds in pixels")
    parser.add_argument("--servers", default="sift,xfeat", help="comma-separated strict servers of CONFIG")
    parser.add_argument("--out", type=Path, default=None, help="folder of the copies (default: STUDY-pnp)")
    parser.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    try:
        config = load_config(args.config)
        thresholds = [float(v) for v in args.px.split(",")]
    except ConfigError as exc:
        parser.exit(2, f"error: {exc}\n")
    except ValueError:
        parser.exit(2, f"error: --px: expected comma-separated numbers, got {args.px!r}\n")
    if any(not math.isfinite(v) or v <= 0 for v in thresholds):
        parser.exit(2, f"error: --px: thresholds must be positive pixels, got {args.px!r}\n")
    servers = args.servers.split(",")
    known = server_by_name(dataclasses.replace(config.localize, servers=[], profile="strict"))
    unknown = [s for s in servers if s not in known]
    if unknown:
        parser.exit(2, f"error: --servers: {', '.join(unknown)} not a strict server of {args.config} "
                       f"(known: {', '.join(known)})\n")
    if not (args.study / "run.json").is_file() or not (args.study / "maps").is_dir():
        parser.exit(2, f"error: {args.study}: not a finished study folder (no run.json or maps/)\n")
    keys = {run["config_key"]: run["config"] for run in read_run_record(args.study)}
    if config_key(config) not in keys:  # another config: its copies would render and map everything again
        parser.exit(2, f"error: {args.study}/run.json: run with {', '.join(f'{c} (key {k})' for k, c in keys.items())}"
                       f", not {args.config} (key {config_key(config)}): pass the config the study was run with\n")
    out = args.out or args.study.with_name(args.study.name + "-pnp")
    rows: list[dict[str, Any]] = []
    for px in thresholds:
        summary = run_threshold(args.study, config, px, servers, out / f"px-{px:g}", args.workers)
        rows += rows_of(summary, px)
    print(f"study {args.study} ({summary['config']} at {summary['commit']}, {summary['cpu']}); first threshold "
          f"pair of the attack, aligner {summary['aligner']}, presence {summary['presence']}\n")
    print_table(rows)


if __name__ == "__main__":
    main()
