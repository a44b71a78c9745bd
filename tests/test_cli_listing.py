"""The listing commands (`objects`, `presets`, `tiers`) pipe: tab-separated lines with whole values when stdout is
no terminal, JSON with --json; `synthleak --version`. Run through the real CLI in a fresh process, stdout piped."""

from __future__ import annotations

import importlib.metadata
import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from synthleak.assets.catalog import objects_rows
from synthleak.assets.library import load_library
from synthleak.config import ConfigError, PresetCost, list_presets, load_config, load_costs
from synthleak.listing import plain_lines, print_rows
from synthleak.localize.tiers import tier_names
from synthleak.paths import render_configs_dir


def run_cli(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "synthleak.cli", *args], capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=120)


def table(stdout: str) -> tuple[list[str], list[list[str]]]:
    """The header and the rows of piped output; every line has the header's number of fields."""
    header, *lines = stdout.splitlines()
    columns = header.split("\t")
    rows = [line.split("\t") for line in lines]
    assert len(columns) > 1 and all(len(row) == len(columns) for row in rows), stdout
    return columns, rows


def test_objects_piped_are_whole_tab_separated_lines() -> None:
    result = run_cli("objects")
    assert result.returncode == 0 and result.stderr == "", result.stderr
    columns, rows = table(result.stdout)
    assert columns[:3] == ["id", "category", "role"]
    library = load_library()
    assert [row[0] for row in rows] == sorted(library)
    longest = max(library, key=len)
    assert len(longest) > 20 and longest in {row[0] for row in rows}  # rich's 80 columns cut such ids
    assert {row[2] for row in rows} == {m.role for m in library.values()}


def test_objects_json_is_the_catalogue() -> None:
    result = run_cli("objects", "--json", "--role", "prop")
    assert result.returncode == 0, result.stderr
    props = {k: m for k, m in load_library().items() if m.role == "prop"}
    assert json.loads(result.stdout) == objects_rows(props)
    result = run_cli("objects", "--json")
    assert len(json.loads(result.stdout)) == len(load_library())


def test_presets_lists_every_config() -> None:
    result = run_cli("presets")
    assert result.returncode == 0 and result.stderr == "", result.stderr
    columns, rows = table(result.stdout)
    assert columns == ["name", "extends", "description", "renderer", "tiers", "measured cost"]
    names = sorted(p.stem for p in render_configs_dir().glob("*.toml"))
    assert [row[0] for row in rows] == names and "ci-tiny" in names
    ci_tiny = dict(zip(columns, rows[names.index("ci-tiny")], strict=True))
    config = load_config("ci-tiny")
    assert ci_tiny["description"] == config.description != ""
    assert ci_tiny["extends"] == "-" and ci_tiny["renderer"] == config.render.renderer
    assert ci_tiny["tiers"] == ", ".join(config.localize.tiers)
    small = dict(zip(columns, rows[names.index("study-small")], strict=True))
    assert small["extends"] == "study"

    result = run_cli("presets", "--json")
    assert result.returncode == 0, result.stderr
    presets = json.loads(result.stdout)
    assert [p["name"] for p in presets] == names
    ci_tiny = presets[names.index("ci-tiny")]
    assert ci_tiny["description"] == config.description and ci_tiny["tiers"] == config.localize.tiers
    assert ci_tiny["error"] is None and (ci_tiny["cost"] is None or isinstance(ci_tiny["cost"]["wall_s"], float))


def test_a_broken_preset_is_listed_and_named_on_stderr(tmp_path: Path) -> None:
    """SYNTHLEAK_RENDER_CONFIGS moves the root: the costs come from docs/results/index.json beside it."""
    configs = tmp_path / "render_configs"
    configs.mkdir()
    shutil.copy(render_configs_dir() / "ci-tiny.toml", configs)
    (configs / "broken.toml").write_text('extends = "ci-tiny"\ndescription = "bad"\n[render]\nrenderer = "nope"\n')
    index = tmp_path / "docs" / "results" / "index.json"
    index.parent.mkdir(parents=True)
    index.write_text(json.dumps({"presets": {"ci-tiny": {"wall_s": 709.4, "cpu": "Intel Xeon", "cores": 2,
                                                         "commit": "abc1234", "page": "docs/results/ci-tiny.md"}}}))
    result = run_cli("presets", env={"SYNTHLEAK_RENDER_CONFIGS": str(configs)})
    assert result.returncode == 2
    columns, rows = table(result.stdout)
    broken, ci_tiny = (dict(zip(columns, row, strict=True)) for row in rows)
    assert broken["name"] == "broken" and broken["extends"] == "ci-tiny" and broken["measured cost"] == "-"
    assert broken["description"].startswith("error: ") and "render.renderer" in broken["description"]
    assert ci_tiny["measured cost"] == "11.8 min (2 cores)"
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("synthleak presets: error: ") and "broken.toml" in lines[0]

    result = run_cli("presets", "--json", env={"SYNTHLEAK_RENDER_CONFIGS": str(configs)})
    assert result.returncode == 2
    broken, ci_tiny = json.loads(result.stdout)
    assert "nope" in broken["error"] and broken["renderer"] is None
    assert ci_tiny["cost"] == {"wall_s": 709.4, "cores": 2, "cpu": "Intel Xeon", "commit": "abc1234",
                               "page": "docs/results/ci-tiny.md", "config_key": "", "stale": False,
                               "from_empty": True}


def test_a_cost_measured_on_another_config_says_so(tmp_path: Path) -> None:
    from synthleak.config import list_presets, load_config
    from synthleak.provenance import config_key

    index = tmp_path / "index.json"
    entry = {"wall_s": 709.4, "cores": 2, "commit": "abc1234"}
    index.write_text(json.dumps({"presets": {"ci-tiny": {**entry, "config_key": config_key(load_config("ci-tiny"))},
                                             "ci-tiny-hard": {**entry, "config_key": "000000000000"}}}))
    costs = {p.name: p.cost for p in list_presets(index) if p.cost}
    assert str(costs["ci-tiny"]) == "11.8 min (2 cores)" and not costs["ci-tiny"].stale
    assert str(costs["ci-tiny-hard"]) == "11.8 min (2 cores), an earlier config"


def test_preset_costs_from_an_index(tmp_path: Path) -> None:
    index = tmp_path / "index.json"
    index.write_text(json.dumps({"presets": {"study-small": {"wall_s": 709.4, "cpu": "Intel Xeon", "cores": 2,
                                                             "commit": "abc1234", "page": "docs/results/x.md",
                                                             "unknown": "ignored"}}}))
    by_name = {p.name: p for p in list_presets(index)}
    assert str(by_name["study-small"].cost) == "11.8 min (2 cores)"
    assert by_name["study-small"].cost.commit == "abc1234"
    assert by_name["ci-tiny"].cost is None and by_name["ci-tiny"].error is None
    assert all(p.cost is None for p in list_presets(tmp_path / "absent.json"))
    assert str(PresetCost(45.2, 1)) == "45 s (1 core)" and str(PresetCost(3 * 3600.0)) == "3.0 h"
    for bad, needle in (("{", "not valid JSON"), ('{"presets": []}', "presets"),
                        ('{"presets": {"a": {"wall_s": "long"}}}', "presets.a.wall_s"),
                        ('{"presets": {"a": {"wall_s": 1, "cores": 0}}}', "presets.a.cores")):
        index.write_text(bad)
        with pytest.raises(ConfigError, match=needle) as error:
            load_costs(index)
        assert str(index) in str(error.value)


def test_tiers_lists_the_registry() -> None:
    result = run_cli("tiers", "--json")
    assert result.returncode == 0, result.stderr
    tiers = json.loads(result.stdout)
    names = [t["name"] for t in tiers]
    assert names == tier_names() and {"sift", "xfeat"} <= set(names)
    sift = tiers[names.index("sift")]
    assert sift["min_inliers"] == 15 and sift["ratio"] == 0.8 and sift["mutual"] is True and sift["description"]
    result = run_cli("tiers")
    columns, rows = table(result.stdout)
    assert [row[0] for row in rows] == tier_names()
    assert dict(zip(columns, rows[names.index("xfeat")], strict=True))["max keypoints"] == "4096"


def test_version() -> None:
    result = run_cli("--version")
    assert result.returncode == 0
    assert result.stdout.strip() == f"synthleak {importlib.metadata.version('synthleak')}"


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX pipes")
def test_a_closed_pipe_ends_quietly() -> None:
    """`synthleak objects | head -1` once head has gone: no traceback, the status of a SIGPIPE death."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        result = subprocess.run([sys.executable, "-m", "synthleak.cli", "objects"], stdout=write_end,
                                stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write_end)
    assert result.stderr == "" and result.returncode == 141


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_print_rows_modes() -> None:
    columns, rows = ("name", "value", "note"), [["a\tb", 1.5, "two\nlines"], ["c", None, ["x", "y"]]]
    assert plain_lines(columns, rows) == ["name\tvalue\tnote", "a b\t1.5\ttwo lines", "c\t-\tx, y"]
    out = io.StringIO()
    print_rows(columns, rows, json_out=True, file=out)
    assert json.loads(out.getvalue()) == [{"name": "a\tb", "value": 1.5, "note": "two\nlines"},
                                          {"name": "c", "value": None, "note": ["x", "y"]}]
    out = io.StringIO()
    print_rows(columns, rows, json_out=False, title="the [title]", file=out)
    assert "the [title]" not in out.getvalue() and out.getvalue().count("\n") == 3
    terminal = _Terminal()
    print_rows(columns, rows, json_out=False, title="the [title]", file=terminal)
    assert "the [title]" in terminal.getvalue() and "━" in terminal.getvalue()
    with pytest.raises(ValueError, match="2 values for 3 columns"):
        plain_lines(columns, [["a", "b"]])
