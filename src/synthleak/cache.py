"""Content-addressed stage caching: a stage's output folder holds a ``.done.json`` with the key of its inputs.

A stage is redone when its key changes (a config section or an upstream output changed), when it is
forced, or when its marker is missing (an interrupted run). Keys are SHA-256 of canonical JSON.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from synthleak.atomic_io import atomic_write_text

MARKER = ".done.json"


def cache_key(*parts: Any) -> str:
    """SHA-256 of the canonical JSON of ``parts`` (dicts sorted, floats as repr)."""
    text = json.dumps(parts, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def done_key(folder: Path) -> str | None:
    """The key ``folder`` was completed with, or None (never completed, or an unreadable marker)."""
    try:
        return json.loads((folder / MARKER).read_text()).get("key")
    except (OSError, json.JSONDecodeError, AttributeError):
        return None


def is_done(folder: Path, key: str) -> bool:
    """True if ``folder`` was completed with the same key."""
    return done_key(folder) == key


def mark_done(folder: Path, key: str, **info: Any) -> None:
    """Record that ``folder`` holds the complete output for ``key`` (atomic write)."""
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_text(folder / MARKER, json.dumps({"key": key, **info}, sort_keys=True, indent=1))
