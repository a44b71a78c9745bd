"""No measurement is typed into the explanatory docs: a presence-like figure in a docs table comes from a generated
block (``synthleak.evaluate.doc_blocks``) or states the benchmark command that measured it and that it was not
regenerated since; study results live on the generated ``docs/results`` pages."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from synthleak.evaluate.doc_blocks import (
    BLOCK_PATTERN,
    DocBlockError,
    begin_marker,
    end_marker,
    invoked_command,
    markdown_table,
    replace_block,
)

ROOT = Path(__file__).resolve().parents[1]
PAGES = sorted((ROOT / "docs").glob("*.md"))  # not docs/results/: those pages are generated whole

PAIR = re.compile(r"(?<![\d.])[01]\.\d{2,3} ?/ ?[01]\.\d{2,3}(?![\d.%])")
"""Two figures in [0, 1] with two or three decimals, ``0.83 / 0.77``: how a P / R (or any rate pair) is typed."""

COMMAND = re.compile(r"`python (benchmarks/[\w-]+\.py)\b[^`]*`")
PROVENANCE = "not regenerated since"


def _paragraph_before(lines: list[str], start: int) -> str:
    """The paragraph above line ``start``: blank lines skipped, then up to the next blank line."""
    i = start - 1
    while i >= 0 and not lines[i].strip():
        i -= 1
    above: list[str] = []
    while i >= 0 and lines[i].strip() and not lines[i].startswith("|"):
        above.insert(0, lines[i])
        i -= 1
    return " ".join(above)


def _names_its_command(paragraph: str) -> bool:
    """The paragraph names an existing benchmark's command and says the figures were not regenerated since."""
    scripts = COMMAND.findall(paragraph)
    return PROVENANCE in " ".join(paragraph.split()) and any((ROOT / s).is_file() for s in scripts)


def hand_typed_rows(text: str) -> list[str]:
    """Table rows of ``text`` holding a figure pair, outside generated blocks and below no paragraph that names
    the command that measured them."""
    spans = [m.span() for m in BLOCK_PATTERN.finditer(text)]
    lines = text.splitlines()
    offsets, at = [], 0
    for line in lines:
        offsets.append(at)
        at += len(line) + 1
    flagged: list[str] = []
    i = 0
    while i < len(lines):
        if not lines[i].startswith("|"):
            i += 1
            continue
        j = i
        while j < len(lines) and lines[j].startswith("|"):
            j += 1
        inside = any(a <= offsets[i] < b for a, b in spans)
        rows = [row for row in lines[i:j] if PAIR.search(row)]
        if rows and not inside and not _names_its_command(_paragraph_before(lines, i)):
            flagged += rows
        i = j
    return flagged


def untraced_paragraphs(text: str) -> list[str]:
    """Prose paragraphs of ``text`` (outside generated blocks) holding a figure pair without saying where it came
    from: they must say the figures were not regenerated since (naming the command there or just above)."""
    for block in BLOCK_PATTERN.finditer(text):
        text = text.replace(block.group(0), "")
    paragraphs = [" ".join(p.split()) for p in re.split(r"\n\s*\n", text) if not p.lstrip().startswith("|")]
    return [p for p in paragraphs if PAIR.search(p) and PROVENANCE not in p]


def test_pages_exist() -> None:
    names = {p.name for p in PAGES}
    assert {"attack.md", "hard-world.md", "learned-tiers.md", "renderers.md", "scaling.md"} <= names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_hand_typed_figure_in_a_table(page: Path) -> None:
    rows = hand_typed_rows(page.read_text())
    assert not rows, (f"{page.relative_to(ROOT)}: figures typed by hand; link the generated docs/results page, or "
                      "put them in a generated block, or name the benchmark command and say "
                      f"'{PROVENANCE}' in the paragraph above:\n" + "\n".join(rows))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_no_untraced_figure_pair_in_prose(page: Path) -> None:
    paragraphs = untraced_paragraphs(page.read_text())
    assert not paragraphs, (f"{page.relative_to(ROOT)}: figures without provenance (link the docs/results page, "
                            f"or say which command measured them and '{PROVENANCE}'):\n" + "\n".join(paragraphs))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_generated_blocks_name_a_benchmark_that_writes_them(page: Path) -> None:
    """Every block's command runs a benchmark that takes ``--docs`` and points it at this page."""
    text = page.read_text()
    assert text.count("<!-- generated:") == 2 * len(BLOCK_PATTERN.findall(text)), "unpaired generated marker"
    for block in BLOCK_PATTERN.finditer(text):
        command = block["command"]
        script = COMMAND.search(f"`{command}`")
        assert script, command
        assert "--docs" in (ROOT / script[1]).read_text(), f"{script[1]} has no --docs option"
        assert f"--docs docs/{page.name}" in command, command
        assert block["body"].strip(), f"{page.name}: block {block['name']!r} is empty: run `{command}`"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_links_resolve(page: Path) -> None:
    """Each relative link of a page (the results pages it points to instead of typed figures) exists."""
    links = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", page.read_text())
    missing = [link for link in links if not link.startswith("http") and not (page.parent / link).exists()]
    assert not missing, missing


def test_the_scan_flags_a_typed_pr_row_and_not_config_tables() -> None:
    typed = "Results:\n\n| tier | P / R |\n|---|---|\n| sift | 0.83 / 0.77 |\n"
    assert hand_typed_rows(typed) == ["| sift | 0.83 / 0.77 |"]
    measured = ("Measured by `python benchmarks/matching.py` at abc1234; not regenerated since:\n\n" + typed[10:])
    assert hand_typed_rows(measured) == []
    wrong_script = measured.replace("matching.py", "no_such_benchmark.py")
    assert hand_typed_rows(wrong_script) == ["| sift | 0.83 / 0.77 |"]
    block = f"{begin_marker('x', 'python benchmarks/matching.py')}\n{typed}{end_marker('x')}\n"
    assert hand_typed_rows(block) == []
    config = ("| key | value |\n|---|---|\n| ratio | 0.75 + mutual, 20 |\n| version | 0.1.4 / 0.2.9 |\n"
              "| thresholds | 10°/0.25 m, 60°/2 m |\n| fraction | 0.05 / 0.1 |\n")
    assert hand_typed_rows(config) == []
    assert untraced_paragraphs("sift P / R 0.83 / 0.77 here.\n\nok 10°/0.25 m, ratio 0.75.\n") == [
        "sift P / R 0.83 / 0.77 here."]
    assert untraced_paragraphs(f"P / R 0.83 / 0.77 ({PROVENANCE}).\n") == []


def test_replace_block_rewrites_only_the_block(tmp_path: Path) -> None:
    page = tmp_path / "page.md"
    page.write_text(f"intro\n{begin_marker('t', 'python old.py')}\nstale 0.1\n{end_marker('t')}\noutro\n")
    replace_block(page, "t", markdown_table(["a", "b"], [["1", "x|y"]]), "python benchmarks/t.py --docs page.md")
    assert page.read_text() == ("intro\n<!-- generated:t begin (by `python benchmarks/t.py --docs page.md`) -->\n"
                                "| a | b |\n|---|---|\n| 1 | x\\|y |\n<!-- generated:t end -->\noutro\n")
    assert [p.name for p in tmp_path.iterdir()] == ["page.md"]  # no temporary file left behind


@pytest.mark.parametrize("text, problem", [
    ("no markers here\n", "no begin and end marker"),
    (f"{begin_marker('t', 'c')}\nbody\n", "no end marker"),
    (f"{end_marker('t')}\n{begin_marker('t', 'c')}\n", "end marker comes before"),
    (f"{begin_marker('t', 'c')}\n{end_marker('t')}\n{begin_marker('t', 'c')}\n{end_marker('t')}\n", "2 begin"),
])
def test_replace_block_refuses_a_missing_or_broken_marker(tmp_path: Path, text: str, problem: str) -> None:
    page = tmp_path / "page.md"
    page.write_text(text)
    with pytest.raises(DocBlockError, match=re.escape(problem)) as error:
        replace_block(page, "t", "new", "python benchmarks/t.py")
    assert str(page) in str(error.value) and "'t'" in str(error.value)
    assert page.read_text() == text


def test_invoked_command_is_relative_and_quoted(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "benchmarks").mkdir()
    script = tmp_path / "benchmarks" / "x.py"
    monkeypatch.chdir(tmp_path)
    assert invoked_command(str(script), ["--docs", "docs/a b.md"]) == "python benchmarks/x.py --docs 'docs/a b.md'"
