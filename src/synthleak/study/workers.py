"""What the feature and query tasks of a study keep in their worker process between tasks."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

QUERIES_PER_TASK = 50
"""Localization queries (or feature extractions) per worker task (a worker loads each map once and keeps it
for its next tasks)."""

_WORKER_CACHE: dict[str, Any] = {}
"""The localizer (or extractor) the last task in this process used (one map at a time, to bound memory)."""


def worker_cached(key: str, make: Callable[[], Any]) -> Any:
    """The value made for ``key`` by the last task in this process, or a new one (replacing it)."""
    if _WORKER_CACHE.get("key") != key:
        _WORKER_CACHE.clear()
        _WORKER_CACHE.update(key=key, value=make())
    return _WORKER_CACHE["value"]


def clear_worker_cache() -> None:
    """Drop what this process keeps (after a stage ran its tasks here, serially)."""
    _WORKER_CACHE.clear()
