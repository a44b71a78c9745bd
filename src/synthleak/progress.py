"""Progress bars for long loops (rich), silent when disabled or when output is not a terminal log."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

T = TypeVar("T")


def progress_display(enabled: bool = True) -> Progress:
    """The one rich progress display of synthleak (description, bar, done / total, elapsed time); a context
    manager that shows nothing when ``enabled`` is False. Add tasks with ``add_task``, step with ``advance``."""
    columns = (TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    return Progress(*columns, disable=not enabled, transient=False)


def progress_bar(items: Iterable[T], description: str, enabled: bool = True, total: int | None = None
                 ) -> Iterator[T]:
    """Iterate over ``items`` with a rich progress bar (a plain iteration when ``enabled`` is False)."""
    if not enabled:
        yield from items
        return
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with progress_display() as bar:
        task = bar.add_task(description, total=total)
        for item in items:
            yield item
            bar.advance(task)
