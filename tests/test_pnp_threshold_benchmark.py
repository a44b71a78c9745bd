"""``benchmarks/pnp_threshold.py``: the paper's stricter-threshold defense measured on a finished study's copies."""

from __future__ import annotations

import importlib.util
from pathlib import Path

from synthleak.config import load_config
from synthleak.evaluate.results_page import results_summary
from synthleak.provenance import read_run_record

BENCH = Path(__file__).parents[1] / "benchmarks" / "pnp_threshold.py"


def _module():
    spec = importlib.util.spec_from_file_location("pnp_threshold", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_copy_at_the_studys_threshold_reproduces_it_and_a_stricter_one_localizes_less(ci_tiny_study: Path,
                                                                                        tmp_path: Path):
    bench = _module()
    config = load_config("ci-tiny")
    logs = {p: p.read_bytes() for p in sorted((ci_tiny_study / "queries").rglob("queries.jsonl"))}
    same = bench.rows_of(bench.run_threshold(ci_tiny_study, config, 12.0, ["sift"], tmp_path / "px-12", 1), 12.0)
    base = bench.rows_of(results_summary(ci_tiny_study), 12.0)
    assert same == [r for r in base if r["server"] == "sift"]  # reused renders, maps, features: the same figures
    strict = bench.rows_of(bench.run_threshold(ci_tiny_study, config, 2.0, ["sift"], tmp_path / "px-2", 1), 2.0)
    (at12,), (at2,) = same, strict
    assert at2["present"] + at2["absent"] < at12["present"] + at12["absent"]  # fewer chance inliers: fewer poses
    assert at2["genuine"] <= at12["genuine"]
    assert read_run_record(tmp_path / "px-2")[-1]["config_dict"]["localize"]["pnp_max_error_px"] == 2.0
    assert logs and logs == {p: p.read_bytes() for p in sorted((ci_tiny_study / "queries").rglob("queries.jsonl"))}
    # the study itself untouched: only its copies were re-queried
