"""A pool of localizer processes for the HTTP service: queries run in parallel, off the event loop.

pycolmap's SIFT holds the GIL while it extracts, so localizer threads would neither run in parallel nor
let the server's event loop answer ``/health`` meanwhile. Each of the ``workers`` processes loads the map
once and answers whole queries (decode, features, matching, PnP). An answer depends on the query only
(RANSAC is seeded per query, extraction is single threaded), so it is the same bytes whatever the number
of workers or which worker takes it. Defense decisions are logged here, in the parent, one writer.
"""

from __future__ import annotations

import asyncio
import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path

from synthleak.config import LocalizeConfig
from synthleak.core.types import Camera
from synthleak.executors import START_METHOD, kill_pool, limit_worker_threads
from synthleak.interrupt import guard_worker
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.images import MAX_QUERY_PIXELS
from synthleak.localize.localizer import LocalizationResult, Localizer, log_decision
from synthleak.localize.store import read_map_meta

_WORKER: dict = {}
"""This worker process's ``localizer`` and start-up ``barrier``."""
READY_TIMEOUT_S = 300.0


class WorkerCrashedError(RuntimeError):
    """A localizer process died (killed, out of memory) during a query; the pool was restarted."""


def _init_worker(map_dir: str, config: LocalizeConfig | None, defense: DefensePolicy | None,
                 weights_dir: str | None, threads: int, barrier: threading.Barrier, parent_pid: int,
                 parent_is_main_thread: bool) -> None:
    # Ctrl-C and SIGHUP stop the server, which stops the pool; the worker dies with the server if it is killed
    guard_worker(parent_pid, parent_is_main_thread)
    limit_worker_threads(threads)
    import synthleak.localize  # noqa: F401  (quiets COLMAP's per-extractor log lines)

    _WORKER["barrier"] = barrier
    _WORKER["localizer"] = Localizer.load(Path(map_dir), config, defense,
                                          Path(weights_dir) if weights_dir else None)


def _localize(data: bytes, camera: Camera | None, max_pixels: int) -> LocalizationResult:
    localizer = _WORKER["localizer"]
    localizer.max_query_pixels = max_pixels
    return localizer.localize(data, camera)


def _ready() -> None:
    """Wait until every worker runs one of these: each has then loaded its map."""
    _WORKER["barrier"].wait(READY_TIMEOUT_S)


class LocalizerPool:
    """``workers`` processes, each with a :class:`Localizer` of the map at ``map_dir``.

    ``await pool.localize(data, camera)`` answers like ``Localizer.localize`` (the same exceptions for bad
    images). Call :meth:`close` (or use ``with``) to stop the processes."""

    def __init__(
        self,
        map_dir: Path,
        workers: int = 1,
        config: LocalizeConfig | None = None,
        defense: DefensePolicy | None = None,
        weights_dir: Path | None = None,
        decision_log: Path | None = None,
        max_query_pixels: int = MAX_QUERY_PIXELS,
    ) -> None:
        if int(workers) < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.workers = int(workers)
        _, self.camera = read_map_meta(Path(map_dir))
        self.defense = defense or DefensePolicy()
        self.decision_log = decision_log
        self.max_query_pixels = int(max_query_pixels)
        # One BLAS thread per process: parallelism comes from the workers (2 threads made a query 35% more
        # CPU and slower on 2 busy cores), and every worker count computes with the same thread count.
        self._initargs = (str(map_dir), config, defense, str(weights_dir) if weights_dir else None, 1)
        self._restart_lock = asyncio.Lock()
        self._pool = self._start()

    def _start(self) -> ProcessPoolExecutor:
        """A started pool: every process has loaded its map (map errors surface here, not in a query)."""
        context = multiprocessing.get_context(START_METHOD)
        main = threading.current_thread() is threading.main_thread()  # a restart runs in a thread of asyncio's
        pool = ProcessPoolExecutor(self.workers, mp_context=context, initializer=_init_worker,
                                   initargs=(*self._initargs, context.Barrier(self.workers), os.getpid(), main))
        try:
            for future in [pool.submit(_ready) for _ in range(self.workers)]:
                future.result()
        except BrokenProcessPool as exc:  # a worker could not load the map: load it here for the error
            pool.shutdown(wait=False, cancel_futures=True)
            map_dir, config, defense, weights_dir, _ = self._initargs
            Localizer.load(Path(map_dir), config, defense, Path(weights_dir) if weights_dir else None)
            raise RuntimeError(f"{map_dir}: localizer processes failed to start") from exc
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
        return pool

    async def localize(self, data: bytes, camera: Camera | None = None) -> LocalizationResult:
        pool = self._pool
        try:
            result = await asyncio.get_running_loop().run_in_executor(
                pool, _localize, data, camera, self.max_query_pixels)
        except BrokenProcessPool as exc:
            async with self._restart_lock:
                if self._pool is pool:  # the first request to notice restarts it, off the event loop
                    pool.shutdown(wait=False, cancel_futures=True)
                    self._pool = await asyncio.to_thread(self._start)
            raise WorkerCrashedError("a localizer process died (killed, or out of memory); the pool was "
                                     "restarted") from exc
        if result.defense is not None and self.decision_log is not None:
            log_decision(self.decision_log, self.defense, result.defense, result.num_inliers)
        return result

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)

    def terminate(self) -> None:
        """Kill the processes without waiting for their running queries (the server is being stopped)."""
        kill_pool(self._pool)

    def __enter__(self) -> LocalizerPool:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:  # stopped by a signal (uvicorn re-raises the one it shut down on) or failing: do not wait
            self.terminate()
