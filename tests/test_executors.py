"""Executors: results in input order, clear errors, and byte-identical study outputs on `ci-tiny` whatever the
executor (serial, a 2-process pool, a local Ray, a simulated two-node Ray cluster)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from synthleak.executors import (
    ExecutorError,
    LocalExecutor,
    chunks,
    make_executor,
    threads_per_worker,
    worker_thread_cap,
)


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


def _thread_settings(_: int) -> tuple[str | None, int, int | None]:
    import numpy  # noqa: F401  (loads BLAS in the worker)
    from threadpoolctl import threadpool_info

    blas = [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]
    return os.environ.get("LP_NUM_THREADS"), max(blas) if blas else 1, worker_thread_cap()


def test_pool_workers_share_the_cores_instead_of_each_taking_all() -> None:
    with LocalExecutor(2) as pool:
        settings = pool.map(_thread_settings, range(4))
    expected = threads_per_worker(2)
    assert expected == max(1, (os.cpu_count() or 1) // 2)
    assert all(lp == str(expected) and blas <= expected and cap == expected for lp, blas, cap in settings)
    assert worker_thread_cap() is None  # the driver keeps every core (mitsuba's pool reads this cap)


_SIGTERM_SCRIPT = """
import os, sys, time
from synthleak.cli import _exit_on_sigterm
from synthleak.executors import LocalExecutor
import signal
signal.signal(signal.SIGTERM, _exit_on_sigterm)
sys.path.insert(0, {tests!r})
from test_executors import _record_pid_and_sleep
with LocalExecutor(2) as pool:
    pool.map(_record_pid_and_sleep, [({folder!r}, i) for i in range(4)])
"""


def _record_pid_and_sleep(task: tuple[str, int]) -> None:
    folder, i = task
    (Path(folder) / f"{os.getpid()}.pid").write_text(str(i))
    time.sleep(60)


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_sigterm_stops_the_worker_pool(tmp_path: Path) -> None:
    """SIGTERM to a driver (e.g. a study) stops its pool's workers instead of leaving them running."""
    script = _SIGTERM_SCRIPT.format(tests=str(Path(__file__).parent), folder=str(tmp_path))
    driver = subprocess.Popen([sys.executable, "-c", script])
    deadline = time.time() + 60
    while len(list(tmp_path.glob("*.pid"))) < 2 and time.time() < deadline:
        time.sleep(0.1)
    workers = [int(p.stem) for p in tmp_path.glob("*.pid")]
    assert len(workers) == 2 and all(_alive(pid) for pid in workers)
    driver.send_signal(signal.SIGTERM)
    assert driver.wait(timeout=30) == 128 + signal.SIGTERM
    deadline = time.time() + 10
    while any(_alive(pid) for pid in workers) and time.time() < deadline:
        time.sleep(0.1)
    assert not any(_alive(pid) for pid in workers)


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


FORCED = ("render", "maps", "queries", "attack")
"""The stages the reruns redo (frames, maps, queries: every kind of worker task)."""


def _stripped_copy(ci_tiny_study: Path, tmp_path: Path) -> Path:
    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study, study)
    assert _strip_frames(study, 3) > 10
    return study


def _rerun(ci_tiny_study: Path, tmp_path: Path, **kwargs) -> Path:
    from synthleak.config import load_config
    from synthleak.study import run_study

    study = _stripped_copy(ci_tiny_study, tmp_path)
    run_study(load_config("ci-tiny"), study, force=list(FORCED), progress=False, **kwargs)
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


def test_ray_two_node_cluster_gives_identical_files(ci_tiny_study: Path, tmp_path: Path) -> None:
    """`synthleak study ci-tiny --executor ray --address` on a simulated two-node Ray cluster, one CPU per node: the
    driver's node runs one task at a time, so a map of two or more tasks sends some to the other node (checked),
    whose workers share nothing with the driver but the study folder. Same bytes as the serial run: no task relies on
    state of the driver (globals, registrations, caches, its environment beyond what the executor passes on)."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    from synthleak import cli

    def node_of_task(_: int) -> str:  # defined here: Ray ships it by value, the test module need not import there
        import ray

        time.sleep(0.5)
        return ray.get_runtime_context().get_node_id()

    expected = result_digests(ci_tiny_study)
    study = _stripped_copy(ci_tiny_study, tmp_path)
    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        with make_executor("ray", 2, cluster.address) as executor:  # the cluster spreads a map over both nodes
            assert executor.workers == 2 and len(set(executor.map(node_of_task, range(4)))) == 2
        args = ["study", "ci-tiny", "--out", str(study), "--quiet", "--executor", "ray", "--address", cluster.address]
        assert cli.main(args + [f"--force={stage}" for stage in FORCED]) == 0
    finally:
        cluster.shutdown()
    assert result_digests(study) == expected


def test_study_workers_default_to_the_usable_cores(monkeypatch, tmp_path) -> None:
    """`synthleak study` without --workers uses one worker per core this process may run on (its CPU affinity),
    not one: the README's study runs on every core. --workers N still wins."""
    import os

    import synthleak.study
    from synthleak import cli
    from synthleak.executors import usable_cpus

    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 2, 5}, raising=False)
    assert usable_cpus() == 3
    seen: list[int] = []

    def run_study(config, out, **kwargs):  # the plumbing only: the study itself is tested in test_study.py
        seen.append(kwargs["workers"])
        return out / "report.md"

    monkeypatch.setattr(synthleak.study, "run_study", run_study)
    assert cli.main(["study", "ci-tiny", "--out", str(tmp_path), "--quiet"]) == 0
    assert cli.main(["study", "ci-tiny", "--out", str(tmp_path), "--quiet", "--workers", "1"]) == 0
    assert seen == [3, 1]
