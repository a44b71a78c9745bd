"""A study's results page for ``docs/results/``: its figures computed from the study's own output folder.

:func:`results_summary` reads a finished study (``results/*.json``, ``run.json``) into a plain summary;
:func:`render_page` turns a summary into markdown; :func:`write_results_page` writes both (``NAME.json`` beside
``NAME.md``), copies the study's plots and a contact sheet into ``NAME/``, and records the preset's wall time in
``index.json``. The page is a pure function of its summary, so a test can check that no committed page was
edited by hand, and the summary's figures are recomputed from ``results.json`` by the test suite.
"""

from __future__ import annotations

import json
import math
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from synthleak.atomic_io import atomic_write_text
from synthleak.evaluate.paper_reference import PRESENCE_RULES, tier_ordering_markdown
from synthleak.evaluate.server_summary import COLUMNS as SERVER_COLUMNS
from synthleak.evaluate.shell_share import shell_share
from synthleak.evaluate.tables import markdown_table, placement_stats, plain, precision_recall, read_results
from synthleak.provenance import read_run_record
from synthleak.schema import as_list

HEADLINE = (10.0, 0.25)
"""The headline thresholds (δr degrees, δt metres): the paper's strictest."""

PLOTS = ("presence_pr.png", "placement_cdf.png", "defense_tradeoff.png", "utility_vs_leakage.png")
"""The study plots a page shows (those the study made), then the first room's top-down plot."""

HEADLINE_COLUMNS = ("tier", "precision", "recall", "tp", "fp", "n_present", "n_absent", "placement_success",
                    "median_rot_err_deg", "median_trans_err_m", "present_queries_localized",
                    "absent_queries_localized")


def _sum_queries(rows: Sequence[dict], present: bool) -> str:
    chosen = [r for r in rows if bool(r["present_gt"]) == present]
    return f"{sum(int(r['n_localized']) for r in chosen)} / {sum(int(r['n_queries']) for r in chosen)}"


def headline_rows(rows: Sequence[dict], aligner: str, thresholds: tuple[float, float] = HEADLINE
                  ) -> list[dict[str, Any]]:
    """Per tier, ``aligner``'s rows at ``thresholds`` (no variant sweep): presence P/R and counts, placement
    success at the same thresholds over the GT-present pairs (unplaced pairs fail), median errors, and the
    attacker queries localized over present / absent pairs."""
    out = []
    chosen = [r for r in rows if r["aligner"] == aligner and r.get("magnitude") is None
              and (float(r["delta_r_deg"]), float(r["delta_t_m"])) == thresholds]
    for tier in sorted({r["tier"] for r in chosen}):
        group = [r for r in chosen if r["tier"] == tier]
        pr = precision_recall(group)
        stats = placement_stats(group, thresholds=[thresholds])
        place = stats[0] if stats else {}
        out.append({
            "tier": tier, "precision": pr["precision"], "recall": pr["recall"], "tp": pr["tp"], "fp": pr["fp"],
            "n_present": pr["n_present"], "n_absent": pr["n_pairs"] - pr["n_present"],
            "placement_success": place.get(f"success_{thresholds[0]:g}deg_{thresholds[1]:g}m", math.nan),
            "median_rot_err_deg": place.get("median_rot_err_deg", math.nan),
            "median_trans_err_m": place.get("median_trans_err_m", math.nan),
            "present_queries_localized": _sum_queries(group, True),
            "absent_queries_localized": _sum_queries(group, False),
        })
    return out


def all_thresholds_rows(rows: Sequence[dict]) -> list[dict[str, Any]]:
    """P/R and placement success per tier x aligner x thresholds (no variant sweep)."""
    out = []
    main = [r for r in rows if r.get("magnitude") is None]
    keys = sorted({(r["tier"], r["aligner"], float(r["delta_r_deg"]), float(r["delta_t_m"])) for r in main})
    for tier, aligner, dr, dt in keys:
        group = [r for r in main if (r["tier"], r["aligner"], float(r["delta_r_deg"]), float(r["delta_t_m"]))
                 == (tier, aligner, dr, dt)]
        pr = precision_recall(group)
        stats = placement_stats(group, thresholds=[(dr, dt)])
        out.append({"tier": tier, "aligner": aligner, "thresholds": f"{dr:g}°, {dt:g} m",
                    "precision": pr["precision"], "recall": pr["recall"],
                    "placement_success": stats[0][f"success_{dr:g}deg_{dt:g}m"] if stats else math.nan})
    return out


def genuine_rows(genuine: Sequence[dict]) -> list[dict[str, Any]]:
    """Genuine-query localization pooled over rooms, per tier."""
    out = []
    for tier in sorted({g["tier"] for g in genuine}):
        group = [g for g in genuine if g["tier"] == tier]
        n = sum(g["n"] for g in group)
        closeups = sum(g.get("closeups", 0) for g in group)
        out.append({"tier": tier, "queries": n, "localized": sum(g["localized"] for g in group),
                    "closeups": closeups, "closeups_localized": sum(g.get("closeups_localized", 0) for g in group)})
    return out


def _finite(value: Any) -> Any:
    return None if isinstance(value, float) and not math.isfinite(value) else value


def _seconds(runs: Sequence[dict]) -> dict[str, float]:
    stages: dict[str, float] = {}
    for run in runs:
        for stage, seconds in run.get("stage_s", {}).items():
            stages[stage] = round(stages.get(stage, 0.0) + float(seconds), 1)
    return stages


def results_summary(study: Path, name: str | None = None) -> dict[str, Any]:
    """The figures of a finished study, from its own files: ``run.json`` (provenance; ``synthleak study``
    writes it), ``results/results.json``, ``genuine_localization.json``, ``defense_tradeoff.json``,
    ``world.json``. ``name``: the page's name (default: the config's)."""
    study = Path(study)
    runs = read_run_record(study)
    if not runs:
        raise FileNotFoundError(f"{study / 'run.json'}: no run record; is {study} a finished synthleak study "
                                f"(run `synthleak study CONFIG --out {study}`)?")
    results = study / "results"
    if not (results / "results.json").is_file():
        raise FileNotFoundError(f"{results / 'results.json'}: missing; the study did not finish (rerun it)")
    rows = read_results(results / "results.json")
    last = runs[-1]
    config = last["config_dict"]
    aligner = config["attack"]["aligners"][0]

    def load(file: str) -> Any:
        path = results / file
        return json.loads(path.read_text()) if path.is_file() else []

    tradeoff = [t for t in load("defense_tradeoff.json") if t.get("tier") == "all"]
    first = runs[0]
    # records before `started_empty`: the renders, which always take minutes, tell whether they were made here
    from_empty = first.get("started_empty", float(first.get("stage_s", {}).get("render", 0.0)) >= 1.0)
    world = load("world.json") or {"rooms": []}
    return plain({
        "name": name or last["config"],
        "config": last["config"], "config_key": last["config_key"], "description": config.get("description", ""),
        "commit": last["commit"], "version": last["version"], "cpu": last["cpu"], "cores": last["cores"],
        "workers": last["workers"], "date": last["started"][:10], "invocations": len(runs),
        "wall_s": round(sum(float(r["wall_s"]) for r in runs), 1), "stage_s": _seconds(runs),
        "from_empty": bool(from_empty), "unfinished": sum(not r.get("finished", True) for r in runs),
        "other_configs": sorted({r["config"] for r in runs if r["config_key"] != last["config_key"]}),
        "renderer": config["render"]["renderer"], "resolution": f"{config['render']['width']}x"
                                                                f"{config['render']['height']}",
        "tiers": config["localize"]["tiers"], "aligner": aligner, "presence": config["attack"]["presence"],
        "rooms": len(world.get("rooms", [])), "pairs": len({(r["room"], r["object"]) for r in rows}),
        "headline": [{k: _finite(v) for k, v in r.items()} for r in headline_rows(rows, aligner)],
        "thresholds": [{k: _finite(v) for k, v in r.items()} for r in all_thresholds_rows(rows)],
        "genuine": genuine_rows(load("genuine_localization.json")),
        "shell": [{k: _finite(v) for k, v in r.items()} for r in shell_share(rows)],
        "capture": {kind: config["render"].get(f"capture_{kind}", "ideal") for kind in ("map", "genuine", "attacker")},
        "lighting": {kind: config["render"].get(f"light_{kind}", "same") for kind in ("map", "genuine", "attacker")},
        "servers": [{k: _finite(v) for k, v in r.items()} for r in load("servers.json")],
        "tier_ordering": tier_ordering_markdown(rows, aligner, config["attack"]["presence"]),
        "defense": [{k: v for k, v in t.items() if k != "tier"} for t in tradeoff],
        "world": [{k: _finite(v) for k, v in r.items()} for r in world.get("rooms", [])],
        "plots": [],
    })


def _none_as_nan(rows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    return [{k: math.nan if v is None else v for k, v in r.items()} for r in rows]


def render_page(summary: Mapping[str, Any]) -> str:
    """The markdown page of a :func:`results_summary` (with ``plots``: file names beside the page)."""
    s = summary
    minutes = ", ".join(f"{k} {v / 60:.1f}" for k, v in s["stage_s"].items() if v >= 6)
    resumed = f" over {s['invocations']} invocations (resumed)" if s["invocations"] > 1 else ""
    if not s.get("from_empty", True):
        resumed = (f" over {s['invocations']} recorded invocation{'s' if s['invocations'] > 1 else ''}; "
                   f"{'the first' if s['invocations'] > 1 else 'it'} "
                   "found stages made by runs the record does not hold, so this is less than the cost from an "
                   "empty folder")
    if s.get("unfinished"):
        resumed += f"; {s['unfinished']} of them interrupted"
    if s.get("other_configs"):
        resumed += f"; some under config {', '.join(f'`{c}`' for c in s['other_configs'])}, sharing its cache"
    origin = " from an empty folder" if s.get("from_empty", True) else ""
    command = f"synthleak report STUDY_DIR --docs docs/results/{s['name']}.md"
    parts = [
        f"# Results: `{s['name']}`\n",
        f"<!-- Generated by `{command}` from the study's own folder; do not edit by hand: rerun the study "
        f"(`synthleak study {s['config']} --out STUDY_DIR`) and the command. -->\n",
        f"{s['description']}\n",
        markdown_table([
            {"": "config", " ": f"`{s['config']}`, content key `{s['config_key']}`"},
            {"": "source", " ": f"synthleak {s['version']}, commit `{s['commit'] or 'unknown'}`"},
            {"": "machine", " ": f"{s['cpu']}, {s['cores']} cores, {s['workers']} workers"},
            {"": "wall time", " ": f"{s['wall_s'] / 60:.1f} min{origin}{resumed} (minutes: {minutes})"},
            {"": "made", " ": s["date"]},
            {"": "world", " ": f"{s['rooms']} rooms, {s['pairs']} (room, object) pairs; {s['renderer']} "
                               f"{s['resolution']}; tiers {', '.join(s['tiers'])}"},
            {"": "captures", " ": ", ".join(f"{k} `{v}` (light `{s.get('lighting', {}).get(k, 'same')}`)"
                                            for k, v in s.get("capture", {}).items()) or "ideal renders"},
        ], ["", " "]),
        *(["## Tier ordering beside the paper's (Table 1)\n", s["tier_ordering"]] if s.get("tier_ordering") else []),
        f"## Presence and placement at {HEADLINE[0]:g}°/{HEADLINE[1]:g} m (`{s['aligner']}`, "
        f"{PRESENCE_RULES.get(s['presence'], s['presence'])})\n",
        "Precision / recall of the presence decision over (room, object) pairs; placement success: GT-present "
        "pairs placed within the same thresholds (unplaced pairs fail); median errors over the GT-present "
        "pairs; attacker queries localized over present / absent pairs.\n",
        markdown_table(_none_as_nan(s["headline"]), HEADLINE_COLUMNS, digits=3),
        "## Every aligner and threshold pair\n",
        markdown_table(_none_as_nan(s["thresholds"]), ["tier", "aligner", "thresholds", "precision", "recall",
                                                       "placement_success"], digits=2),
        "## Genuine queries (held-out frames) localized\n",
        markdown_table(s["genuine"], ["tier", "queries", "localized", "closeups", "closeups_localized"]),
    ]
    if s.get("servers"):
        parts += ["## Utility and leakage per server\n",
                  "Genuine queries localized and their median error beside the attacker queries localized, presence "
                  "P/R and placement success (first threshold pair), per server (tier, profile, map "
                  "representation).\n",
                  markdown_table(_none_as_nan(s["servers"]), [c for c in SERVER_COLUMNS if c in s["servers"][0]],
                                 digits=3)]
    if s.get("shell"):
        parts += ["## Attacker queries localized on the room's shell\n",
                  "Localized attacker queries with most PnP inliers on the room's shell (chance background "
                  "matches; target under 10 %), over present / absent pairs.\n",
                  markdown_table(_none_as_nan(s["shell"]), list(s["shell"][0]), digits=2)]
    if s["defense"]:
        parts += ["## Defense trade-off (pooled over tiers)\n",
                  "`min_fraction` X and `min_instances` k of the paper's defense; shares of the localized queries.\n",
                  markdown_table(s["defense"], list(s["defense"][0]), digits=2)]
    if s["world"]:
        parts += ["## The world\n",
                  "Coverage: share of a walk-through frame's pixels on furniture and props (GT masks).\n",
                  markdown_table(_none_as_nan(s["world"]), list(s["world"][0]), digits=2)]
    if s["plots"]:
        parts += ["## Plots\n", "\n".join(f"![{Path(p).stem}]({s['name']}/{p})" for p in s["plots"]) + "\n"]
    return "\n".join(parts)


def _copy_figures(study: Path, folder: Path) -> list[str]:
    """Copy the page's plots and contact sheets of the first room and the first attacker orbit into ``folder``;
    their names."""
    from synthleak.inspect import contact_sheet

    folder.mkdir(parents=True, exist_ok=True)
    names = []
    rooms = sorted((study / "dataset" / "scenes").glob("*/"))
    if rooms:
        contact_sheet(rooms[0], folder / "contact_sheet.png", frames=3)
        names.append("contact_sheet.png")
    attackers = sorted((study / "dataset" / "attackers").glob("*/"))
    if attackers:  # a photographed study: its rows put each kind of capture's render beside its photo
        contact_sheet(attackers[0], folder / "contact_sheet_attacker.png", frames=2)
        names.append("contact_sheet_attacker.png")
    plots = study / "plots"
    topdown = sorted(plots.glob("*_topdown.png"))[:1]
    for path in [*(plots / p for p in PLOTS), *topdown]:
        if path.is_file():
            shutil.copyfile(path, folder / path.name)
            names.append(path.name)
    return names


def write_results_page(study: Path, page: Path, name: str | None = None) -> Path:
    """Write ``page`` (markdown), its summary ``page.with_suffix('.json')`` and its figures (``page``'s stem
    folder) from the finished study ``study``; record the preset in ``index.json`` beside the page."""
    page = Path(page)
    summary = results_summary(study, name or page.stem)
    summary["plots"] = _copy_figures(Path(study), page.parent / summary["name"])
    atomic_write_text(page.with_suffix(".json"), json.dumps(summary, indent=1, ensure_ascii=False) + "\n")
    atomic_write_text(page, render_page(summary))
    _update_index(page.parent / "index.json", summary, page.name)
    return page


def _update_index(index: Path, summary: Mapping[str, Any], page: str) -> None:
    data = json.loads(index.read_text()) if index.is_file() else {"presets": {}}
    data["presets"][summary["config"]] = {"wall_s": summary["wall_s"], "cpu": summary["cpu"],
                                          "cores": summary["cores"], "commit": summary["commit"],
                                          "config_key": summary["config_key"],
                                          "from_empty": summary.get("from_empty", True),
                                          "page": f"docs/results/{page}"}
    data["presets"] = dict(sorted(data["presets"].items()))
    atomic_write_text(index, json.dumps(data, indent=1, ensure_ascii=False) + "\n")


PRESETS_BEGIN = "<!-- presets:begin"
PRESETS_END = "<!-- presets:end -->"
"""The markers of the README's generated presets table (:func:`write_readme_presets`)."""

NOT_PRESETS = ("study",)
"""Configs that only others extend: left out of the README's table."""


def presets_markdown(index: Path | None = None, folder: Path | None = None) -> str:
    """The README's presets table: each config of ``render_configs/`` (what it is for, its scale), its measured
    wall time and its results page from ``index`` (``docs/results/index.json``, written by
    :func:`write_results_page`)."""
    from synthleak.config import list_presets, load_config

    lines = ["| preset | what it is for | scale | measured wall time | results |", "|---|---|---|---|---|"]
    for preset in list_presets(index, folder):
        if preset.name in NOT_PRESETS or preset.error:
            continue
        config = load_config(preset.path)
        scale = (f"{config.scenes.rooms} rooms, {config.render.width}x{config.render.height}, "
                 f"{len(config.localize.tiers)} tier{'s' if len(config.localize.tiers) > 1 else ''}")
        for axis in ("profile", "representation"):
            values = as_list(getattr(config.localize, axis))
            if len(values) > 1:
                scale += f" x {len(values)} {axis}s"
        if config.localize.servers:  # a subset of that span
            scale += f", {len(config.localize.servers)} servers"
        cost = preset.cost
        wall = f"{cost}, {_short_cpu(cost.cpu)}" if cost else "not measured"
        page = f"[{Path(cost.page).name}]({cost.page})" if cost and cost.page else "–"
        lines.append(f"| `{preset.name}` | {preset.description} | {scale} | {wall} | {page} |")
    return "\n".join(lines) + "\n"


def _short_cpu(cpu: str) -> str:
    """``Intel(R) Xeon(R) Processor, AVX-512`` from :func:`synthleak.provenance.cpu_model`'s longer text."""
    name, _, rest = cpu.partition(" (")
    simd = rest.rstrip(")").partition("; ")[2].split(", ")[0]
    return f"{name}, {simd}" if simd else name


def write_readme_presets(readme: Path, index: Path | None = None) -> Path:
    """Replace the block between the presets markers of ``readme`` by :func:`presets_markdown`."""
    text = Path(readme).read_text()
    start, end = text.find(PRESETS_BEGIN), text.find(PRESETS_END)
    if start < 0 or end < start:
        raise ValueError(f"{readme}: no '{PRESETS_BEGIN} ...' / '{PRESETS_END}' markers for the presets table")
    head = text[:text.index("\n", start) + 1]
    atomic_write_text(Path(readme), head + presets_markdown(index) + text[end:])
    return Path(readme)
