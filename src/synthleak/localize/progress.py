"""Optional rich progress bars for long loops."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from typing import TypeVar

T = TypeVar("T")


def track(items: Sequence[T], description: str, enabled: bool = True) -> Iterator[T]:
    """Iterate ``items``, with a rich progress bar if ``enabled``."""
    if not enabled:
        yield from items
        return
    from rich.progress import track as rich_track

    yield from rich_track(items, description=description, total=len(items), transient=True)


__all__ = ["track", "Iterable"]
