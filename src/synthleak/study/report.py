"""The report stage: ``report.md`` with the paper-shaped tables, placement and defense figures, and the plots."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

from synthleak.atomic_io import atomic_write_text
from synthleak.attack.local_poses import sfm_model
from synthleak.cache import cache_key, is_done
from synthleak.config import config_to_dict
from synthleak.core.dataset import load_sequence, read_index
from synthleak.evaluate.defense_online import holds_decisions, report_section
from synthleak.evaluate.defense_sweep import defense_tradeoff
from synthleak.evaluate.genuine import genuine_localization
from synthleak.evaluate.plots import plot_defense_tradeoff, plot_placement_cdfs, plot_presence_pr
from synthleak.evaluate.query_log import defense_queries, read_query_log
from synthleak.evaluate.room_plots import room_plots
from synthleak.evaluate.server_summary import plot_utility_vs_leakage, server_rows, server_summary_markdown
from synthleak.evaluate.study_report import report_markdown, side_by_side_sections, sweep_section, world_sweep_section
from synthleak.evaluate.tables import plain, presence_pr_per_room
from synthleak.evaluate.world_summary import world_summary
from synthleak.study.attack import attack_rows
from synthleak.study.context import Stage, StudyContext, Unit


class ReportStage(Stage):
    """``report.md``, its plots and the summaries in ``results/`` (world, genuine queries, defense trade-off, the
    defense online). Keyed by the whole config and the content keys of every output before it (sweep points
    included); the wall-time table is the run's that made the report."""

    name = "report"
    reads = ("attack", "sweep", "world-sweep")

    def units(self, ctx: StudyContext) -> list[Unit]:
        return [Unit(ctx.paths.plots, cache_key("report", config_to_dict(ctx.config), ctx.keys))]

    def is_current(self, ctx: StudyContext, unit: Unit) -> bool:
        return is_done(unit.folder, unit.key) and ctx.paths.report.is_file()

    def make(self, ctx: StudyContext, todo: list[Unit]) -> Path:
        if todo:
            write_report(ctx, ctx.outputs["attack"], ctx.outputs.get("sweep") or [],
                         ctx.outputs.get("world-sweep") or [])
        return ctx.paths.report


def write_report(ctx: StudyContext, rows: list[dict[str, Any]], sweep_rows: list[dict[str, Any]],
                 world_rows: list[dict[str, Any]]) -> Path:
    """Write ``report.md`` (and what it shows) from the attack's rows and the sweeps' rows."""
    config, paths, logs = ctx.config, ctx.paths, ctx.logs()
    paths.plots.mkdir(parents=True, exist_ok=True)
    index = read_index(paths.dataset / "stages")
    scenes = {room["name"]: paths.scene(room["name"]) for room in index["rooms"]}
    world = world_summary(config, index["rooms"], scenes)
    atomic_write_text(paths.results / "world.json", json.dumps(plain(world), indent=1))
    genuine = genuine_localization(logs, scenes)
    tradeoff = defense_tradeoff(defense_queries(logs), config.defense.sweep_fractions,
                                config.defense.sweep_min_instances)
    atomic_write_text(paths.results / "genuine_localization.json", json.dumps(plain(genuine), indent=1))
    atomic_write_text(paths.results / "defense_tradeoff.json", json.dumps(plain(tradeoff), indent=1, default=str))
    policy = (config.defense.min_fraction, config.defense.min_instances)
    servers = server_rows(genuine, rows, tradeoff, config.attack.thresholds[0], policy)
    atomic_write_text(paths.results / "servers.json", json.dumps(plain(servers), indent=1))
    plots = [plot_presence_pr(presence_pr_per_room(rows), paths.plots / "presence_pr.png"),
             plot_placement_cdfs(rows, paths.plots / "placement_cdf.png"),
             plot_defense_tradeoff(tradeoff, paths.plots / "defense_tradeoff.png"),
             plot_utility_vs_leakage(servers, tradeoff, paths.plots / "utility_vs_leakage.png"),
             *room_plots(config, index["rooms"], scenes, rows, paths.plots)]
    attack_sections = [*server_section(servers, config.attack.thresholds[0], policy),
                       *_side_by_side(ctx, rows, logs), *_defense_online(ctx, rows, logs)]
    sweep_sections = [*sweep_section(sweep_rows, paths.plots, plots),
                      *world_sweep_section(config, world_rows, paths.plots, plots)]
    atomic_write_text(paths.report, report_markdown(config, index, world, genuine, rows, tradeoff, plots,
                                                    attack_sections, sweep_sections, ctx.timings))
    return paths.report


def server_section(servers: list[dict[str, Any]], thresholds: Any, policy: tuple[float, int]) -> list[str]:
    """"Utility and leakage per server" (every server of the study: tiers x profiles x representations)."""
    return ["## Utility and leakage per server (tier, profile, map representation)\n",
            server_summary_markdown(servers, tuple(thresholds), policy)]


def _side_by_side(ctx: StudyContext, rows: list[dict[str, Any]], logs: dict[tuple[str, str], Path]) -> list[str]:
    """The aligners on the same queries; with an SfM local model, oracle vs SfM on the same queries."""
    config, paths = ctx.config, ctx.paths
    if config.attack.local_model != "sfm":
        return side_by_side_sections(config, rows)
    oracle = attack_rows(dataclasses.replace(config, attack=dataclasses.replace(config.attack, local_model="oracle")),
                         paths, logs)
    models = {o["id"]: sfm_model(load_sequence(paths.attacker(o["id"])), paths.sfm_dir(o["id"]), config.seed)
              for o in read_index(paths.dataset / "stages")["attacker_objects"]}
    return side_by_side_sections(config, rows, oracle, models)


def _defense_online(ctx: StudyContext, rows: list[dict[str, Any]], logs: dict[tuple[str, str], Path]) -> list[str]:
    """Report lines for the defense online: the attack with and without it on the same queries."""
    config = ctx.config
    if not config.defense.enabled:
        return []
    records = [q for _, log in sorted(logs.items()) for q in read_query_log(log)]
    without = attack_rows(config, ctx.paths, logs, undefended=True) if holds_decisions(records) else None
    return report_section(config.defense, records, without, rows, config.attack.thresholds, ctx.paths.results)
