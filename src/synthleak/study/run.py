"""Run or resume a whole study: every stage in order over one context."""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from synthleak.atomic_io import atomic_write_text
from synthleak.config import StudyConfig, check_config
from synthleak.executors import Executor, make_executor
from synthleak.provenance import start_run, update_run
from synthleak.schema import as_list
from synthleak.study.attack import AttackStage
from synthleak.study.context import Stage, StudyContext
from synthleak.study.features import FeaturesStage
from synthleak.study.local_models import SfmStage
from synthleak.study.lock import study_lock
from synthleak.study.maps import MapsStage
from synthleak.study.paths import StudyPaths
from synthleak.study.queries import QueriesStage
from synthleak.study.render import RenderStage
from synthleak.study.report import ReportStage
from synthleak.study.sweep import SweepStage, WorldSweepStage
from synthleak.study.tiers import check_tiers_installed

STAGE_TYPES: tuple[type[Stage], ...] = (RenderStage, MapsStage, FeaturesStage, SfmStage, QueriesStage, AttackStage,
                                        SweepStage, WorldSweepStage, ReportStage)
"""A study's stages, in the order they run."""

STAGES = tuple(stage.name for stage in STAGE_TYPES)
"""Their names (``--force``)."""


def check_force(force: Sequence[str]) -> frozenset[str]:
    """The stage names of ``force``; a ValueError naming the unknown ones and the stages."""
    unknown = set(force) - set(STAGES)
    if unknown:
        raise ValueError(f"--force: unknown stage(s) {sorted(unknown)} (stages: {', '.join(STAGES)})")
    return frozenset(force)


def forced_stages(force: Sequence[str]) -> frozenset[str]:
    """The stages ``force`` redoes: the named ones and every stage that reads what they make (:attr:`Stage.reads`).
    A forced stage can give other bytes under an unchanged key (the code changed), so what reads them is redone
    too: ``--force maps`` redoes queries, attack and report. ``render`` forces nothing after it."""
    forced = set(check_force(force))
    for stage in STAGE_TYPES:  # in run order: one pass reaches every stage downstream
        if forced & set(stage.reads):
            forced.add(stage.name)
    return frozenset(forced)


def study_stages(ctx: StudyContext) -> list[Stage]:
    """The stages a study runs (no features stage against a remote server: it is sent the images)."""
    return [stage() for stage in STAGE_TYPES if not (stage is FeaturesStage and ctx.server_url is not None)]


def run_study(config: StudyConfig, out: Path, force: Sequence[str] = (), server_url: str | None = None,
              progress: bool = True, workers: int = 1, executor: str | Executor = "local",
              address: str | None = None) -> Path:
    """Run or resume every stage of a study; returns the report's path.

    Rendering, maps and queries run over ``executor``: ``"local"`` with ``workers`` processes, ``"ray"``
    (``address``: a running cluster, e.g. ``"auto"``; None starts a local Ray), or an
    :class:`~synthleak.executors.Executor`. Result files are the same bytes whatever the executor.

    One study at a time per folder: while this runs it holds ``out/.study.lock``, and another ``run_study``
    on ``out`` (any process) raises :class:`~synthleak.study.lock.StudyLockedError` at once. Interrupted
    (Ctrl-C, SIGTERM), it ends its workers; what was finished is kept, and a rerun resumes."""
    forced = forced_stages(force)
    check_config(config, config.name)  # a config built in Python fails here, not after the renders
    for profile in as_list(config.localize.profile):
        check_tiers_installed(config.localize.tiers, profile)
    if server_url is not None:  # before the renders: a wrong address fails now, not after them
        from synthleak.localize.client import check_reachable

        check_reachable(server_url)
    paths = StudyPaths(Path(out))
    paths.root.mkdir(parents=True, exist_ok=True)
    with study_lock(paths.root):  # before any worker starts: a second run is refused at once
        started = time.time()
        kind = executor if isinstance(executor, str) else type(executor).__name__
        index = start_run(paths.root, config, getattr(executor, "workers", workers), kind)

        def record(timings: dict[str, float], finished: bool = False) -> None:
            update_run(paths.root, index, started, timings, finished)

        if isinstance(executor, str):
            with make_executor(executor, workers, address) as pool:
                ctx = _run_stages(config, paths, forced, server_url, progress, pool, record)
        else:
            ctx = _run_stages(config, paths, forced, server_url, progress, executor, record)
        record(ctx.timings, finished=True)
        return ctx.outputs["report"]


def _run_stages(config: StudyConfig, paths: StudyPaths, forced: frozenset[str], server_url: str | None,
                progress: bool, executor: Executor,
                record: Callable[[dict[str, float]], None]) -> StudyContext:
    """Run the stages in order; after each (and when one is interrupted) ``record`` gets the stage seconds."""
    ctx = StudyContext(config, paths, forced, progress, executor, server_url)
    for stage in study_stages(ctx):
        start = time.perf_counter()
        try:
            ctx.outputs[stage.name] = stage.run(ctx)
        finally:  # an interrupted stage counts the time it ran
            ctx.timings[stage.timings_label()] = round(time.perf_counter() - start, 2)
            record(ctx.timings)
    atomic_write_text(paths.timings, json.dumps(ctx.timings, indent=1))
    return ctx
