"""A queries stage stopped part way resumes after its finished tasks and writes the same logs."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from synthleak.config import load_config
from synthleak.study import queries as queries_stage
from synthleak.study import run_study


def _logs(study: Path) -> dict[str, bytes]:
    return {str(p.relative_to(study)): p.read_bytes() for p in sorted((study / "queries").glob("*/*/queries.jsonl"))}


def test_a_stopped_queries_stage_resumes_after_its_finished_tasks(ci_tiny_study, tmp_path, monkeypatch):
    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study, study)
    expected = _logs(study)
    assert expected
    shutil.rmtree(study / "queries")  # as if the stage had never finished
    config = load_config("ci-tiny")
    real_task, calls = queries_stage.query_task, []

    def stops_after_two(task):
        if len(calls) == 2:
            raise KeyboardInterrupt  # Ctrl-C in the middle of the stage
        calls.extend(t.part_file for t in task.targets)
        return real_task(task)

    monkeypatch.setattr(queries_stage, "query_task", stops_after_two)
    with pytest.raises(KeyboardInterrupt):
        run_study(config, study, progress=False)
    finished = sorted((study / "queries").glob("*/*/.parts-*/*.jsonl"))
    assert finished == sorted(calls) and len(finished) == 2
    assert not _logs(study)  # no server's log is written before all its tasks are done

    resumed = []
    monkeypatch.setattr(queries_stage, "query_task",
                        lambda task: resumed.extend(t.part_file for t in task.targets) or real_task(task))
    run_study(config, study, progress=False)
    assert resumed and not set(resumed) & set(finished)  # the finished tasks are not run again
    assert _logs(study) == expected  # the same bytes as the uninterrupted run
    assert not list((study / "queries").glob("*/*/.parts-*"))  # parts are removed once the log is written
