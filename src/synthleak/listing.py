"""Print a listing (``synthleak objects``, ``presets``, ``tiers``): a rich table on a terminal, tab-separated
text when stdout is piped, JSON with ``--json``.

Piped output is a header line and one line per row, fields separated by tabs, values whole (never cut to the
terminal's width; tabs and newlines inside a value become spaces), so ``grep``, ``cut -f`` and ``sort`` work on it.
JSON is a list of objects, one per row, with numbers kept as numbers.
"""

from __future__ import annotations

import json
import re
import sys
from collections.abc import Mapping, Sequence
from typing import Any, TextIO

from rich.markup import escape
from rich.table import Table

_BLANKS = re.compile(r"[\t\r\n]+")


def cell_text(value: Any) -> str:
    """A value as a cell: ``None`` is ``-``, floats in their shortest form, lists joined by commas."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:g}"
    if isinstance(value, list | tuple):
        return ", ".join(cell_text(v) for v in value)
    return str(value)


def rows_table(columns: Sequence[str], rows: Sequence[Sequence[Any]], title: str | None = None) -> Table:
    """A rich table of ``rows`` whose cells fold instead of being cut (markup in the values is shown as is)."""
    table = Table(title=escape(title) if title else None)
    for column in columns:
        table.add_column(escape(column), overflow="fold")
    for row in rows:
        table.add_row(*(escape(cell_text(v)) for v in row))
    return table


def plain_lines(columns: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    """The header and one line per row, tab-separated, tabs and newlines inside values turned into spaces."""
    def line(cells: Sequence[Any]) -> str:
        return "\t".join(_BLANKS.sub(" ", cell_text(c)) for c in cells)

    for row in rows:
        if len(row) != len(columns):
            raise ValueError(f"listing: a row of {len(row)} values for {len(columns)} columns: {row!r}")
    return [line(columns)] + [line(row) for row in rows]


def print_rows(columns: Sequence[str], rows: Sequence[Sequence[Any]], *, json_out: bool, title: str | None = None,
               records: Sequence[Mapping[str, Any]] | None = None, file: TextIO | None = None) -> None:
    """Print ``rows`` (one value per column) to ``file`` (default: stdout).

    ``json_out``: a JSON list of ``records`` (default: each row as an object keyed by the column names).
    Otherwise a rich table titled ``title`` when ``file`` is a terminal, else :func:`plain_lines` (no title)."""
    file = file if file is not None else sys.stdout
    if json_out:
        if records is None:
            records = [dict(zip(columns, row, strict=True)) for row in rows]
        file.write(json.dumps(list(records), indent=2, default=str) + "\n")
    elif file.isatty():
        from rich.console import Console

        Console(file=file).print(rows_table(columns, rows, title))
    else:
        file.write("".join(f"{line}\n" for line in plain_lines(columns, rows)))
