"""The maps stage: one localization map per (tier, room) server, built in parallel."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from synthleak.cache import cache_key
from synthleak.config import config_to_dict
from synthleak.localize.mapping import build_maps
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.tiers import tier_weights

MAP_SETTINGS = ("profile", "representation", "max_keypoints", "pairs_per_image", "bow_branching", "bow_depth")
"""The ``[localize]`` settings a map is built from (its content key); the others (retrieval, top k, the PnP
threshold, min inliers, two-view verification) are query-time settings: a change redoes the queries only."""


def build_maps_task(task: tuple[Path, str, list[tuple[Path, Any]]]) -> list[Path]:
    """The maps of one (tier, room): each of the tier's servers' (a worker task; ``build_maps`` is single threaded
    and deterministic, and extracts the frames' features and scores each pair once for all of them)."""
    sequence_dir, tier, maps = task
    return build_maps(sequence_dir, tier, maps, progress=False)


class MapsStage(Stage):
    """A map depends on the renders, its tier (a learned tier's definition and weights; any tier's effective
    definition under a server profile other than ``strict``) and the settings it is built from
    (:data:`MAP_SETTINGS`), not on the other tiers. The maps of one (tier, room) are built by one task."""

    name = "maps"

    def units(self, ctx: StudyContext) -> list[Unit]:
        render_key = ctx.render_key
        units = []
        for (name, room), folder in ctx.servers().items():
            server = ctx.server(name)
            settings = config_to_dict(server.localize(ctx.config.localize))
            localize = {k: v for k, v in settings.items() if k in MAP_SETTINGS}  # this server's own: a profile beside
            # it rebuilds nothing
            units.append(Unit(folder, cache_key("map", render_key, server.tier, localize,
                                                *tier_weights(server.tier, server.profile)), (name, room)))
        return units

    def make(self, ctx: StudyContext, todo: list[Unit]) -> None:
        if self.name in ctx.force:
            for unit in todo:
                (unit.folder / "map.json").unlink(missing_ok=True)  # build_map reuses a matching map otherwise
        groups: dict[tuple[str, str], list[tuple[Path, Any]]] = {}
        for unit in todo:
            name, room = unit.item
            server = ctx.server(name)
            groups.setdefault((server.tier, room), []).append((unit.folder, server.localize(ctx.config.localize)))
        tasks = [(ctx.paths.scene(room), tier, maps) for (tier, room), maps in groups.items()]
        ctx.executor.map(build_maps_task, tasks, "maps", ctx.progress)
