"""The queries stage: every planned image sent to each (tier, room) server, one JSON line per query."""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.atomic_io import atomic_write_text
from synthleak.cache import cache_key, done_key
from synthleak.config import StudyConfig, config_to_dict
from synthleak.evaluate.query_log import query_line
from synthleak.executors import chunks
from synthleak.localize.client import HttpLocalizer
from synthleak.localize.feature_files import load_features
from synthleak.localize.localizer import Localizer, with_image_size
from synthleak.localize.match_store import QueryMatches, read_matches, write_matches
from synthleak.localize.shared_matching import can_share, shared_pair_matches
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.plan import query_plans
from synthleak.study.workers import QUERIES_PER_TASK, clear_worker_cache, worker_cached


def make_localizer(map_dir: Path, config: StudyConfig | Any, server_url: str | None, defense: Any = None):
    """The study's server for one map: in process (running the ``defense`` policy if given) or over HTTP at
    ``server_url``, this map's service (the remote server applies its own policy; its server-side labels are
    asked for, ``?labels=1``, and logged when it gives them)."""
    if server_url:
        return HttpLocalizer(server_url, labels=True)
    localize = config.localize if isinstance(config, StudyConfig) else config
    return Localizer.load(map_dir, localize, defense=defense)


@dataclass
class QueryTarget:
    """One server of a :class:`QueryTask`: where its map is, how it answers, where its lines go."""

    map_dir: Path
    localize: Any
    server_url: str | None
    """This (server, room) pair's service URL (:meth:`StudyContext.server_urls`), or None: in process."""
    tier: str
    """The server's name (:mod:`synthleak.localize.servers`)."""
    part_file: Path
    """Where the task writes this server's lines when it is done (a stopped stage keeps them and resumes after
    them)."""
    matches_file: Path | None = None
    """In process: where this task's correspondences of this server are kept (:mod:`synthleak.localize.match_store`):
    read when they are there (pose estimation is replayed, nothing is matched), else written."""


@dataclass
class QueryTask:
    """Consecutive planned queries of one room, for one worker, sent to one server, or in process to several
    servers of one tier (each pair of a query and a map image is then scored once for all of them:
    :mod:`synthleak.localize.shared_matching`)."""

    targets: list[QueryTarget]
    room: str
    items: list[dict[str, Any]]
    """Plan entries plus ``_camera`` (the intrinsics) and ``_image`` (the image's path; sent to a server) or
    ``_features`` (its cached features; matched in process)."""
    defense: Any = None
    """The enabled :class:`~synthleak.localize.defense.DefensePolicy` the in-process server applies, or None."""


def _load_localizers(task: QueryTask) -> tuple[list[Any], bool]:
    localizers = [make_localizer(t.map_dir, t.localize, t.server_url, task.defense) for t in task.targets]
    in_process = all(t.server_url is None for t in task.targets)
    return localizers, in_process and can_share(localizers)


def query_task(task: QueryTask) -> int:
    """Localize each image of the task with each of its servers and write one JSON line per query and server,
    in the task's order, to the server's ``part_file`` (a worker task; the lines stay on disk rather than
    travel back to the driver). In process, a server's correspondences come from its ``matches_file`` when it is
    there, else they are matched (each pair scored once for the servers that match) and written to it. Returns
    the number of queries answered."""
    key = repr([(str(t.map_dir), done_key(t.map_dir), t.server_url, config_to_dict(t.localize))
                for t in task.targets] + [task.defense])
    localizers, shared = worker_cached(key, lambda: _load_localizers(task))
    if all(t.server_url is None for t in task.targets) and all("_features" in e for e in task.items):
        results = _answer_in_process(task, localizers, shared)
    else:
        results = [[localizer.localize(Path(entry["_image"]).read_bytes(), entry["_camera"])
                    for localizer in localizers] for entry in task.items]
    for j, target in enumerate(task.targets):
        lines = []
        for entry, answers in zip(task.items, results, strict=True):
            result = answers[j]
            remote = bool(target.server_url) and not getattr(result, "labelled", False)  # labelled: as in process
            lines.append(query_line(entry, target.tier, task.room, result, task.defense, remote=remote,
                                    served=bool(target.server_url)))
        atomic_write_text(target.part_file, "".join(line + "\n" for line in lines))
    return len(task.items) * len(task.targets)


def _answer_in_process(task: QueryTask, localizers: list[Localizer], shared: bool) -> list[list[Any]]:
    """Per query, each target's result from the query's cached features: cached correspondences replayed,
    the others matched (together where ``shared``) and then kept in the targets' matches files."""
    cached = [read_matches(t.matches_file) if t.matches_file is not None and t.matches_file.is_file() else None
              for t in task.targets]
    for t, kept in zip(task.targets, cached, strict=True):
        if kept is not None and len(kept) != len(task.items):
            raise ValueError(f"{t.matches_file}: matches of {len(kept)} queries, the task has {len(task.items)}")
    todo = [j for j, kept in enumerate(cached) if kept is None]
    made: list[list[QueryMatches]] = [[] for _ in task.targets]
    results = []
    for q, entry in enumerate(task.items):
        camera = entry["_camera"]
        features, size = load_features(Path(entry["_features"]))
        if size != (camera.width, camera.height):
            raise ValueError(f"{entry['_features']}: features of a {size[0]}x{size[1]} image but the camera "
                             f"is {camera.width}x{camera.height}")
        query = with_image_size(features, camera)
        matched: dict[int, QueryMatches] = {}
        if todo:
            locs = [localizers[j] for j in todo]
            candidates = [loc.candidates(query) if len(query) else np.zeros(0, np.int64) for loc in locs]
            pairs = shared_pair_matches(locs, query, candidates, shared) if len(query) else [[] for _ in locs]
            matched = {j: (c, m) for j, c, m in zip(todo, candidates, pairs, strict=True)}
        answers = []
        for j, loc in enumerate(localizers):
            candidates, pairs = matched[j] if j in matched else cached[j][q]
            if j in matched:
                made[j].append((candidates, pairs))
            answers.append(loc.localize_features(query, camera, candidates, pairs))
        results.append(answers)
    for j in todo:
        if task.targets[j].matches_file is not None:
            write_matches(task.targets[j].matches_file, made[j])
    return results


def parts_dir(unit: Unit) -> Path:
    """Where a server's finished tasks keep their lines until its whole log is written (one folder per key,
    so parts made from other inputs are never read)."""
    return unit.folder / f".parts-{unit.key[:16]}"


def _read_part(path: Path) -> list[str]:
    return path.read_text().splitlines()


class QueriesStage(Stage):
    """Each server's log ``queries/<tier>/<room>/queries.jsonl``, in plan order whatever the executor.

    In process, each image's cached features (the features stage) are matched against every room's map; with
    ``[defense] enabled`` the in-process server applies the policy to every query
    (:mod:`synthleak.evaluate.defense_online`). With a server URL the images themselves are sent.

    Each task of 50 queries writes its lines to the server's parts folder when it is done; a stage stopped
    part way (Ctrl-C, a crash, a lost node) resumes after the finished tasks (``--force queries`` redoes them).
    The log is written from the parts, in plan order, and the parts are then removed."""

    name = "queries"
    reads = ("maps", "features")

    def units(self, ctx: StudyContext) -> list[Unit]:
        policy = ctx.defense
        return [Unit(ctx.paths.query_dir(tier, room),
                     cache_key("queries", done_key(map_dir), done_key(ctx.paths.dataset), ctx.genuine,
                               ctx.config.attack.queries_per_object, ctx.server_url, self.settings(ctx, tier),
                               *([repr(policy)] if policy else [])), (tier, room))
                for (tier, room), map_dir in ctx.servers().items()]

    @staticmethod
    def settings(ctx: StudyContext, server: str) -> dict[str, Any]:
        """The ``[localize]`` settings server ``server`` answers with (its query-time settings among them: the
        map's key holds only what builds the map, :data:`synthleak.study.maps.MAP_SETTINGS`)."""
        localize = config_to_dict(ctx.server(server).localize(ctx.config.localize))
        return {k: v for k, v in localize.items() if k != "tiers"}

    @staticmethod
    def matching_key(ctx: StudyContext, server: str, room: str) -> str:
        """What a server's correspondences depend on: its map (the map's key names the tier, profile and what
        built it), the query features, the plan and the retrieval, not the acceptance rule or the PnP threshold
        (a change of those replays pose estimation on the kept correspondences)."""
        localize = QueriesStage.settings(ctx, server)
        return cache_key("matches", done_key(ctx.paths.map_dir(server, room)), done_key(ctx.paths.dataset),
                         ctx.genuine, ctx.config.attack.queries_per_object,
                         {k: localize.get(k) for k in ("retrieval", "top_k", "max_keypoints")})

    def make(self, ctx: StudyContext, todo: list[Unit]) -> dict[tuple[str, str], Path]:
        """Returns every server's log (made now or before). In process, the servers of one tier and room share
        their tasks (one task answers a chunk of queries for each of them) and each server keeps its
        correspondences (``.matches-<key>/``, :meth:`matching_key`) beside its log for later replays."""
        plans = query_plans(ctx) if todo else {}
        urls = ctx.server_urls() if todo else {}
        part_files, match_files = [], {}
        groups: dict[tuple[str, ...], list[tuple[Unit, list[Path]]]] = {}
        for unit in todo:
            tier, room = unit.item
            folder = parts_dir(unit)
            matches = unit.folder / f".matches-{self.matching_key(ctx, tier, room)[:16]}"
            for stale in [*unit.folder.glob(".parts-*"), *unit.folder.glob(".matches-*")] if unit.folder.is_dir() \
                    else []:
                if stale not in (folder, matches) or self.name in ctx.force:
                    shutil.rmtree(stale)
            folder.mkdir(parents=True, exist_ok=True)
            count = len(chunks(plans[room], QUERIES_PER_TASK))
            files = [folder / f"{i:05d}.jsonl" for i in range(count)]
            part_files.append(files)
            if ctx.server_url is None:
                matches.mkdir(parents=True, exist_ok=True)
                match_files[unit.item] = [matches / f"{i:05d}.npz" for i in range(count)]
            server = ctx.server(tier)
            # in process, a tier's servers of one profile (its map representations) share a task: their maps give
            # the same keypoints a point, so each pair is scored once; other servers (profiles) get tasks of their
            # own, which keeps the tasks small enough to balance the workers. Over HTTP: a server alone.
            group = (server.tier, server.profile, room) if ctx.server_url is None else (tier, room)
            groups.setdefault(group, []).append((unit, files))
        tasks = []
        for (*_, room), members in groups.items():
            plan = [dict(item) for item in plans[room]]
            if ctx.server_url is None:
                tier = ctx.server(members[0][0].item[0]).tier
                for item in plan:
                    item["_features"] = str(ctx.paths.features_file(tier, item["sequence"], item["frame"]))
                    del item["_image"]
            for c, items in enumerate(chunks(plan, QUERIES_PER_TASK)):
                targets = [QueryTarget(ctx.paths.map_dir(*unit.item), ctx.server(unit.item[0]).localize(
                    ctx.config.localize), urls.get(unit.item), unit.item[0], files[c],
                    match_files[unit.item][c] if unit.item in match_files else None)
                           for unit, files in members if not files[c].is_file()]
                if targets:
                    tasks.append(QueryTask(targets, room, items, None if ctx.server_url else ctx.defense))
        ctx.executor.map(query_task, tasks, "queries", ctx.progress)
        clear_worker_cache()
        for unit, files in zip(todo, part_files, strict=True):
            lines = [line for part in files for line in _read_part(part)]
            atomic_write_text(ctx.paths.query_log(*unit.item), "\n".join(lines) + "\n")
            shutil.rmtree(parts_dir(unit))  # after the log: a crash in between leaves parts to resume from
        return ctx.logs()
