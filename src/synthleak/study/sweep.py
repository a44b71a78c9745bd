"""The sweeps: leakage against attacker dissimilarity (``sweep``: attacker objects re-made at each variant
magnitude, sent to the study's own servers) and against the hard-world knobs (``world-sweep``: a whole study per
value). Both run the study's own stages on each point's folder (``sweep/<point>/``)."""

from __future__ import annotations

import dataclasses
import shutil
from typing import Any

from synthleak.cache import cache_key
from synthleak.config import SweepConfig
from synthleak.core.dataset import read_index
from synthleak.evaluate.tables import write_results
from synthleak.render.pipeline import SequenceJob, render_sequences
from synthleak.scene.generate import write_study_stages
from synthleak.study.attack import attack_rows
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.features import FeaturesStage
from synthleak.study.local_models import SfmStage
from synthleak.study.maps import MapsStage
from synthleak.study.options import SWEEP_KINDS
from synthleak.study.queries import QueriesStage
from synthleak.study.render import RenderStage


class AttackerRenderStage(Stage):
    """A variant-sweep point's attacker objects, re-made with ``kinds`` at ``magnitude`` and rendered; the rooms'
    stages are copied from the study (byte-identical), only the attackers are rewritten."""

    name = "render"

    def __init__(self, kinds: list[str], magnitude: float) -> None:
        self.kinds, self.magnitude = kinds, magnitude

    def units(self, ctx: StudyContext) -> list[Unit]:
        return [Unit(ctx.paths.dataset, cache_key("sweep-render", ctx.render_key, self.kinds, self.magnitude))]

    def make(self, ctx: StudyContext, todo: list[Unit]) -> None:
        if not todo:
            return
        stages = ctx.paths.stages
        if not stages.exists():  # rooms are byte-identical: start from them, rewrite attackers only
            shutil.copytree(ctx.paths.rooms.stages, stages)
        write_study_stages(ctx.config, stages, attacker_magnitude=self.magnitude, attacker_kinds=self.kinds,
                           progress=ctx.progress)
        jobs = [SequenceJob(stages / obj["stage"], ctx.paths.attacker(obj["id"]), "attacker")
                for obj in read_index(ctx.paths.dataset / "stages")["attacker_objects"]]
        render_sequences(jobs, ctx.config, ctx.executor, ctx.progress)


class SweepStage(Stage):
    """Leakage against dissimilarity: at each (kind, magnitude) of ``[sweep]``, the attacker-side stages (render
    the re-made attackers, features, queries to the study's servers) and the attack; rooms, their renders and
    maps are the study's. Rows (tagged ``kind``, ``magnitude``) in ``results/sweep.{csv,json}``; the points'
    stages are cached as the study's, ``--force sweep`` redoes them all."""

    name = "sweep"

    def make(self, ctx: StudyContext, todo: list[Unit]) -> list[dict[str, Any]]:
        features = [FeaturesStage()] if ctx.server_url is None else []  # a remote server is sent the images
        stages = [*features, SfmStage(), QueriesStage()]
        rows: list[dict[str, Any]] = []
        for kind in ctx.config.sweep.kinds:
            if kind not in SWEEP_KINDS:
                raise ValueError(f"sweep.kinds: unknown kind {kind!r} (allowed: {', '.join(SWEEP_KINDS)})")
            kinds = list(ctx.config.scenes.attacker_variant_kinds) if kind == "all" else [kind]
            for magnitude in ctx.config.sweep.magnitudes:
                render = AttackerRenderStage(kinds, magnitude)
                point = ctx.point(ctx.paths.sweep_point(f"{kind}-{magnitude:g}", attacker_only=True),
                                  force=_names([render, *stages]) if self.name in ctx.force else frozenset())
                for stage in (render, *stages):
                    point.outputs[stage.name] = stage.run(point)
                rows += attack_rows(point.config, point.paths, point.outputs["queries"], magnitude, kind)
        if rows:
            write_results(rows, ctx.paths.results, stem="sweep")
        return rows


class WorldSweepStage(Stage):
    """Leakage against the hard-world knobs: for each value of ``[sweep] material_sharing`` / ``clutter``, the
    whole study (render, maps, features, queries stages, then the attack) with that value under
    ``sweep/<knob>-<value>/``, each stage cached as in the study; ``--force world-sweep`` redoes them all. Rows
    (tagged ``sweep_param``, ``sweep_value``) in ``results/sweep_world.{csv,json}``."""

    name = "world-sweep"
    label = "world sweep"

    def make(self, ctx: StudyContext, todo: list[Unit]) -> list[dict[str, Any]]:
        config = ctx.config
        points = [(param, float(v)) for param in ("material_sharing", "clutter") for v in getattr(config.sweep, param)]
        if points and ctx.server_url:
            raise ValueError("sweep.material_sharing / sweep.clutter build a map per value: they need the "
                             "in-process server (drop --server)")
        stages = [RenderStage(), MapsStage(), FeaturesStage(), SfmStage(), QueriesStage()]
        rows: list[dict[str, Any]] = []
        for param, value in points:
            sub = dataclasses.replace(config, scenes=dataclasses.replace(config.scenes, **{param: value}),
                                      sweep=SweepConfig())
            point = ctx.point(ctx.paths.sweep_point(f"{param}-{value:g}"), sub,
                              force=_names(stages) if self.name in ctx.force else frozenset())
            for stage in stages:
                point.outputs[stage.name] = stage.run(point)
            rows += [r | {"sweep_param": param, "sweep_value": value}
                     for r in attack_rows(sub, point.paths, point.outputs["queries"])]
        if rows:
            write_results(rows, ctx.paths.results, stem="sweep_world")
        return rows


def _names(stages: list[Stage]) -> frozenset[str]:
    return frozenset(stage.name for stage in stages)
