"""docs/results pages: written from a study's own folder, their figures those of its results.json, never edited."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from PIL import Image

from synthleak.evaluate.results_page import render_page, results_summary, write_results_page

DOCS_RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"


def _table_after(text: str, heading: str) -> list[dict[str, str]]:
    """The first markdown table after ``heading`` as dicts of cells."""
    lines = text[text.index(heading):].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    header = [c.strip() for c in lines[start].strip("|").split("|")]
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(header, (c.strip() for c in line.strip("|").split("|")), strict=True)))
    return rows


def test_a_page_from_the_ci_tiny_study_shows_its_results(ci_tiny_study: Path, tmp_path: Path) -> None:
    page = write_results_page(ci_tiny_study, tmp_path / "results" / "ci-tiny.md")
    text = page.read_text()
    runs = json.loads((ci_tiny_study / "run.json").read_text())["runs"]
    assert runs[-1]["config"] == "ci-tiny" and runs[-1]["cpu"] in text and runs[-1]["config_key"] in text
    # the headline, recomputed here from results.json by counting
    rows = [r for r in json.loads((ci_tiny_study / "results" / "results.json").read_text())
            if r["aligner"] == "alg1" and r["delta_r_deg"] == 10 and r["delta_t_m"] == 0.25
            and r.get("magnitude") is None]
    table = _table_after(text, "## Presence and placement at 10°/0.25 m")
    assert [t["tier"] for t in table] == sorted({r["tier"] for r in rows})
    for line in table:
        mine = [r for r in rows if r["tier"] == line["tier"]]
        tp = sum(r["decision"] and r["present_gt"] for r in mine)
        fp = sum(r["decision"] and not r["present_gt"] for r in mine)
        present = [r for r in mine if r["present_gt"]]
        placed = sum((r["rot_err_deg"] or 1e9) <= 10 and (r["trans_err_m"] or 1e9) <= 0.25 for r in present)
        assert (int(line["tp"]), int(line["fp"]), int(line["n_present"])) == (tp, fp, len(present))
        assert float(line["precision"]) == pytest.approx(tp / (tp + fp) if tp + fp else 0.0, abs=0.005)
        assert float(line["recall"]) == pytest.approx(tp / len(present), abs=0.005)
        assert float(line["placement_success"]) == pytest.approx(placed / len(present), abs=0.005)
        absent = [r for r in mine if not r["present_gt"]]
        localized, queries = sum(r["n_localized"] for r in absent), sum(r["n_queries"] for r in absent)
        assert line["absent_queries_localized"] == f"{localized} / {queries}"
    # the page is its summary rendered; the figures are there and are images
    summary = json.loads(page.with_suffix(".json").read_text())
    assert render_page(summary) == text
    assert summary["wall_s"] == pytest.approx(sum(r["wall_s"] for r in runs), abs=0.2)
    assert "contact_sheet.png" in summary["plots"] and "presence_pr.png" in summary["plots"]
    for name in summary["plots"]:
        assert f"(ci-tiny/{name})" in text
        with Image.open(page.parent / "ci-tiny" / name) as image:
            assert image.width > 100
    index = json.loads((page.parent / "index.json").read_text())
    assert index["presets"]["ci-tiny"]["wall_s"] == summary["wall_s"]


def test_a_folder_without_a_run_record_is_refused_by_name(ci_tiny_study: Path, tmp_path: Path) -> None:
    copy = tmp_path / "study"
    shutil.copytree(ci_tiny_study / "results", copy / "results")
    with pytest.raises(FileNotFoundError, match="run.json"):
        results_summary(copy)


@pytest.mark.parametrize("summary_path", sorted(p for p in DOCS_RESULTS.glob("*.json") if p.name != "index.json"),
                         ids=lambda p: p.stem)
def test_committed_pages_are_their_summaries_rendered(summary_path: Path) -> None:
    """A page in docs/results is exactly what the command wrote from its run: no figure typed by hand."""
    summary = json.loads(summary_path.read_text())
    assert summary_path.with_suffix(".md").read_text() == render_page(summary)
    for name in summary["plots"]:
        assert (DOCS_RESULTS / summary["name"] / name).is_file(), name
    index = json.loads((DOCS_RESULTS / "index.json").read_text())
    assert index["presets"][summary["config"]]["wall_s"] == summary["wall_s"]


def test_docs_results_holds_the_readme_study() -> None:
    assert (DOCS_RESULTS / "study-small.md").is_file()
