"""Stopping on a signal: the driver unwinds and ends its workers; a worker never outlives its driver.

The commands (:func:`synthleak.cli.main`) turn SIGTERM (a job scheduler, ``timeout``, ``kill PID``), SIGINT
(Ctrl-C) and SIGHUP (a closed terminal or ssh session) into :class:`Stopped`, raised in the main thread: the
executors' ``with`` blocks then kill their workers (finished files stay, they are written atomically, and a
rerun resumes by content key) and the command exits with ``128 + signum`` after one line on stderr.

Two things defeat a Python signal handler, both dealt with here:

* ``import pycolmap`` installs glog's failure signal handler for SIGTERM (and SIGSEGV, SIGABRT, ...) in C,
  replacing Python's without Python noticing (``signal.getsignal`` still names the Python handler). A SIGTERM
  then printed a C stack trace and killed the driver on the spot, its pool workers left running. pycolmap is
  therefore imported *before* the handlers are installed (:func:`preload_native_handlers`), and
  :func:`reassert_stop_handlers` reinstalls them after code known to replace them (``ray.init`` sets its own).
* A driver killed outright (SIGKILL, the out-of-memory killer, a crash) runs no handler. Each worker therefore
  watches its parent (:func:`guard_worker`): on Linux the kernel sends it SIGKILL when the parent dies
  (``prctl(PR_SET_PDEATHSIG)``), elsewhere (and where the pool was started from a thread other than the main
  one, which PR_SET_PDEATHSIG would tie the worker's life to) a thread polls ``os.getppid()``.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from typing import Any

STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGTERM", "SIGINT", "SIGHUP") if hasattr(signal, name))
"""The signals that stop a command (SIGHUP only where the platform has it)."""

NATIVE_HANDLER_MODULES = ("pycolmap",)
"""Extension modules whose import replaces Python's SIGTERM handler with a C one (pycolmap: glog's
``InstallFailureSignalHandler``)."""

PARENT_POLL_S = 1.0
"""How often a worker's watchdog thread checks that its parent is alive."""


class Stopped(SystemExit):
    """A stop signal arrived: unwind (ending workers) and exit with ``128 + signum``."""

    def __init__(self, signum: int) -> None:
        super().__init__(128 + int(signum))
        self.signum = int(signum)

    @property
    def signal_name(self) -> str:
        return signal_name(self.signum)


def signal_name(signum: int) -> str:
    """``SIGTERM`` for 15, and so on."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


_STATE: dict[str, Any] = {"installed": False, "received": None}


def _on_stop_signal(signum: int, frame: object) -> None:
    if _STATE["received"] is not None:  # already stopping: let the cleanup of the first one finish
        return
    _STATE["received"] = signum
    raise Stopped(signum)


def received_stop_signal() -> int | None:
    """The stop signal this process received since :func:`stop_on_signals` began (None: none)."""
    return _STATE["received"]


def preload_native_handlers() -> None:
    """Import the extension modules that install C signal handlers at import (:data:`NATIVE_HANDLER_MODULES`),
    so that handlers installed afterwards are the ones that stay. Those not installed are skipped."""
    for name in NATIVE_HANDLER_MODULES:
        if name in sys.modules:
            continue
        with contextlib.suppress(ImportError):
            __import__(name)


def _in_main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def reassert_stop_handlers() -> None:
    """Reinstall the stop handlers (inside :func:`stop_on_signals`, from the main thread; else a no-op): after
    code that replaced them, e.g. ``ray.init`` (its SIGTERM handler exits with status 15 and no message)."""
    if _STATE["installed"] and _in_main_thread():
        for signum in STOP_SIGNALS:
            signal.signal(signum, _on_stop_signal)


@contextlib.contextmanager
def stop_on_signals(preload: bool = True) -> Iterator[None]:
    """While inside, SIGTERM, SIGINT and SIGHUP raise :class:`Stopped` in the main thread (a second signal
    while stopping is ignored, so the cleanup of the first is not cut short: SIGKILL still ends everything,
    workers included). ``preload``: first import the modules that would replace the handlers later
    (:func:`preload_native_handlers`). The previous handlers are restored on exit. A no-op outside the main
    thread (Python runs signal handlers there only)."""
    if not _in_main_thread():
        yield
        return
    if preload:
        preload_native_handlers()
    previous = {signum: signal.signal(signum, _on_stop_signal) for signum in STOP_SIGNALS}
    _STATE.update(installed=True, received=None)
    try:
        yield
    finally:
        _STATE["installed"] = False
        for signum, handler in previous.items():
            if handler is not None:  # None: a handler set from C, which Python cannot put back
                signal.signal(signum, handler)


# ------------------------------------------------------------------------------------------------- workers
PR_SET_PDEATHSIG = 1


def _kill_with_parent() -> bool:
    """Linux: ask the kernel to SIGKILL this process when its parent (thread) ends; False elsewhere."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _watch_parent(parent_pid: int, interval: float) -> None:
    while True:
        time.sleep(interval)
        if os.getppid() != parent_pid:  # reparented: the driver is gone, nobody will read our results
            os._exit(1)


def guard_worker(parent_pid: int, parent_is_main_thread: bool = True) -> None:
    """Set a pool worker up to stop with its driver (call it first in the pool's initializer).

    * SIGINT and SIGHUP are ignored: Ctrl-C and a hangup reach the whole process group, and the driver,
      which receives them too, ends its workers itself (a worker's KeyboardInterrupt would otherwise come
      back to the driver as the task's error).
    * SIGTERM kills quietly (pycolmap imported first, so that glog's handler, which prints a C stack trace,
      is replaced): ``timeout`` and schedulers signal the whole group.
    * The worker dies with ``parent_pid``: PR_SET_PDEATHSIG on Linux when the pool was started from the
      driver's main thread (the kernel ties it to the thread that started the worker), and a thread
      polling ``os.getppid()`` every :data:`PARENT_POLL_S` seconds in any case."""
    for name in ("SIGINT", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    preload_native_handlers()
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if parent_is_main_thread:
        _kill_with_parent()
    if os.getppid() != parent_pid:  # the driver died before this worker got here
        os._exit(1)
    threading.Thread(target=_watch_parent, args=(parent_pid, PARENT_POLL_S), name="synthleak-parent-watch",
                     daemon=True).start()
