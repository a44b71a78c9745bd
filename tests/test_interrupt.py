"""Stopping a study stops its work: SIGTERM, SIGINT and SIGHUP end the workers, exit 128 + signum with one line,
and leave a folder a rerun resumes (to the same bytes); workers die with a driver killed outright (SIGKILL), and
a second study on the same folder is refused at once, naming the running one's PID."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from synthleak.executors import LocalExecutor

TESTS = str(Path(__file__).parent)
CLI = [sys.executable, "-m", "synthleak.cli"]


# ------------------------------------------------------------------------------------------------ processes
def _stat(pid: int) -> list[str] | None:
    """Fields of /proc/<pid>/stat after the command name (state, ppid, ...); None once the process is gone."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None


def _alive(pid: int) -> bool:
    fields = _stat(pid)
    return fields is not None and fields[0] != "Z"


def _descendants(root: int) -> set[int]:
    """Every living process below ``root`` (read from /proc/*/stat: psutil is not a dependency)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and (fields := _stat(int(entry.name))) and fields[0] != "Z":
            parents[int(entry.name)] = int(fields[1])
    found, todo = set(), [root]
    while todo:
        parent = todo.pop()
        children = {pid for pid, ppid in parents.items() if ppid == parent}
        todo += children - found
        found |= children
    return found


def _workers(root: int) -> set[int]:
    """The pool workers among ``root``'s children (spawned: ``-c from multiprocessing.spawn import spawn_main``)."""
    out = set()
    for pid in _descendants(root):
        try:
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                out.add(pid)
        except OSError:
            pass
    return out


def _wait_gone(pids: set[int], timeout: float) -> set[int]:
    """Those of ``pids`` still alive after up to ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while (alive := {pid for pid in pids if _alive(pid)}) and time.monotonic() < deadline:
        time.sleep(0.1)
    return alive


def _wait_for(condition, timeout: float, what: str, process: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if process is not None and process.poll() is not None:
            raise AssertionError(f"{what}: the process ended first ({process.returncode}): "
                                 f"{process.communicate()[1]}")
        if time.monotonic() > deadline:
            raise AssertionError(f"{what}: not within {timeout} s")
        time.sleep(0.2)


def _stop_line(signum: int, out: Path) -> str:
    name = signal.Signals(signum).name
    return f"synthleak study: stopped by {name}; finished work is kept in {out}, rerun the same command to resume"


# ------------------------------------------------------------------------------------- tasks (run in workers)
def _record_pid_and_sleep(task: tuple[str, int]) -> None:
    folder, i = task
    (Path(folder) / f"{os.getpid()}.pid").write_text(str(i))
    time.sleep(60)


def _pid_after_nap(_: int) -> int:
    time.sleep(0.2)
    return os.getpid()


_FAKE_STUDY = """
import sys, threading
from pathlib import Path
sys.path.insert(0, {tests!r})
from synthleak import cli
from synthleak.executors import LocalExecutor
from test_interrupt import _record_pid_and_sleep

def late_import(out):  # as a stage imports it, while the pool runs: it replaces the C SIGTERM handler
    import pycolmap  # noqa: F401
    (Path(out) / "imported").touch()

def study(args):  # the CLI's study command, with one map of sleeping tasks for its stages
    with LocalExecutor(2) as pool:
        threading.Thread(target=late_import, args=(args.out,)).start()
        pool.map(_record_pid_and_sleep, [(args.out, i) for i in range(4)])

cli._cmd_study = study
raise SystemExit(cli.main(["study", "ci-tiny", "--out", {out!r}, "--quiet"]))
"""


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGHUP], ids=lambda s: s.name)
def test_a_stop_signal_ends_the_workers_with_one_line(tmp_path: Path, signum: int) -> None:
    """`kill PID` (or Ctrl-C, or a hangup) of the driver, with pycolmap imported as a study's stages import it:
    exit 128 + signum, one line on stderr, and no worker left (before the fix, glog's handler killed the driver
    with a C stack trace and the workers ran on)."""
    out = tmp_path / "out"
    out.mkdir()
    driver = subprocess.Popen([sys.executable, "-c", _FAKE_STUDY.format(tests=TESTS, out=str(out))],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(lambda: len(list(out.glob("*.pid"))) == 2 and (out / "imported").exists(), 120,
                  "two tasks running, pycolmap imported", driver)
        workers = {int(p.stem) for p in out.glob("*.pid")}
        assert workers <= _workers(driver.pid)
        children = _descendants(driver.pid)
        driver.send_signal(signum)
        _, stderr = driver.communicate(timeout=60)
        assert driver.returncode == 128 + signum, stderr
        assert stderr.splitlines() == [_stop_line(signum, out)], stderr
        assert not _wait_gone(children, 5), "processes outlived the driver"
    finally:
        driver.kill()


_KILLED_DRIVER = """
import sys, threading
sys.path.insert(0, {tests!r})
from synthleak.executors import LocalExecutor
from test_interrupt import _record_pid_and_sleep

def run():
    with LocalExecutor(2) as pool:
        pool.map(_record_pid_and_sleep, [({out!r}, i) for i in range(4)])

if {in_thread!r}:
    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
else:
    run()
"""


@pytest.mark.parametrize("in_thread", [False, True], ids=["main-thread", "other-thread"])
def test_workers_die_with_a_driver_killed_outright(tmp_path: Path, in_thread: bool) -> None:
    """SIGKILL runs no handler: PR_SET_PDEATHSIG (pool started from the main thread) or the workers' watchdog
    thread (started from another thread, which PR_SET_PDEATHSIG would tie them to) ends them."""
    script = _KILLED_DRIVER.format(tests=TESTS, out=str(tmp_path), in_thread=in_thread)
    driver = subprocess.Popen([sys.executable, "-c", script])
    try:
        _wait_for(lambda: len(list(tmp_path.glob("*.pid"))) == 2, 120, "two tasks running", driver)
        workers = {int(p.stem) for p in tmp_path.glob("*.pid")}
        assert all(_alive(pid) for pid in workers)
        driver.kill()
        driver.wait(timeout=30)
        assert not _wait_gone(workers, 5), "workers outlived their killed driver"
    finally:
        driver.kill()


def test_a_pool_started_by_a_thread_that_ends_keeps_its_workers() -> None:
    """PR_SET_PDEATHSIG fires when the *thread* that started a worker ends: not set then (the watchdog is)."""
    with LocalExecutor(2) as pool:
        first: list[int] = []
        thread = threading.Thread(target=lambda: first.extend(pool.map(_pid_after_nap, range(4))))
        thread.start()
        thread.join()
        time.sleep(1.5)
        assert first and all(_alive(pid) for pid in set(first))
        assert set(pool.map(_pid_after_nap, range(4))) <= set(pool._pool._processes)
        assert set(first) <= set(pool._pool._processes)


# ----------------------------------------------------------------------------------------------------- lock
_HOLD_LOCK = """
import sys, time
from pathlib import Path
from synthleak.study.lock import study_lock
with study_lock(Path({folder!r})):
    print("held", flush=True)
    time.sleep(120)
"""


def test_a_second_study_on_the_same_folder_is_refused_at_once(tmp_path: Path) -> None:
    """While a process holds the folder, `synthleak study` on it exits 2 at once with one line naming the folder
    and that PID, and the Python API raises StudyLockedError (this process's own second run_study too); the
    kernel drops the lock of a killed holder, so the next run goes ahead."""
    from synthleak.config import load_config
    from synthleak.study import run_study
    from synthleak.study.lock import LOCK_NAME, StudyLockedError, study_lock

    folder = tmp_path / "study"
    folder.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", _HOLD_LOCK.format(folder=str(folder))],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        start = time.monotonic()
        result = subprocess.run([*CLI, "study", "ci-tiny", "--out", str(folder), "--quiet"], capture_output=True,
                                text=True, timeout=120)
        assert result.returncode == 2, result
        assert result.stderr.splitlines() == [
            f"synthleak study: error: {folder}: another synthleak study is running on this folder "
            f"(PID {holder.pid}); wait for it to end or stop it (kill {holder.pid}), then rerun"], result.stderr
        assert time.monotonic() - start < 30  # refused before any work (a CLI start is a few seconds here)
        assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]
        with pytest.raises(StudyLockedError, match=f"PID {holder.pid}"):
            run_study(load_config("ci-tiny"), folder, progress=False)
    finally:
        holder.kill()
        holder.wait()
    with study_lock(folder):  # released with the killed holder; held here, this process's run_study is refused
        assert (folder / LOCK_NAME).read_text().split()[0] == str(os.getpid())
        with pytest.raises(StudyLockedError, match=rf"{folder}: .*\(PID {os.getpid()}\)"):
            run_study(load_config("ci-tiny"), folder, progress=False)
    assert sorted(p.name for p in folder.iterdir()) == [LOCK_NAME]


# ------------------------------------------------------------------------------------------ a whole study
def _digests(study: Path) -> dict[str, str]:
    """sha256 of the result files: results, query logs, maps and the dataset manifest's file list."""
    files = sorted(study.glob("results/*.json")) + sorted(study.glob("results/*.csv"))
    files += sorted(study.glob("queries/*/*/queries.jsonl")) + sorted(study.glob("maps/*/*/*.npz"))
    out = {str(p.relative_to(study)): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}
    manifest = json.loads((study / "dataset" / "manifest.json").read_text())
    return out | {f"dataset/{k}": v for k, v in manifest["files"].items()}


def _complete_frames(study: Path) -> dict[Path, int]:
    """Every file of every whole frame rendered so far, with its mtime (ns)."""
    from synthleak.core.dataset import frame_complete, frame_paths

    out = {}
    for seq in sorted({p.parent.parent for p in study.glob("dataset/*/*/images/*.png")}):
        for rgb in sorted(seq.glob("images/*.png")):
            if frame_complete(seq, rgb.stem):
                out |= {p: p.stat().st_mtime_ns for p in frame_paths(seq, rgb.stem).values()}
    return out


@pytest.mark.slow
def test_sigterm_mid_study_then_a_rerun_resumes_to_the_same_bytes(ci_tiny_study: Path, tmp_path: Path) -> None:
    """`synthleak study ci-tiny --workers 2` stopped by SIGTERM while rendering: a second study on the folder was
    refused meanwhile, the driver exits 143 with one line, no worker outlives it, and the rerun keeps the frames
    already rendered and ends with the same result files as an uninterrupted study."""
    study = tmp_path / "study"
    command = [*CLI, "study", "ci-tiny", "--out", str(study), "--workers", "2", "--quiet"]
    driver = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        _wait_for(lambda: len(_workers(driver.pid)) == 2 and len(list(study.glob("dataset/*/*/images/*.png"))) >= 10,
                  300, "two workers and ten frames", driver)
        second = subprocess.run(command, capture_output=True, text=True, timeout=120)
        assert second.returncode == 2 and len(second.stderr.splitlines()) == 1, second
        assert f"{study}: another synthleak study" in second.stderr and f"(PID {driver.pid})" in second.stderr

        children = _descendants(driver.pid)
        driver.send_signal(signal.SIGTERM)
        _, stderr = driver.communicate(timeout=60)
        assert driver.returncode == 128 + signal.SIGTERM, stderr
        assert stderr.splitlines() == [_stop_line(signal.SIGTERM, study)], stderr
        assert not _wait_gone(children, 5), "processes outlived the driver"
    finally:
        driver.kill()
    assert not (study / "report.md").exists()
    frames = _complete_frames(study)
    assert frames
    (killed,) = json.loads((study / "run.json").read_text())["runs"]  # recorded although it never finished
    assert killed["started_empty"] is True and killed["finished"] is False and killed["stage_s"]["render"] > 1

    start = time.monotonic()
    rerun = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert rerun.returncode == 0, rerun.stderr
    print(f"rerun after SIGTERM: {time.monotonic() - start:.1f} s, {len(frames)} frame files kept")
    assert {p: p.stat().st_mtime_ns for p in frames} == frames  # finished frames are not rendered again
    assert _digests(study) == _digests(ci_tiny_study)
    runs = json.loads((study / "run.json").read_text())["runs"]
    assert [(r["started_empty"], r["finished"]) for r in runs] == [(True, False), (False, True)]
    from synthleak.evaluate.results_page import render_page, results_summary

    wall = render_page(results_summary(study)).split("| wall time |")[1].splitlines()[0]
    assert "from an empty folder over 2 invocations (resumed); 1 of them interrupted" in wall, wall
