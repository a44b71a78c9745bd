"""Generated blocks in the docs: a benchmark figure quoted by a page is written there by the command that measures it.

A block is the text between ``<!-- generated:NAME begin (by `COMMAND`) -->`` and ``<!-- generated:NAME end -->``.
:func:`replace_block` rewrites it (and the command in its begin marker) atomically; a page without both markers
is refused, so a figure is only ever regenerated where someone placed the markers by hand once. The benchmarks
that take ``--docs PAGE`` call :func:`write_benchmark_block` with their printed table; ``tests/test_docs_figures.py``
checks that no presence-like figure sits in a docs table outside such a block or a line naming its command.
"""

from __future__ import annotations

import os
import re
import shlex
import sys
import time
from pathlib import Path

from synthleak.atomic_io import atomic_write_text
from synthleak.errors import SynthleakError


class DocBlockError(SynthleakError, ValueError):
    """A docs page lacks a generated block's markers (or holds them twice, or out of order)."""


def begin_marker(name: str, command: str) -> str:
    """The line that opens block ``name``, naming the ``command`` that regenerates it."""
    return f"<!-- generated:{name} begin (by `{command}`) -->"


def end_marker(name: str) -> str:
    """The line that closes block ``name``."""
    return f"<!-- generated:{name} end -->"


def _begin_pattern(name: str) -> re.Pattern[str]:
    return re.compile(rf"^<!-- generated:{re.escape(name)} begin(?: \(by `[^`\n]*`\))? -->$", re.M)


BLOCK_PATTERN = re.compile(r"^<!-- generated:(?P<name>[\w.-]+) begin \(by `(?P<command>[^`\n]+)`\) -->\n"
                           r"(?P<body>.*?)^<!-- generated:(?P=name) end -->$", re.M | re.S)
"""A whole block of a page: its name, command and body (for readers such as the docs test)."""


def replace_block(path: str | Path, name: str, markdown: str, command: str) -> None:
    """Replace the body of block ``name`` in ``path`` with ``markdown`` and its begin marker's command with
    ``command``; written atomically (temporary file + rename). Raises :class:`DocBlockError` naming the file and
    the block when either marker is missing, repeated or out of order."""
    path = Path(path)
    if not re.fullmatch(r"[\w.-]+", name):
        raise DocBlockError(f"{path}: block name {name!r}: letters, digits, '.', '_' and '-' only")
    if "`" in command or "\n" in command:
        raise DocBlockError(f"{path}: block {name!r}: the command may hold no backtick or newline: {command!r}")
    text = path.read_text(encoding="utf-8")
    begins = list(_begin_pattern(name).finditer(text))
    ends = [m.start() for m in re.finditer(rf"^{re.escape(end_marker(name))}$", text, re.M)]
    how = f"add the lines `{begin_marker(name, command)}` and `{end_marker(name)}` where the figures go"
    if not begins or not ends:
        missing = " and ".join(w for w, found in (("begin", begins), ("end", ends)) if not found)
        raise DocBlockError(f"{path}: generated block {name!r}: no {missing} marker ({how})")
    if len(begins) > 1 or len(ends) > 1:
        raise DocBlockError(f"{path}: generated block {name!r}: {len(begins)} begin and {len(ends)} end markers, "
                            "one of each expected")
    begin, end = begins[0], ends[0]
    if end < begin.end():
        raise DocBlockError(f"{path}: generated block {name!r}: the end marker comes before the begin marker")
    body = markdown if markdown.endswith("\n") or not markdown else markdown + "\n"
    atomic_write_text(path, text[:begin.start()] + begin_marker(name, command) + "\n" + body + text[end:])


def invoked_command(script: str | None = None, argv: list[str] | None = None) -> str:
    """The command line that ran this process, as ``python benchmarks/X.py ARGS`` (the script's path relative to
    the working directory where it lies under it)."""
    script = script or sys.argv[0]
    argv = sys.argv[1:] if argv is None else argv
    shown = Path(os.path.relpath(Path(script).resolve(), Path.cwd()))
    if shown.parts and shown.parts[0] == "..":
        shown = Path(script)
    return shlex.join(["python", shown.as_posix(), *argv])


def measured_line(cores: int | None = None) -> str:
    """One line of provenance under a benchmark's table: commit, date, CPU, cores and load average."""
    from synthleak.provenance import cpu_model, source_commit  # noqa: PLC0415 (imports the config machinery)

    commit = source_commit() or "unknown"
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    cores = cores or os.cpu_count() or 0
    return (f"Measured at commit `{commit}` on {time.strftime('%Y-%m-%d')}: {cpu_model()}, {cores} cores, "
            f"load average {load:.1f} at the end (other jobs on the machine inflate timings).")


def markdown_table(header: list[str], rows: list[list[str]]) -> str:
    """A markdown table of strings (``|`` in a cell escaped)."""
    def line(cells: list[str]) -> str:
        return "| " + " | ".join(str(c).replace("|", "\\|") for c in cells) + " |"
    return "\n".join([line(header), "|" + "---|" * len(header), *(line(r) for r in rows)])


def rich_table_markdown(table: object) -> str:
    """A :class:`rich.table.Table` of plain-text cells as a markdown table (its title, if any, is left out)."""
    columns = list(table.columns)  # type: ignore[attr-defined]
    cells = [[str(c) for c in column.cells] for column in columns]
    rows = [list(row) for row in zip(*cells, strict=True)] if cells else []
    return markdown_table([str(column.header) for column in columns], rows)


def write_benchmark_block(page: str | Path, name: str, markdown: str) -> None:
    """Write a benchmark's ``markdown`` (its table) and a provenance line into block ``name`` of ``page``, the
    command being this process's own command line."""
    replace_block(page, name, markdown.rstrip("\n") + "\n\n" + measured_line() + "\n", invoked_command())
