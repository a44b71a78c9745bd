"""Atomic file writes: a temporary file in the target's folder, then ``os.replace`` onto the target, so a
reader (or a resumed run) sees the old file or the whole new one, never a part. Files get the mode a plain
``open`` would give them (0666 less the umask), not the 0600 of ``tempfile.mkstemp``."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

TEMP_PREFIX = ".tmp-"
"""Name prefix of the temporary files; an interrupted writer's leftovers start with it."""


def _read_umask() -> int:
    """The process umask, without changing it (Linux: /proc; elsewhere set and restore once, at import)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK_AT_IMPORT = _read_umask()


def umask() -> int:
    """The current umask (read from /proc where it exists, so later ``os.umask`` calls are seen)."""
    return _read_umask() if os.path.exists("/proc/self/status") else _UMASK_AT_IMPORT


def file_mode() -> int:
    """The mode of a new file: ``0o666 & ~umask``."""
    return 0o666 & ~umask()


def folder_mode() -> int:
    """The mode of a new folder: ``0o777 & ~umask``."""
    return 0o777 & ~umask()


def atomic_write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to a temporary file in the same folder, then ``os.replace`` it onto ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX + path.name + ".", dir=path.parent)
    try:
        os.fchmod(fd, file_mode())
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_text(path: Path, text: str) -> None:
    """UTF-8 ``text`` through :func:`atomic_write_bytes`."""
    atomic_write_bytes(path, text.encode("utf-8"))
