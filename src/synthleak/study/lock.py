"""One study at a time per folder: ``run_study`` holds an exclusive ``flock`` on ``<study>/.study.lock``.

Two studies writing one folder would redo each other's work and delete each other's temporary files (a
resumed render clears stray ``.tmp-*`` files). The lock file holds the holder's PID and host, for the
second run's error message. The kernel releases the lock when its holder exits, however it exits (SIGKILL
included), so a stale lock file never blocks a rerun; the file itself stays (removing it would let a third
run lock a new file while a second still holds the old one). A no-op where ``fcntl`` is missing (Windows) or
the file system has no ``flock``.
"""

from __future__ import annotations

import contextlib
import errno
import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

from synthleak.atomic_io import file_mode
from synthleak.errors import SynthleakError

try:
    import fcntl
except ImportError:  # Windows
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = ".study.lock"
"""The lock file's name inside the study folder."""


class StudyLockedError(SynthleakError, RuntimeError):
    """Another process runs a study on this folder; the message names the folder and that process's PID."""


def _holder(handle) -> str:
    """``PID 1234`` (``PID 1234 on host``, another host's) from the lock file; ``PID unknown`` if not yet written."""
    handle.seek(0)
    fields = handle.read().split()
    if not fields or not fields[0].isdigit():
        return "PID unknown"
    host = fields[1] if len(fields) > 1 else ""
    return f"PID {fields[0]}" + (f" on {host}" if host and host != socket.gethostname() else "")


@contextlib.contextmanager
def study_lock(root: Path) -> Iterator[Path]:
    """Hold the study folder ``root`` (which must exist) for this process; a :class:`StudyLockedError` at once
    if another holds it (another process, or another ``run_study`` of this one)."""
    path = Path(root) / LOCK_NAME
    if fcntl is None:
        yield path
        return
    fd = os.open(path, os.O_RDWR | os.O_CREAT, file_mode())
    with os.fdopen(fd, "r+") as handle:
        if not _lock(handle, root):  # a file system without flock (some FUSE mounts): unguarded, as before
            yield path
            return
        try:
            handle.seek(0)
            handle.truncate()
            handle.write(f"{os.getpid()} {socket.gethostname()}\n")
            handle.flush()
            yield path
        finally:
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def _lock(handle, root: Path) -> bool:
    """Lock ``handle`` (True), or find the file system has no flock (False); StudyLockedError if held."""
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        pass
    except OSError as exc:
        if exc.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP, errno.EINVAL, errno.ENOSYS):
            return False
        raise
    holder = _holder(handle)
    for _ in range(10):  # the holder writes its PID just after it locks
        if holder != "PID unknown":
            break
        time.sleep(0.1)
        holder = _holder(handle)
    pid = holder.split()[1]
    how = f"wait for it to end or stop it (kill {pid})" if pid.isdigit() else "wait for it to end"
    raise StudyLockedError(f"{root}: another synthleak study is running on this folder ({holder}); {how}, "
                           f"then rerun")
