"""The markdown of a study's ``report.md``: the paper-shaped tables, the funnels, the placement and defense
figures, the sweeps and the plots, from what the study computed."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from synthleak.evaluate.absent_pairs import absent_funnel_markdown, presence_by_absent_kind_markdown
from synthleak.evaluate.compare import side_by_side_markdown
from synthleak.evaluate.paper_reference import PRESENCE_RULES, tier_ordering_markdown
from synthleak.evaluate.plots import leakage_vs_magnitude, plot_leakage_vs_magnitude, plot_leakage_vs_world
from synthleak.evaluate.sfm_summary import sfm_objects_markdown
from synthleak.evaluate.shell_share import shell_share_markdown
from synthleak.evaluate.tables import (
    markdown_table,
    placement_summary,
    presence_rules_markdown,
    recall_funnel_markdown,
    table1_markdown,
    table2_markdown,
)
from synthleak.evaluate.world_summary import world_markdown
from synthleak.evaluate.world_sweep import leakage_vs_world
from synthleak.localize.servers import study_servers


def world_sweep_section(config: Any, rows: list[dict[str, Any]], plots_dir: Path, plots: list[Path]) -> list[str]:
    """Report lines for the material-sharing / clutter sweeps (and their plot appended to ``plots``)."""
    if not rows:
        return []
    aligner = config.attack.aligners[0]
    thresholds = config.attack.thresholds[len(config.attack.thresholds) // 2]
    plots.append(plot_leakage_vs_world(rows, plots_dir / "leakage_vs_world.png", aligner, thresholds))
    stats = [s for s in leakage_vs_world(rows) if s["aligner"] == aligner
             and (s["delta_r_deg"], s["delta_t_m"]) == tuple(thresholds)]
    columns = ["sweep_param", "sweep_value", "tier", "precision", "recall", "tp", "fp", "n_pairs"]
    return ["## Leakage against the hard-world knobs (material sharing, clutter)\n",
            f"A whole study per value (rooms, maps and attackers re-made); presence P/R with `{aligner}` at "
            f"{thresholds[0]:g}°/{thresholds[1]:g} m.\n",
            markdown_table(stats, columns)]


def sweep_section(sweep_rows: list[dict[str, Any]], plots_dir: Path, plots: list[Path]) -> list[str]:
    """Report lines for the variant-magnitude sweep (and its plot appended to ``plots``)."""
    if not sweep_rows:
        return []
    plots.append(plot_leakage_vs_magnitude(sweep_rows, plots_dir / "leakage_vs_magnitude.png"))
    stats = leakage_vs_magnitude(sweep_rows)
    columns = ["tier", "aligner", "delta_r_deg", "delta_t_m", "kind", "magnitude", "precision", "recall",
               "placement_success", "n_pairs"]
    return ["## Leakage against dissimilarity (attacker variant magnitude sweep)\n",
            "Presence precision/recall and placement success at 30°/0.5 m for attacker objects made with "
            "growing variant magnitude (colour, scale, shape, each alone and together).\n",
            markdown_table(stats, columns)]


def side_by_side_sections(config: Any, rows: list[dict[str, Any]], oracle_rows: list[dict[str, Any]] | None = None,
                          sfm_models: Mapping[str, Any] | None = None) -> list[str]:
    """The aligners on the same queries; with an SfM local model, its models (``sfm_models``: object id -> model)
    and the attack with the oracle poses (``oracle_rows``) vs SfM on the same queries."""
    parts = []
    if len(config.attack.aligners) > 1:
        parts += ["## Aligners side by side (same queries)\n",
                  "Presence P/R; success: GT-present pairs placed within 10°/0.25 m (unplaced ones fail); medians "
                  "over the GT-present pairs every aligner placed (`common`).\n",
                  side_by_side_markdown({a: [r for r in rows if r["aligner"] == a] for a in config.attack.aligners},
                                        variant_label="aligner")]
    if config.attack.local_model == "sfm":
        parts += ["## Local model: SfM of the attacker's orbit\n",
                  "pycolmap incremental SfM per orbit, scaled by the object's known size. Scored against the GT "
                  "orbit: `misregistered` views lie off the LO-RANSAC Sim(3) onto the GT camera centres; "
                  "`seconds` is the build time (the `all` line: registered share, median |scale error|, total "
                  "seconds).\n",
                  sfm_objects_markdown(sfm_models or {}),
                  "## Local model: oracle vs SfM (same queries)\n",
                  "The same query logs attacked with the exact local poses (`oracle`) and the SfM ones (`sfm`); "
                  "views SfM did not register are left out of the SfM attack.\n",
                  side_by_side_markdown({"oracle": oracle_rows or [], "sfm": rows}, ("tier", "aligner",
                                                                                     "delta_r_deg", "delta_t_m"),
                                        variant_label="local model")]
    return parts


def report_markdown(config: Any, index: Mapping[str, Any], world: Mapping[str, Any], genuine: Sequence[dict],
                    rows: list[dict[str, Any]], tradeoff: Sequence[dict], plots: Sequence[Path],
                    attack_sections: Sequence[str], sweep_sections: Sequence[str], timings: Mapping[str, float]
                    ) -> str:
    """The whole ``report.md``. ``index``: the study plan; ``world``/``genuine``/``tradeoff``: the world summary,
    the genuine-query accuracy and the defense trade-off; ``attack_sections`` (side by side, defense online) and
    ``sweep_sections``: the optional sections, before and after the defense trade-off; ``plots``: every plot,
    linked at the end; ``timings``: seconds per stage."""
    n_present = sum(len(o.get("present_in", {})) for o in index["attacker_objects"])
    parts = [
        f"# synthleak study `{config.name}`\n",
        f"{config.description}\n",
        f"seed {config.seed}; {len(index['rooms'])} rooms; {len(index['attacker_objects'])} attacker objects; "
        f"{n_present} present (room, object) pairs of {len(index['rooms']) * len(index['attacker_objects'])}; "
        f"renderer {config.render.renderer} {config.render.width}x{config.render.height}; "
        f"servers {', '.join(s.name for s in study_servers(config.localize))}; "
        f"aligners {', '.join(config.attack.aligners)}; "
        f"local model {config.attack.local_model}; presence decided by the "
        f"{PRESENCE_RULES.get(config.attack.presence, config.attack.presence)} (`decision`).\n",
        *world_markdown(world),
        "## Genuine queries (held-out frames: walk-through and close-ups)\n",
        markdown_table(genuine, ["tier", "room", "n", "localized", "closeups", "closeups_localized",
                                 "median_rot_err_deg", "median_trans_err_m"]),
        "## Presence (paper Table 1 shape)\n",
        table1_markdown(rows),
        "## Tier ordering beside the paper's (Table 1)\n",
        tier_ordering_markdown(rows, presence=config.attack.presence),
        "## Presence per object (paper appendix table shape)\n",
        table2_markdown(rows),
        "## Where presence is lost (GT-present pairs, server side)\n",
        "Pairs, then their attacker queries step by step. *Retrieved images see the object*: a retrieved map "
        "image shows the room's instance on at least 0.5 % of its pixels (GT masks); a query lost before this "
        "step is the retrieval's miss, one lost between it and *queries localized* is matching's or PnP's "
        "(\"–\": unknown, e.g. a remote server). *On the object*: most PnP inliers on the room's instance.\n",
        recall_funnel_markdown(rows),
        "## Where false presence comes from (GT-absent pairs, server side)\n",
        "Absent pairs by what the room holds: an instance sharing a material SKU with the queried object "
        "(`shares_sku`), else one of its category (`same_category`), else neither (`unrelated`). "
        "*Localized on a look-alike*: a localized query has most PnP inliers on such an instance.\n",
        absent_funnel_markdown(rows),
        "## Attacker queries localized on the room's shell\n",
        "Localized attacker queries with most PnP inliers on the room's shell (floor, walls, ceiling, door, "
        "window backdrop): chance matches of the attacker's background to the room's, not the look-alike leak "
        "(`synthleak.evaluate.shell_share`; target under 10 %).\n",
        shell_share_markdown(rows),
        "## Presence by kind of absent pair\n",
        "False positives among the absent pairs of each kind, and the precision counting only that kind of "
        "absent pair (all present pairs).\n",
        presence_by_absent_kind_markdown(rows),
        presence_rules_markdown(rows, config.attack.presence),
        "## Placement against ground truth\n",
        placement_summary(rows, config.attack.thresholds),
        *attack_sections,
        "## Defense trade-off (paper Fig. 6, exact instance labels)\n",
        "Among the queries the server localizes: genuine queries kept (all, walk-through frames, close-ups of one "
        "object or a small group) and attacker queries rejected, pooled over tiers.\n",
        markdown_table([t for t in tradeoff if t.get("tier") == "all"],
                       [k for k in (tradeoff[0] if tradeoff else {}) if k != "tier"]),
        *sweep_sections,
        "## Plots\n",
        "\n".join(f"![{p.stem}](plots/{p.name})" for p in plots) + "\n",
        "## Wall time per stage (this run; cached stages take ~0 s)\n",
        markdown_table([{"stage": k, "seconds": v} for k, v in timings.items()], ["stage", "seconds"], 1),
    ]
    return "\n".join(parts)
