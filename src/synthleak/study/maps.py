"""The maps stage: one localization map per (tier, room) server, built in parallel."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from synthleak.cache import cache_key
from synthleak.config import config_to_dict
from synthleak.localize.mapping import build_map
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.tiers import tier_weights


def build_map_task(task: tuple[Path, str, Path, Any]) -> Path:
    """One (tier, room) map (a worker task; ``build_map`` is single threaded and deterministic)."""
    sequence_dir, tier, out, localize = task
    return build_map(sequence_dir, tier, out, localize, progress=False)


class MapsStage(Stage):
    """A map depends on the renders, its tier (a learned tier's definition and weights; any tier's effective
    definition under a server profile other than ``strict``) and the localize settings, not on the other tiers."""

    name = "maps"

    def units(self, ctx: StudyContext) -> list[Unit]:
        render_key = ctx.render_key
        units = []
        for (name, room), folder in ctx.servers().items():
            server = ctx.server(name)
            localize = {k: v for k, v in config_to_dict(server.localize(ctx.config.localize)).items()
                        if k != "tiers"}  # this server's own profile: a profile added beside it rebuilds nothing
            units.append(Unit(folder, cache_key("map", render_key, server.tier, localize,
                                                *tier_weights(server.tier, server.profile)), (name, room)))
        return units

    def make(self, ctx: StudyContext, todo: list[Unit]) -> None:
        if self.name in ctx.force:
            for unit in todo:
                (unit.folder / "map.json").unlink(missing_ok=True)  # build_map reuses a matching map otherwise
        tasks = [(ctx.paths.scene(room), server.tier, unit.folder, server.localize(ctx.config.localize))
                 for unit in todo for name, room in [unit.item] for server in [ctx.server(name)]]
        ctx.executor.map(build_map_task, tasks, "maps", ctx.progress)
