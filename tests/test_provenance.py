"""run.json: each invocation recorded from its start, so a killed one keeps its stages; pages say what it covers."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from synthleak.config import load_config, load_costs
from synthleak.evaluate.results_page import render_page, results_summary, write_results_page
from synthleak.provenance import config_key, read_run_record, start_run, update_run


def test_an_invocation_is_recorded_at_its_start_and_updated_per_stage(tmp_path: Path) -> None:
    config = load_config("ci-tiny")
    study = tmp_path / "study"
    study.mkdir()
    (study / ".study.lock").touch()  # held by the running study: not content
    first = start_run(study, config, workers=2, executor="local")
    (entry,) = read_run_record(study)
    assert (first, entry["finished"], entry["started_empty"], entry["stage_s"]) == (0, False, True, {})
    assert entry["config_key"] == config_key(config) and entry["workers"] == 2
    (study / "dataset").mkdir()
    update_run(study, first, started=0.0, timings={"render": 12.5})  # killed after this: the stage stays
    second = start_run(study, config, workers=2, executor="local")
    update_run(study, second, started=0.0, timings={"render": 0.1, "maps": 3.0}, finished=True)
    runs = read_run_record(study)
    assert [(r["started_empty"], r["finished"], r["stage_s"]) for r in runs] == [
        (True, False, {"render": 12.5}), (False, True, {"render": 0.1, "maps": 3.0})]


def _wall_line(summary: dict) -> str:
    return render_page(summary).split("| wall time |")[1].splitlines()[0]


def test_a_page_from_a_folder_made_partly_by_unrecorded_runs_says_so(ci_tiny_study: Path, tmp_path: Path) -> None:
    """A record whose first invocation found the renders made (old records: no `started_empty`, render ~0 s)
    is not the cost from an empty folder: the page and the presets table say so instead of under-reporting it."""
    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study / "results", study / "results")
    runs = json.loads((ci_tiny_study / "run.json").read_text())["runs"]
    assert runs[-1]["finished"] is True and runs[0]["started_empty"] is True
    assert " min from an empty folder" in _wall_line(results_summary(ci_tiny_study))

    legacy = [{k: v for k, v in r.items() if k not in ("started_empty", "finished")} for r in runs]
    legacy[0]["stage_s"] = {**legacy[0]["stage_s"], "render": 0.0}
    (study / "run.json").write_text(json.dumps({"runs": legacy}))
    summary = results_summary(study)
    assert summary["from_empty"] is False and summary["unfinished"] == 0
    line = _wall_line(summary)
    assert " min from an empty folder" not in line and "less than the cost from an empty folder" in line, line

    page = write_results_page(study, tmp_path / "docs" / "results" / "ci-tiny.md")
    (cost,) = load_costs(page.parent / "index.json").values()
    assert cost.from_empty is False and str(cost).startswith(">= ")
