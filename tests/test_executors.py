"""Executors: results in input order, clear errors, and byte-identical study outputs on `ci-tiny` whatever the
executor (serial, a 2-process pool, a local Ray)."""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from pathlib import Path

import pytest

from synthleak.executors import ExecutorError, LocalExecutor, chunks, make_executor


def _slow_square(x: int) -> int:
    time.sleep(0.05 * (4 - x % 4))  # later items finish first
    return x * x


def _fail_on_three(x: int) -> int:
    if x == 3:
        raise ValueError("three")
    return x


def test_local_executor_keeps_input_order() -> None:
    items = list(range(8))
    with LocalExecutor(2) as pool:
        assert pool.map(_slow_square, items) == [x * x for x in items]
    assert LocalExecutor(1).map(_slow_square, items) == [x * x for x in items]


def test_local_executor_names_the_failed_task() -> None:
    with LocalExecutor(2) as pool, pytest.raises(ExecutorError, match=r"_fail_on_three\(3\).*three"):
        pool.map(_fail_on_three, range(6))


def test_bad_executor_arguments() -> None:
    with pytest.raises(ValueError, match="workers"):
        LocalExecutor(0)
    with pytest.raises(ValueError, match="unknown kind"):
        make_executor("dask")
    with pytest.raises(ValueError, match="--address"):
        make_executor("local", 2, "auto")
    assert chunks(list(range(7)), 3) == [[0, 1, 2], [3, 4, 5], [6]]


# ----------------------------------------------------------------------------- whole-study determinism
def result_digests(study: Path) -> dict[str, str]:
    """sha256 of every result file: results, query logs, maps' points and the dataset manifest's file list."""
    files = [study / "results" / "results.json", study / "results" / "results.csv",
             study / "results" / "genuine_localization.json", study / "results" / "defense_tradeoff.json"]
    files += sorted(study.glob("queries/*/*/queries.jsonl"))
    files += sorted(study.glob("maps/*/*/points.npz")) + sorted(study.glob("maps/*/*/features.npz"))
    out = {str(p.relative_to(study)): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}
    manifest = json.loads((study / "dataset" / "manifest.json").read_text())
    out |= {f"dataset/{k}": v for k, v in manifest["files"].items()}
    return out


def _strip_frames(study: Path, every: int) -> int:
    """Delete the RGB of every ``every``-th frame of every sequence (the render stage must redo them)."""
    removed = 0
    for rgb in sorted(study.glob("dataset/*/*/images/*.png")):
        if int(rgb.stem) % every == 0:
            rgb.unlink()
            removed += 1
    return removed


def _rerun(ci_tiny_study: Path, tmp_path: Path, **kwargs) -> Path:
    from synthleak.config import load_config
    from synthleak.study import run_study

    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study, study)
    assert _strip_frames(study, 3) > 10
    run_study(load_config("ci-tiny"), study, force=["render", "maps", "queries", "attack"], progress=False,
              **kwargs)
    return study


def test_two_local_workers_give_identical_files(ci_tiny_study: Path, tmp_path: Path) -> None:
    """Frames re-rendered, maps rebuilt and every query re-sent by 2 processes: the same bytes as serially."""
    expected = result_digests(ci_tiny_study)
    assert len(expected) > 100
    assert result_digests(_rerun(ci_tiny_study, tmp_path, workers=2)) == expected


def test_ray_executor_gives_identical_files(ci_tiny_study: Path, tmp_path: Path) -> None:
    pytest.importorskip("ray")
    expected = result_digests(ci_tiny_study)
    assert result_digests(_rerun(ci_tiny_study, tmp_path, workers=2, executor="ray")) == expected
