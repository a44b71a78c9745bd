"""Where a study's independent tasks run: in this process, in a local process pool, or on a Ray cluster.

Every executor's :meth:`Executor.map` returns the results **in input order**, whatever order the tasks
finish in, so a study's outputs do not depend on the executor or the number of workers (each task is
seeded by what it computes, never by when or where it runs). Tasks must be picklable module-level
functions with picklable arguments; they read their inputs from, and may write their outputs to, the
study folder, which is therefore shared by every worker (a local disk for local workers, a shared file
system mounted at the same path on every node for a Ray cluster: see ``docs/scaling.md``).

An executor used as a ``with`` block that is left by an exception (a failed task, Ctrl-C, SIGTERM: see
:mod:`synthleak.interrupt`) ends its workers at once instead of waiting for their running tasks; workers also
end by themselves when their driver dies (:func:`worker_init`).
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from typing import Any, TypeVar

from synthleak.errors import MissingDependencyError, SynthleakError
from synthleak.interrupt import guard_worker, reassert_stop_handlers
from synthleak.progress import progress_display

T = TypeVar("T")
R = TypeVar("R")

EXECUTORS = ("local", "ray")
START_METHOD = "spawn"
"""Process start method of local pools: ``spawn`` (fork after mitsuba/EGL/pycolmap threads started is
unsafe; spawn costs ~1-2 s of imports per worker, once per pool)."""


THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "LP_NUM_THREADS")
"""Thread-count variables of the libraries a worker loads (BLAS, OpenMP, Mesa's llvmpipe)."""
WORKER_THREADS_ENV = "SYNTHLEAK_WORKER_THREADS"


def limit_worker_threads(threads: int) -> None:
    """Cap the native thread pools of this (worker) process at ``threads``: the environment variables for
    libraries loaded later (llvmpipe reads LP_NUM_THREADS when the GL context is made) and threadpoolctl
    for BLAS/OpenMP already loaded. With N workers on C cores each gets C // N, so N workers that each
    spread a matrix product or a raster over all cores do not fight over them. Results do not change."""
    threads = max(1, int(threads))
    for name in (*THREAD_ENV, WORKER_THREADS_ENV):
        os.environ[name] = str(threads)
    from threadpoolctl import threadpool_limits

    threadpool_limits(threads)


def worker_init(threads: int, parent_pid: int, parent_is_main_thread: bool = True) -> None:
    """The initializer of a local pool's workers: stop with the driver (:func:`~synthleak.interrupt.guard_worker`:
    the driver ends them on a signal, and they die with it if it is killed outright), then
    :func:`limit_worker_threads`."""
    guard_worker(parent_pid, parent_is_main_thread)
    limit_worker_threads(threads)


def worker_thread_cap() -> int | None:
    """The cap :func:`limit_worker_threads` set in this process (None outside workers): for libraries that
    take their thread count from a call rather than the environment (drjit/mitsuba)."""
    value = os.environ.get(WORKER_THREADS_ENV)
    return max(1, int(value)) if value and value.isdigit() else None


def usable_cpus() -> int:
    """Cores this process may run on: its CPU affinity where the OS has one (a container's or ``taskset``'s
    limit), else ``os.cpu_count()``; at least 1. The default number of ``synthleak study`` workers."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # macOS, Windows: no affinity call
        return max(1, os.cpu_count() or 1)


def threads_per_worker(workers: int) -> int:
    """Cores per worker: ``usable_cpus() // workers`` (at least 1)."""
    return max(1, usable_cpus() // max(1, int(workers)))


class ExecutorError(SynthleakError, RuntimeError):
    """A task that failed in a worker; the message names the task."""


class Executor:
    """Runs ``fn(item)`` for every item; results in input order."""

    workers: int = 1

    def map(self, fn: Callable[[T], R], items: Iterable[T], description: str = "tasks",
            progress: bool = False) -> list[R]:
        raise NotImplementedError

    def close(self) -> None:
        """Release workers (a no-op where there are none)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: Any) -> None:
        if exc_type is None:
            self.close()
        else:  # the caller is failing or being stopped: nobody will use the running tasks' results
            self.terminate()

    def terminate(self) -> None:
        """End the workers now, without waiting for their running tasks (defaults to :meth:`close`)."""
        self.close()


def _describe(fn: Callable, item: Any) -> str:
    text = repr(item)
    return f"{getattr(fn, '__name__', fn)}({text[:200]}{'...' if len(text) > 200 else ''})"


def kill_pool(pool: ProcessPoolExecutor, timeout: float = 5.0) -> None:
    """Kill a process pool's workers (SIGKILL) without waiting for their tasks, and reap them.

    The tasks not started are cancelled first, and the pool's manager thread is given a moment to drop them:
    Python 3.11's fails with InvalidStateError (a thread traceback on stderr) on a cancelled future it still
    holds when it finds its workers dead."""
    manager = getattr(pool, "_executor_manager_thread", None)  # shutdown() forgets both
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + 2.0
    while (manager is not None and manager.is_alive() and time.monotonic() < deadline
           and any(item.future.cancelled() for item in list(getattr(manager, "pending_work_items", {}).values()))):
        time.sleep(0.01)
    processes = [p for p in processes if p.is_alive()]
    for process in processes:
        process.kill()
    for process in processes:  # reap them: gone, not zombies, when this returns
        process.join(timeout)


class LocalExecutor(Executor):
    """``workers`` processes on this machine (``workers <= 1``: serially in this process, no pool).

    The pool is started on first use and kept for the executor's life (``close()`` or ``with``; a ``with``
    block left by an exception kills the workers: :meth:`terminate`)."""

    def __init__(self, workers: int = 1, start_method: str = START_METHOD) -> None:
        if int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = int(workers)
        self.start_method = start_method
        self._pool: ProcessPoolExecutor | None = None

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            ctx = multiprocessing.get_context(self.start_method)
            # processes are started by the thread that submits (the one calling map): PR_SET_PDEATHSIG would
            # tie them to it, so only when it is the main thread (worker_init's watchdog thread in any case)
            main = threading.current_thread() is threading.main_thread()
            self._pool = ProcessPoolExecutor(self.workers, mp_context=ctx, initializer=worker_init,
                                             initargs=(threads_per_worker(self.workers), os.getpid(), main))
        return self._pool

    def map(self, fn: Callable[[T], R], items: Iterable[T], description: str = "tasks",
            progress: bool = False) -> list[R]:
        items = list(items)
        results: list[Any] = [None] * len(items)
        reassert_stop_handlers()  # in case something since replaced them (a no-op outside the CLI)
        with progress_display(progress and bool(items)) as bar:
            task = bar.add_task(description, total=len(items))
            if self.workers <= 1 or len(items) <= 1:
                for i, item in enumerate(items):
                    results[i] = fn(item)
                    bar.advance(task)
                return results
            futures: dict[Any, int] = {}
            pending: set[Any] = set()
            try:
                pool = self._get_pool()
                for i, item in enumerate(items):
                    future = pool.submit(fn, item)
                    futures[future] = i
                    pending.add(future)
                while pending:
                    done, pending = wait(pending, return_when=FIRST_COMPLETED)
                    for future in done:
                        i = futures[future]
                        try:
                            results[i] = future.result()
                        except Exception as exc:
                            raise ExecutorError(f"task {_describe(fn, items[i])} failed: "
                                                f"{type(exc).__name__}: {exc}") from exc
                        bar.advance(task)
            except BaseException as exc:
                if not isinstance(exc, Exception):  # Ctrl-C, SIGTERM (Stopped): stop the workers now
                    self.terminate()
                else:  # a failed task: what has not started will not, the pool stays usable
                    for future in pending:
                        future.cancel()
                raise
        return results

    def terminate(self) -> None:
        """Kill the workers without waiting for their running tasks (an interrupted study resumes later).

        SIGKILL, not SIGTERM: nothing a task imported can catch it, and files are written atomically (a
        killed writer leaves a ``.tmp-*`` file at worst, never a partial result under its real name)."""
        pool, self._pool = self._pool, None
        if pool is not None:
            kill_pool(pool)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None


class RayExecutor(Executor):
    """Tasks as Ray remote functions (``pip install -e .[ray]``).

    ``address``: ``"auto"`` (or ``ray://...`` / ``host:port``) joins a running cluster; None starts a
    local Ray on this machine with ``workers`` CPUs (the default: all). The study folder must be the
    same path on every node."""

    def __init__(self, address: str | None = None, workers: int | None = None, num_cpus_per_task: float = 1) -> None:
        try:
            import ray
        except ImportError as exc:
            raise MissingDependencyError(
                "the ray executor needs Ray: pip install -e '.[ray]' (or pip install 'ray[default]')"
            ) from exc
        self._ray = ray
        self._started = False
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": True}
            if address:
                kwargs["address"] = address
            else:
                kwargs["num_cpus"] = workers or usable_cpus()
            # workers import synthleak from the driver's environment; pass the driver's egl choice along
            env = {k: os.environ[k] for k in ("PYOPENGL_PLATFORM",) if k in os.environ}
            # one task per CPU: cap each task's native thread pools accordingly (unless the user set them)
            threads = str(max(1, int(num_cpus_per_task)))
            env |= {k: threads for k in (*THREAD_ENV, WORKER_THREADS_ENV) if k not in os.environ}
            if env:
                kwargs["runtime_env"] = {"env_vars": env}
            ray.init(**kwargs)
            reassert_stop_handlers()  # ray.init replaced our SIGTERM handler with sys.exit(15)
            self._started = True
        self.workers = int(ray.cluster_resources().get("CPU", 1))
        self.num_cpus_per_task = num_cpus_per_task
        self._remote: dict[Callable, Any] = {}

    def map(self, fn: Callable[[T], R], items: Iterable[T], description: str = "tasks",
            progress: bool = False) -> list[R]:
        ray = self._ray
        items = list(items)
        reassert_stop_handlers()
        remote = self._remote.get(fn)
        if remote is None:
            remote = self._remote[fn] = ray.remote(num_cpus=self.num_cpus_per_task, max_retries=1)(fn)
        refs = [remote.remote(item) for item in items]
        index = {ref: i for i, ref in enumerate(refs)}
        results: list[Any] = [None] * len(items)
        pending = list(refs)
        with progress_display(progress and bool(items)) as bar:
            task = bar.add_task(description, total=len(items))
            try:
                while pending:
                    done, pending = ray.wait(pending, num_returns=1)
                    for ref in done:
                        i = index[ref]
                        try:
                            results[i] = ray.get(ref)
                        except Exception as exc:
                            self._cancel(pending, force=False)
                            raise ExecutorError(f"task {_describe(fn, items[i])} failed on Ray: "
                                                f"{type(exc).__name__}: {exc}") from exc
                        bar.advance(task)
            except BaseException as exc:
                if not isinstance(exc, Exception):  # Ctrl-C, SIGTERM: stop the running tasks too (a cluster
                    self._cancel(pending, force=True)  # joined with --address outlives this driver)
                raise
        return results

    def _cancel(self, refs: Iterable[Any], force: bool) -> None:
        for ref in refs:  # an error: finished meanwhile, or Ray going down, nothing left to stop
            with contextlib.suppress(Exception):
                self._ray.cancel(ref, force=force)

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()
            self._started = False


def make_executor(kind: str = "local", workers: int = 1, address: str | None = None) -> Executor:
    """``local`` (``workers`` processes) or ``ray`` (``address``: None starts a local Ray)."""
    if kind == "local":
        if address:
            raise ValueError("--address only applies to --executor ray")
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(address, workers if workers > 1 else None)
    raise ValueError(f"executor: unknown kind {kind!r} (known: {', '.join(EXECUTORS)})")


def chunks(items: Sequence[T], size: int) -> list[list[T]]:
    """Consecutive runs of at most ``size`` items (the task granularity of frames and queries)."""
    size = max(1, int(size))
    return [list(items[i:i + size]) for i in range(0, len(items), size)]
