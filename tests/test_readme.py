"""README.md: short, its links resolve, its presets table is generated, its Python quickstart runs."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from synthleak.evaluate.results_page import PRESETS_BEGIN, PRESETS_END, presets_markdown

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def test_readme_is_a_front_door() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    for heading in ("## Two commands", "## Python quickstart", "## The pipeline", "## Presets"):
        assert heading in text


def test_readme_links_resolve() -> None:
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", README.read_text())
    assert len(links) >= 10
    missing = [link for link in links if not link.startswith("http") and not (ROOT / link).exists()]
    assert not missing, missing


def test_readme_presets_table_is_the_generated_one() -> None:
    """No wall time in the table is typed by hand: it is `presets_markdown` of docs/results/index.json."""
    text = README.read_text()
    block = text[text.index("\n", text.index(PRESETS_BEGIN)) + 1:text.index(PRESETS_END)]
    assert block == presets_markdown()
    assert "`study-small`" in block and "`ci-tiny`" in block


def test_readme_quickstart_runs(ci_tiny_study: Path, tmp_path: Path) -> None:
    """The quickstart block as written, in a folder holding a finished ci-tiny study (so run_study resumes)."""
    text = README.read_text()
    code = re.search(r"## Python quickstart\s+```python\n(.*?)```", text, re.S).group(1)
    shutil.copytree(ci_tiny_study, tmp_path / "runs" / "ci-tiny", ignore=shutil.ignore_patterns(".study.lock"))
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    first, second = done.stdout.strip().splitlines()[-2:]
    pr = eval(first, {"nan": float("nan")})  # the dict precision_recall printed
    assert pr["n_present"] >= 2 and 0.0 <= pr["precision"] <= 1.0
    errors = eval(second, {"None": None})
    assert len(errors) == pr["n_present"] and min(e for e in errors if e is not None) < 0.25


@pytest.mark.parametrize("page", ["study-small"])
def test_readme_pictures_come_from_a_results_page(page: str) -> None:
    text = README.read_text()
    assert f"docs/results/{page}/contact_sheet.png" in text
    assert (ROOT / "docs" / "results" / page / "contact_sheet.png").is_file()
