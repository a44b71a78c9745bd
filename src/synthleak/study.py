"""`synthleak study`: stages -> renders -> maps -> queries -> attack -> scores -> report, resumable.

Every stage writes into its own folder under the study's output and records a content key
(:mod:`synthleak.cache`); a rerun skips stages whose inputs did not change, so changing a scoring
threshold re-runs only the attack and the report, and changing a tier does not re-render.
"""

from __future__ import annotations

import json
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.assets.mesh import VARIANT_KINDS
from synthleak.atomic_io import atomic_write_bytes, atomic_write_text
from synthleak.cache import cache_key, done_key, is_done, mark_done
from synthleak.config import StudyConfig, check_config, config_to_dict
from synthleak.executors import Executor, LocalExecutor

STAGES = ("render", "maps", "features", "queries", "attack", "report")


@dataclass
class StudyPaths:
    """Where each stage of a study writes."""

    root: Path

    @property
    def dataset(self) -> Path:
        return self.root / "dataset"

    @property
    def maps(self) -> Path:
        return self.root / "maps"

    @property
    def queries(self) -> Path:
        return self.root / "queries"

    @property
    def results(self) -> Path:
        return self.root / "results"

    @property
    def plots(self) -> Path:
        return self.root / "plots"

    @property
    def report(self) -> Path:
        return self.root / "report.md"


def _section(config: StudyConfig, name: str) -> dict[str, Any]:
    return config_to_dict(config)[name]


def _check_force(force: Sequence[str]) -> set[str]:
    unknown = set(force) - set(STAGES)
    if unknown:
        raise ValueError(f"--force: unknown stage(s) {sorted(unknown)} (stages: {', '.join(STAGES)})")
    return set(force)


def load_index(dataset: Path) -> dict[str, Any]:
    """The study plan written with the stages (rooms, attacker objects, presence)."""
    path = dataset / "stages" / "index.json"
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise FileNotFoundError(f"{path}: missing study index (run the render stage first)") from exc


# ----------------------------------------------------------------------------------------------- render
def stage_render(config: StudyConfig, paths: StudyPaths, force: set[str], progress: bool,
                 executor: Executor | None = None) -> str:
    """Stages and renders (the render pipeline resumes frame by frame by itself)."""
    from synthleak.render.pipeline import generate

    key = cache_key("render", config.seed, _section(config, "scenes"), _section(config, "render"))
    if "render" not in force and is_done(paths.dataset, key):
        return key
    old_key = done_key(paths.dataset)
    if old_key is not None and old_key != key:  # rendered with another config: keep it aside, never delete
        paths.dataset.rename(paths.root / f"dataset.{old_key[:12]}")
    generate(config, paths.dataset, progress=progress, executor=executor)
    mark_done(paths.dataset, key)
    return key


# ------------------------------------------------------------------------------------------------- maps
def _build_map_task(task: tuple[Path, str, Path, Any]) -> Path:
    """One (tier, room) map (a worker task; ``build_map`` is single threaded and deterministic)."""
    from synthleak.localize.mapping import build_map

    sequence_dir, tier, out, localize = task
    return build_map(sequence_dir, tier, out, localize, progress=False)


def _tier_weights(tier: str) -> list:
    """A learned tier's definition (matching thresholds, budget) and the sha256 of its weight files; nothing for
    the other tiers (their keys stay as they were)."""
    from dataclasses import asdict

    from synthleak.localize.tiers import get_tier

    spec = get_tier(tier)
    record = spec.weights_record()
    if not record:
        return []
    return [{"tier": asdict(spec), "weights": {name: entry["sha256"] for name, entry in sorted(record.items())}}]


def check_tiers_installed(tiers: Sequence[str]) -> None:
    """Fail before any rendering when a tier's packages (torch, kornia) or weight files are not installed; the
    error names the ``[learned]`` extra and the install command."""
    import importlib.util

    from synthleak.errors import MissingDependencyError
    from synthleak.localize.tiers import get_tier

    for tier in tiers:
        if not get_tier(tier).needs_torch:
            continue
        missing = [m for m in ("torch", "kornia") if importlib.util.find_spec(m) is None]
        if missing:
            from synthleak.localize.deep import EXTRA, INSTALL_HINT

            raise MissingDependencyError(f"localize.tiers: {tier!r} needs {', '.join(missing)} (the [{EXTRA}] "
                                         f"extra): {INSTALL_HINT}")
        _tier_weights(tier)  # a missing weight file raises WeightsNotFoundError naming the package


def _map_key(config: StudyConfig, render_key: str, tier: str) -> str:
    """A map depends on the renders, its tier (a learned tier's definition and weights) and the localize settings,
    not on the other tiers."""
    localize = {k: v for k, v in _section(config, "localize").items() if k != "tiers"}
    return cache_key("map", render_key, tier, localize, *_tier_weights(tier))


def stage_maps(config: StudyConfig, paths: StudyPaths, render_key: str, force: set[str], progress: bool,
               executor: Executor | None = None) -> dict[tuple[str, str], Path]:
    """One map per (tier, room), built in parallel over ``executor``."""
    index = load_index(paths.dataset)
    maps: dict[tuple[str, str], Path] = {}
    todo: list[tuple[Path, str, Path, Any]] = []
    keys: list[tuple[Path, str]] = []
    for tier in config.localize.tiers:
        for room in index["rooms"]:
            out = paths.maps / tier / room["name"]
            key = _map_key(config, render_key, tier)
            if "maps" in force or not is_done(out, key):
                if "maps" in force:
                    (out / "map.json").unlink(missing_ok=True)  # build_map reuses a matching map otherwise
                todo.append((paths.dataset / "scenes" / room["name"], tier, out, config.localize))
                keys.append((out, key))
            maps[(tier, room["name"])] = out
    (executor or LocalExecutor(1)).map(_build_map_task, todo, "maps", progress)
    for out, key in keys:
        mark_done(out, key)
    return maps


# ---------------------------------------------------------------------------------------------- queries
def _query_plan(config: StudyConfig, scene_dataset: Path, attacker_dataset: Path, room: str,
                genuine: bool = True) -> list[dict]:
    """Every image sent to one room's server: its genuine held-out frames and every attacker frame.

    ``sequence`` is the sequence folder relative to its dataset; ``dataset`` says which one."""
    from synthleak.core.dataset import load_sequence

    plan = []
    if genuine:
        scene = load_sequence(scene_dataset / "scenes" / room)
        closeups = set(scene.split.get("closeup", []))
        plan += [{"sequence": f"scenes/{room}", "frame": f, "genuine": True, "attacker_object": None}
                 | ({"closeup": f in closeups} if closeups else {}) for f in scene.split["query"]]
    for obj in load_index(attacker_dataset)["attacker_objects"]:
        seq = load_sequence(attacker_dataset / "attackers" / obj["id"])
        frames = seq.frames
        if 0 < config.attack.queries_per_object < len(frames):  # spread evenly around the orbit
            step = len(frames) / config.attack.queries_per_object
            frames = [frames[int(k * step)] for k in range(config.attack.queries_per_object)]
        plan += [{"sequence": f"attackers/{obj['id']}", "frame": f, "genuine": False,
                  "attacker_object": obj["id"]} for f in frames]
    return plan


QUERIES_PER_TASK = 50
"""Localization queries (or feature extractions) per worker task (a worker loads each map once and keeps it
for its next tasks)."""

_WORKER_CACHE: dict[str, Any] = {}
"""The localizer (or extractor) the last task in this process used (one map at a time, to bound memory)."""


def _make_localizer(map_dir: Path, config: StudyConfig | Any, server_url: str | None, defense: Any = None):
    """The study's server for one map: in process (running the ``defense`` policy if given) or over HTTP (the
    remote server applies its own policy)."""
    if server_url:
        from synthleak.localize.client import HttpLocalizer

        return HttpLocalizer(server_url)
    from synthleak.localize.localizer import Localizer

    localize = config.localize if isinstance(config, StudyConfig) else config
    return Localizer.load(map_dir, localize, defense=defense)


def _worker_cached(key: str, make):
    if _WORKER_CACHE.get("key") != key:
        _WORKER_CACHE.clear()
        _WORKER_CACHE.update(key=key, value=make())
    return _WORKER_CACHE["value"]


# --------------------------------------------------------------------------------------------- features
def _features_path(root: Path, tier: str, item: dict[str, Any]) -> Path:
    return root / tier / item["sequence"] / f"{item['frame']}.npz"


def save_features(path: Path, features: Any, image_size: tuple[int, int]) -> None:
    """One image's features as ``.npz`` (exact arrays), written atomically."""
    import io

    buffer = io.BytesIO()
    arrays = {"keypoints": features.keypoints, "descriptors": features.descriptors,
              "binary": np.array(features.binary), "image_size": np.array(image_size, np.int64)}
    if features.scores is not None:
        arrays["scores"] = features.scores
    np.savez(buffer, **arrays)
    atomic_write_bytes(path, buffer.getvalue())


def load_features(path: Path) -> tuple[Any, tuple[int, int]]:
    """``(Features, (width, height))`` of :func:`save_features`."""
    from synthleak.localize.features import Features

    with np.load(path) as z:
        scores = z["scores"] if "scores" in z.files else None
        size = tuple(int(v) for v in z["image_size"])
        return Features(z["keypoints"], z["descriptors"], bool(z["binary"]), scores, size), size


@dataclass
class FeatureTask:
    """Extract one tier's features of consecutive query images (``(image, out)`` paths), for one worker."""

    tier: str
    max_keypoints: int
    items: list[tuple[str, str]]


def feature_task(task: FeatureTask) -> int:
    """Extract and save the features of the task's images (a worker task; extraction is single threaded)."""
    from synthleak.localize.localizer import decode_image
    from synthleak.localize.tiers import get_tier

    extractor = _worker_cached(repr(("extractor", task.tier, task.max_keypoints)),
                               lambda: get_tier(task.tier).make_extractor(task.max_keypoints))
    for image, out in task.items:
        rgb = decode_image(Path(image).read_bytes())
        save_features(Path(out), extractor(rgb), (rgb.shape[1], rgb.shape[0]))
    return len(task.items)


def _query_plans(config: StudyConfig, paths: StudyPaths, maps: dict[tuple[str, str], Path],
                 attacker_dataset: Path, genuine: bool) -> dict[str, list[dict]]:
    """Each room's query plan, with ``_image`` (the image's path) and ``_camera`` (its intrinsics) added."""
    from synthleak.core.dataset import load_sequence

    sequences: dict[Path, Any] = {}
    plans = {}
    for room in sorted({room for _, room in maps}):
        plan = _query_plan(config, paths.dataset, attacker_dataset, room, genuine)
        for item in plan:
            folder = (paths.dataset if item["genuine"] else attacker_dataset) / item["sequence"]
            seq = sequences.get(folder) or sequences.setdefault(folder, load_sequence(folder))
            item |= {"_image": str(seq.image_path(item["frame"])), "_camera": seq.camera}
        plans[room] = plan
    return plans


def stage_features(config: StudyConfig, paths: StudyPaths, maps: dict[tuple[str, str], Path], force: set[str],
                   progress: bool, attacker_dataset: Path | None = None, out_root: Path | None = None,
                   executor: Executor | None = None) -> Path:
    """Every query image's features, once per tier (not once per room server it is sent to), cached under
    ``features/<tier>/<sequence>/<frame>.npz``; returns the features root."""
    from synthleak.executors import chunks

    genuine = attacker_dataset is None
    attacker_dataset = attacker_dataset or paths.dataset
    root = (out_root or paths.queries).parent / "features"
    plans: dict[str, list[dict]] | None = None
    tasks, marks = [], []
    for tier in sorted({tier for tier, _ in maps}):
        key = cache_key("features", done_key(paths.dataset), done_key(attacker_dataset), genuine, tier,
                        config.localize.max_keypoints, config.attack.queries_per_object, *_tier_weights(tier))
        if "features" not in force and is_done(root / tier, key):
            continue
        plans = plans or _query_plans(config, paths, maps, attacker_dataset, genuine)
        seen: dict[str, tuple[str, str]] = {}
        for plan in plans.values():
            for item in plan:
                seen.setdefault(item["_image"], (item["_image"], str(_features_path(root, tier, item))))
        items = [seen[k] for k in sorted(seen)]
        tasks += [FeatureTask(tier, config.localize.max_keypoints, c) for c in chunks(items, QUERIES_PER_TASK)]
        marks.append((root / tier, key))
    (executor or LocalExecutor(1)).map(feature_task, tasks, "features", progress)
    _WORKER_CACHE.clear()
    for folder, key in marks:
        mark_done(folder, key)
    return root


# ---------------------------------------------------------------------------------------------- queries
@dataclass
class QueryTask:
    """Consecutive planned queries of one (tier, room) server, for one worker."""

    map_dir: Path
    localize: Any
    server_url: str | None
    tier: str
    room: str
    items: list[dict[str, Any]]
    """Plan entries plus ``_camera`` (the intrinsics) and ``_image`` (the image's path; sent to a server) or
    ``_features`` (its cached features; matched in process)."""
    defense: Any = None
    """The enabled :class:`~synthleak.localize.defense.DefensePolicy` the in-process server applies, or None."""


def query_task(task: QueryTask) -> list[str]:
    """Localize each image of the task; one JSON line per query, in the task's order (a worker task)."""
    from synthleak.evaluate.defense_online import log_fields

    key = repr((str(task.map_dir), done_key(task.map_dir), task.server_url, config_to_dict(task.localize),
                task.defense))
    localizer = _worker_cached(key, lambda: _make_localizer(task.map_dir, task.localize, task.server_url,
                                                            task.defense))
    lines = []
    for entry in task.items:
        item = {k: v for k, v in entry.items() if not k.startswith("_")}
        camera = entry["_camera"]
        if "_features" in entry:
            features, size = load_features(Path(entry["_features"]))
            if size != (camera.width, camera.height):
                raise ValueError(f"{entry['_features']}: features of a {size[0]}x{size[1]} image but the camera "
                                 f"is {camera.width}x{camera.height}")
            result = localizer.localize_features(features, camera)
        else:
            result = localizer.localize(Path(entry["_image"]).read_bytes(), camera)
        pose = result.cam_from_world
        lines.append(json.dumps({
            **item, "tier": task.tier, "room": task.room, "success": bool(result.success),
            "cam_from_world": None if pose is None else np.asarray(pose).tolist(),
            "num_inliers": int(getattr(result, "num_inliers", 0) or 0),
            "inlier_instance_counts": {str(k): int(v) for k, v in
                                       sorted((getattr(result, "inlier_instance_counts", None) or {}).items())},
            **log_fields(result, task.defense),
            # the map images matched (in process only: an HTTP answer names none, the funnel step stays unknown)
            **({} if task.server_url else {"retrieved": list(result.retrieved)}),
        }, sort_keys=True))
    return lines


def stage_queries(config: StudyConfig, paths: StudyPaths, maps: dict[tuple[str, str], Path], force: set[str],
                  progress: bool, server_url: str | None = None, attacker_dataset: Path | None = None,
                  out_root: Path | None = None, executor: Executor | None = None) -> dict[tuple[str, str], Path]:
    """Send every planned image to each (tier, room) server; log one JSON line per query.

    By default the attacker images come from the study's dataset and genuine queries are included; a
    variant sweep passes its own ``attacker_dataset`` and ``out_root`` (attacker queries only). In process,
    each image's features are extracted once per tier (:func:`stage_features`) and matched against every
    room's map; queries run in chunks over ``executor``; each log is in plan order whatever the executor.
    With ``[defense] enabled`` the in-process server applies the policy to every query
    (:mod:`synthleak.evaluate.defense_online`)."""
    from synthleak.evaluate.defense_online import online_policy
    from synthleak.executors import chunks

    genuine = attacker_dataset is None
    attacker_dataset = attacker_dataset or paths.dataset
    out_root = out_root or paths.queries
    policy = online_policy(config.defense)
    logs: dict[tuple[str, str], Path] = {}
    todo: list[tuple[tuple[str, str], Path, str, int]] = []  # (tier, room), folder, key, number of tasks
    tasks: list[QueryTask] = []
    plans: dict[str, list[dict]] | None = None
    features_root: Path | None = None
    for (tier, room), map_dir in maps.items():
        out = out_root / tier / room
        key = cache_key("queries", done_key(map_dir), done_key(attacker_dataset), genuine,
                        config.attack.queries_per_object, server_url, *([repr(policy)] if policy else []))
        logs[(tier, room)] = out / "queries.jsonl"
        if "queries" not in force and is_done(out, key):
            continue
        plans = plans or _query_plans(config, paths, maps, attacker_dataset, genuine)
        if server_url is None and features_root is None:
            features_root = stage_features(config, paths, maps, force - {"features"}, progress,
                                           None if genuine else attacker_dataset, out_root, executor)
        plan = [dict(item) for item in plans[room]]
        if features_root is not None:
            for item in plan:
                item["_features"] = str(_features_path(features_root, tier, item))
                del item["_image"]
        parts = [QueryTask(map_dir, config.localize, server_url, tier, room, c, None if server_url else policy)
                 for c in chunks(plan, QUERIES_PER_TASK)]
        todo.append(((tier, room), out, key, len(parts)))
        tasks += parts
    results = iter((executor or LocalExecutor(1)).map(query_task, tasks, "queries", progress))
    _WORKER_CACHE.clear()
    for name, out, key, n_tasks in todo:
        lines = [line for _ in range(n_tasks) for line in next(results)]
        atomic_write_text(logs[name], "\n".join(lines) + "\n")
        mark_done(out, key)
    return logs


def read_query_log(path: Path) -> list[dict[str, Any]]:
    """The query records of one (tier, room)."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


# ----------------------------------------------------------------------------------------------- attack
LOCAL_MODELS = ("oracle", "sfm")
"""``attack.local_model``: the attacker's local poses from ground truth, or from pycolmap SfM."""


def _attacker_local_model(config: StudyConfig, sfm_root: Path, obj_id: str, seq: Any
                          ) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """The attacker's local poses (``cam_from_object`` / ``cam_from_local``) and, for SfM, the
    scoring-only ``object_from_local``."""
    from synthleak.attack.local_model import oracle_local_poses

    if config.attack.local_model == "oracle":
        return oracle_local_poses(seq), None
    if config.attack.local_model == "sfm":
        model = _sfm_model(config, sfm_root, obj_id, seq)
        return dict(model.cam_from_local), model.object_from_local
    raise ValueError(f"attack.local_model: unknown value {config.attack.local_model!r} ({', '.join(LOCAL_MODELS)})")


def _sfm_model(config: StudyConfig, sfm_root: Path, obj_id: str, seq: Any):
    """The attacker's SfM of its orbit (built once, then read from ``sfm_root/obj_id``)."""
    from synthleak.attack.local_model import cached_sfm_local_poses

    target = seq.objects_by_id()[seq.target_instance_id]
    return cached_sfm_local_poses(seq, target.extents, sfm_root / obj_id, seed=config.seed)


def _map_points_per_instance(map_dir: Path) -> dict[int, int] | None:
    """Number of the map's 3D points per instance id (``points_instance.json``), or None without a local map
    (a study against a remote server)."""
    path = map_dir / "points_instance.json"
    if not path.is_file():
        return None
    return dict(Counter(int(instance) for instance in json.loads(path.read_text()).values()))


def _server_funnel(records: list[dict[str, Any]], gt_id: int | None, points: dict[int, int] | None,
                   lookalikes: dict[int, str], visible: dict[str, set[int]] | None = None
                   ) -> dict[str, int | None]:
    """Where a pair's queries go on the server. Present pairs: the map's 3D points on the room's instance, the
    queries whose retrieved map images see it (``visible``: the map's :mod:`~synthleak.localize.visibility`;
    None where unknown) and the localized queries whose PnP inliers lie mostly on it; absent pairs: the
    localized queries whose inliers lie mostly on a look-alike (an instance sharing a SKU or the category with
    the queried object)."""
    from synthleak.evaluate.lookalikes import top_instance
    from synthleak.localize.visibility import count_retrieving

    tops = [top_instance(q.get("inlier_instance_counts") or {}) for q in records if q["success"]]
    if gt_id is None:
        return {"map_points_on_target": None, "n_retrieved_target": None, "n_target_top": None,
                "n_lookalike_top": sum(1 for t in tops if t in lookalikes)}
    return {"map_points_on_target": None if points is None else points.get(int(gt_id), 0),
            "n_retrieved_target": count_retrieving(records, int(gt_id), visible),
            "n_target_top": sum(1 for t in tops if t == int(gt_id)), "n_lookalike_top": None}


def attack_rows(config: StudyConfig, paths: StudyPaths, logs: dict[tuple[str, str], Path],
                attacker_dataset: Path | None = None, magnitude: float | None = None, kind: str | None = None,
                undefended: bool = False) -> list[dict[str, Any]]:
    """One results row per (room, attacker object, tier, aligner, thresholds), presence decided
    leave-one-scene-out and placement scored against the room's ground truth. ``undefended``: attack the
    answers the server gave before its online defense refused some (the same logged queries)."""
    from synthleak.attack.presence_features import attack_features
    from synthleak.attack.run import run_attack
    from synthleak.core.dataset import load_sequence
    from synthleak.evaluate.defense_online import without_defense
    from synthleak.evaluate.lookalikes import absent_kind, lookalike_ids
    from synthleak.evaluate.score import score_placement
    from synthleak.evaluate.tables import apply_presence_decisions
    from synthleak.localize.visibility import read_image_instances

    attacker_dataset = attacker_dataset or paths.dataset
    index = load_index(attacker_dataset)
    room_entries = {room["name"]: room for room in load_index(paths.dataset)["rooms"]}
    rooms = {name: load_sequence(paths.dataset / "scenes" / name).objects_by_id() for name in room_entries}
    by_object: dict[tuple[str, str], dict[str, list[dict]]] = {}  # each log parsed once, not once per object
    for name, log in logs.items():
        for q in read_query_log(log):
            q = without_defense(q) if undefended else q
            by_object.setdefault(name, {}).setdefault(q["attacker_object"], []).append(q)
    map_points = {name: _map_points_per_instance(paths.maps / name[0] / name[1]) for name in logs}
    visible = {name: read_image_instances(paths.maps / name[0] / name[1]) for name in logs}
    rows: list[dict[str, Any]] = []
    for obj in index["attacker_objects"]:
        seq = load_sequence(attacker_dataset / "attackers" / obj["id"])
        local, object_from_local = _attacker_local_model(config, attacker_dataset.parent / "sfm", obj["id"], seq)
        target = seq.objects_by_id()[seq.target_instance_id]
        for tier, room in sorted(logs):
            records = by_object.get((tier, room), {}).get(obj["id"], [])
            # frames without a local pose (SfM did not register them) are left out of the attack and counted
            sent = {q["frame"] for q in records}
            server = {q["frame"]: None if q["cam_from_world"] is None else np.array(q["cam_from_world"])
                      for q in records if q["success"] and q["frame"] in local}
            local_sent = {f: p for f, p in local.items() if f in sent}
            gt_id = obj.get("present_in", {}).get(room)
            gt = rooms[room].get(gt_id) if gt_id is not None else None
            funnel = _server_funnel(records, gt_id if gt is not None else None, map_points[(tier, room)],
                                    lookalike_ids(obj, room_entries[room]), visible[(tier, room)])
            kind_of_pair = None if gt is not None else absent_kind(obj, room_entries[room])
            for aligner in config.attack.aligners:
                alignments = [run_attack(local_sent, server, aligner, delta_r, delta_t, n_sent=len(local_sent))
                              for delta_r, delta_t in config.attack.thresholds]
                features = attack_features(local_sent, server, alignments, config.attack.thresholds)
                for (delta_r, delta_t), alignment, trial in zip(config.attack.thresholds, alignments, features,
                                                                strict=True):
                    estimate = alignment.scene_from_object if alignment.ok else None
                    score = score_placement(
                        estimate, None if gt is None else gt.world_from_object,
                        None if gt is None else gt.extents, target.extents,
                        symmetry=(gt or target).symmetry, object_from_local=object_from_local)
                    rows.append({
                        "room": room, "object": obj["id"], "model_id": obj["model_id"],
                        "category": target.category, "tier": tier, "aligner": aligner,
                        "delta_r_deg": float(delta_r), "delta_t_m": float(delta_t), "present_gt": gt is not None,
                        "eps": float(alignment.eps), "decision": False, "n_queries": len(sent),
                        "n_no_local_pose": len(sent) - len(local_sent), "n_localized": len(server), **funnel,
                        **score, "magnitude": magnitude, "kind": kind,
                        "absent_kind": kind_of_pair, **trial,
                    })
    return apply_presence_decisions(rows, config.attack.presence)


def stage_attack(config: StudyConfig, paths: StudyPaths, logs: dict[tuple[str, str], Path], force: set[str]
                 ) -> list[dict[str, Any]]:
    """Attack every (room, object) pair and write ``results/results.{csv,json}``."""
    from synthleak.evaluate.tables import read_results, write_results

    query_keys = [done_key(log.parent) for _, log in sorted(logs.items())]
    key = cache_key("attack", query_keys, _section(config, "attack"))
    if "attack" not in force and is_done(paths.results, key):
        return read_results(paths.results / "results.json")
    rows = attack_rows(config, paths, logs)
    write_results(rows, paths.results)
    mark_done(paths.results, key)
    return rows


# ------------------------------------------------------------------------------------------------ sweep
SWEEP_KINDS = ("all", *VARIANT_KINDS)
"""``sweep.kinds``: ``all`` varies the kinds of ``scenes.attacker_variant_kinds`` together."""


def stage_sweep(config: StudyConfig, paths: StudyPaths, render_key: str, maps: dict[tuple[str, str], Path],
                force: set[str], progress: bool, server_url: str | None = None, executor: Executor | None = None
                ) -> list[dict[str, Any]]:
    """Leakage against dissimilarity: re-make only the attacker objects at each (kind, magnitude) of
    ``[sweep]``, send them to the same servers, and attack. Rooms, renders of rooms and maps are reused."""
    import shutil

    from synthleak.evaluate.tables import write_results
    from synthleak.render.pipeline import SequenceJob, render_sequences
    from synthleak.scene.generate import write_study_stages

    rows: list[dict[str, Any]] = []
    for kind in config.sweep.kinds:
        if kind not in SWEEP_KINDS:
            raise ValueError(f"sweep.kinds: unknown kind {kind!r} (allowed: {', '.join(SWEEP_KINDS)})")
        kinds = list(config.scenes.attacker_variant_kinds) if kind == "all" else [kind]
        for magnitude in config.sweep.magnitudes:
            folder = paths.root / "sweep" / f"{kind}-{magnitude:g}"
            dataset = folder / "dataset"
            key = cache_key("sweep-render", render_key, kinds, magnitude)
            if "render" in force or not is_done(dataset, key):
                stages = dataset / "stages"
                if not stages.exists():  # rooms are byte-identical: start from them, rewrite attackers only
                    shutil.copytree(paths.dataset / "stages", stages)
                write_study_stages(config, stages, attacker_magnitude=magnitude, attacker_kinds=kinds,
                                   progress=progress)
                jobs = [SequenceJob(stages / obj["stage"], dataset / "attackers" / obj["id"], "attacker")
                        for obj in load_index(dataset)["attacker_objects"]]
                render_sequences(jobs, config, executor, progress)
                mark_done(dataset, key)
            logs = stage_queries(config, paths, maps, force, progress, server_url, attacker_dataset=dataset,
                                 out_root=folder / "queries", executor=executor)
            rows += attack_rows(config, paths, logs, dataset, magnitude, kind)
    if rows:
        write_results(rows, paths.results, stem="sweep")
    return rows


def stage_world_sweep(config: StudyConfig, paths: StudyPaths, force: set[str], progress: bool,
                      server_url: str | None = None, executor: Executor | None = None) -> list[dict[str, Any]]:
    """Leakage against the hard-world knobs: for each value of ``[sweep] material_sharing`` / ``clutter``, the
    whole study (stages, renders, maps, queries, attack) with that value, under ``sweep/<knob>-<value>/``,
    each stage cached as in the main study. Rows are tagged ``sweep_param`` / ``sweep_value``."""
    import dataclasses

    from synthleak.config import SweepConfig
    from synthleak.evaluate.tables import write_results

    points = [(param, float(v)) for param in ("material_sharing", "clutter") for v in getattr(config.sweep, param)]
    if points and server_url:
        raise ValueError("sweep.material_sharing / sweep.clutter build a map per value: they need the in-process "
                         "server (drop --server)")
    rows: list[dict[str, Any]] = []
    for param, value in points:
        sub = dataclasses.replace(config, scenes=dataclasses.replace(config.scenes, **{param: value}),
                                  sweep=SweepConfig())
        sub_paths = StudyPaths(paths.root / "sweep" / f"{param}-{value:g}")
        render_key = stage_render(sub, sub_paths, force, progress, executor)
        maps = stage_maps(sub, sub_paths, render_key, force, progress, executor)
        stage_features(sub, sub_paths, maps, force, progress, executor=executor)
        logs = stage_queries(sub, sub_paths, maps, force, progress, executor=executor)
        rows += [r | {"sweep_param": param, "sweep_value": value} for r in attack_rows(sub, sub_paths, logs)]
    if rows:
        write_results(rows, paths.results, stem="sweep_world")
    return rows


# ----------------------------------------------------------------------------------------------- report
def genuine_localization(paths: StudyPaths, logs: dict[tuple[str, str], Path]) -> list[dict[str, Any]]:
    """Accuracy of the held-out genuine queries per (tier, room): the server works as a server should."""
    from synthleak.core.dataset import load_sequence
    from synthleak.geometry.poses import camera_centre, rotation_error_deg

    out = []
    for (tier, room), log in sorted(logs.items()):
        scene = load_sequence(paths.dataset / "scenes" / room)
        genuine = [q for q in read_query_log(log) if q["genuine"]]
        closeups = [q for q in genuine if q.get("closeup")]
        rot, trans = [], []
        for q in genuine:
            if q["success"]:
                est, gt = np.array(q["cam_from_world"]), scene.pose(q["frame"])
                rot.append(rotation_error_deg(est[:3, :3], gt[:3, :3]))
                trans.append(float(np.linalg.norm(camera_centre(est) - camera_centre(gt))))
        out.append({"tier": tier, "room": room, "n": len(genuine), "localized": len(rot),
                    "closeups": len(closeups), "closeups_localized": sum(1 for q in closeups if q["success"]),
                    "median_rot_err_deg": float(np.median(rot)) if rot else float("nan"),
                    "median_trans_err_m": float(np.median(trans)) if trans else float("nan")})
    return out


def world_summary(config: StudyConfig, paths: StudyPaths) -> dict[str, Any]:
    """The hard-world knobs, what each room holds, and the furniture coverage of each walk-through (from the
    GT instance masks)."""
    from synthleak.core.dataset import load_sequence
    from synthleak.evaluate.coverage import sequence_coverage

    sc, rc = config.scenes, config.render
    rooms = []
    for room in load_index(paths.dataset)["rooms"]:
        coverage = sequence_coverage(load_sequence(paths.dataset / "scenes" / room["name"]))
        rooms.append({"room": room["name"], "selected": len(room["objects"]),
                      "distractors": len(room.get("distractors", [])), "props": len(room.get("props", [])),
                      **{k: v for k, v in coverage.items() if k != "sequence"}})
    return {"knobs": {"material_sharing": sc.material_sharing, "distractors": list(sc.distractors),
                      "clutter": sc.clutter, "layout": sc.layout, "walkthrough": rc.walkthrough,
                      "genuine_closeup_fraction": rc.genuine_closeup_fraction},
            "rooms": rooms}


def _world_section(config: StudyConfig, world: dict[str, Any]) -> list[str]:
    from synthleak.evaluate.tables import markdown_table

    knobs = ", ".join(f"{k} = {v}" for k, v in world["knobs"].items())
    columns = ["room", "selected", "distractors", "props", "frames", "median_coverage", "share_below_10pct",
               "closeups", "closeup_median_coverage"]
    return ["## The world\n",
            f"Difficulty knobs: {knobs}. Coverage: fraction of a frame's pixels on furniture and props (not the "
            "room shell), from the GT instance masks; `share_below_10pct`: walk-through frames under 10 %.\n",
            markdown_table(world["rooms"], columns, digits=3)]


def defense_queries(logs: dict[tuple[str, str], Path]) -> list[dict[str, Any]]:
    """The logged query decisions in the form the offline defense sweep reads (a query the online defense
    refused counts as localized without the defense)."""
    from synthleak.evaluate.defense_online import localized_without_defense

    return [{"tier": q["tier"], "room": q["room"], "genuine": q["genuine"], "attacker_object": q["attacker_object"],
             "success_without_defense": localized_without_defense(q),
             "inlier_instance_counts": q["inlier_instance_counts"]}
            | ({"closeup": q["closeup"]} if "closeup" in q else {})
            for _, log in sorted(logs.items()) for q in read_query_log(log)]


def _defense_online_section(config: StudyConfig, paths: StudyPaths, rows: list[dict[str, Any]],
                            logs: dict[tuple[str, str], Path]) -> list[str]:
    """Report lines for the defense online: the attack with and without it on the same queries."""
    if not config.defense.enabled:
        return []
    from synthleak.evaluate.defense_online import holds_decisions, report_section

    records = [q for _, log in sorted(logs.items()) for q in read_query_log(log)]
    without = attack_rows(config, paths, logs, undefended=True) if holds_decisions(records) else None
    return report_section(config.defense, records, without, rows, config.attack.thresholds, paths.results)


def _room_plots(config: StudyConfig, paths: StudyPaths, rows: list[dict[str, Any]]) -> list[Path]:
    """Top-down map per room: GT boxes and the estimates the attack decided present (first tier, last
    aligner, middle thresholds)."""
    from synthleak.core.dataset import load_sequence
    from synthleak.evaluate.plots import plot_room_topdown

    tier, aligner = config.localize.tiers[0], config.attack.aligners[-1]
    delta_r, delta_t = config.attack.thresholds[len(config.attack.thresholds) // 2]
    out = []
    for room in load_index(paths.dataset)["rooms"]:
        scene = load_sequence(paths.dataset / "scenes" / room["name"])
        objects = [(f"{o.model_id}#{o.instance_id}", o.world_from_object, o.extents)
                   for o in scene.objects if o.role == "object"]
        size = np.asarray(room["size"][:2], dtype=float)  # the room interior is centred on the origin
        chosen = [r for r in rows if r["room"] == room["name"] and r["tier"] == tier and r["aligner"] == aligner
                  and r["delta_r_deg"] == delta_r and r["delta_t_m"] == delta_t and r["decision"]
                  and r["scene_from_object_est"] is not None]
        estimates = []
        for r in chosen:
            gt_name = next((name for name, *_ in objects if name.startswith(f"{r['model_id']}#")), r["object"])
            extents = next((e for name, _, e in objects if name == gt_name), (0.5, 0.5, 0.5))
            estimates.append((gt_name, np.array(r["scene_from_object_est"]), extents))
        cams = np.array([scene.pose(f) for f in scene.frames])
        out.append(plot_room_topdown(
            size, objects, estimates, cameras=cams, out=paths.plots / f"{room['name']}_topdown.png",
            room_min=-size / 2, title=f"{room['name']}: GT (solid) vs decided-present estimates (dashed), "
            f"{tier}/{aligner} {delta_r:g}°/{delta_t:g} m"))
    return out


def _world_sweep_section(config: StudyConfig, rows: list[dict[str, Any]], paths: StudyPaths,
                         plots: list[Path]) -> list[str]:
    """Report lines for the material-sharing / clutter sweeps (and their plot appended to ``plots``)."""
    if not rows:
        return []
    from synthleak.evaluate.plots import plot_leakage_vs_world
    from synthleak.evaluate.tables import markdown_table
    from synthleak.evaluate.world_sweep import leakage_vs_world

    aligner = config.attack.aligners[0]
    thresholds = config.attack.thresholds[len(config.attack.thresholds) // 2]
    plots.append(plot_leakage_vs_world(rows, paths.plots / "leakage_vs_world.png", aligner, thresholds))
    stats = [s for s in leakage_vs_world(rows) if s["aligner"] == aligner
             and (s["delta_r_deg"], s["delta_t_m"]) == tuple(thresholds)]
    columns = ["sweep_param", "sweep_value", "tier", "precision", "recall", "tp", "fp", "n_pairs"]
    return ["## Leakage against the hard-world knobs (material sharing, clutter)\n",
            f"A whole study per value (rooms, maps and attackers re-made); presence P/R with `{aligner}` at "
            f"{thresholds[0]:g}°/{thresholds[1]:g} m.\n",
            markdown_table(stats, columns)]


def _sweep_section(sweep_rows: list[dict[str, Any]], paths: StudyPaths, plots: list[Path]) -> list[str]:
    """Report lines for the variant-magnitude sweep (and its plot appended to ``plots``)."""
    if not sweep_rows:
        return []
    from synthleak.evaluate.plots import leakage_vs_magnitude, plot_leakage_vs_magnitude
    from synthleak.evaluate.tables import markdown_table

    plots.append(plot_leakage_vs_magnitude(sweep_rows, paths.plots / "leakage_vs_magnitude.png"))
    stats = leakage_vs_magnitude(sweep_rows)
    columns = ["tier", "aligner", "delta_r_deg", "delta_t_m", "kind", "magnitude", "precision", "recall",
               "placement_success", "n_pairs"]
    return ["## Leakage against dissimilarity (attacker variant magnitude sweep)\n",
            "Presence precision/recall and placement success at 30°/0.5 m for attacker objects made with "
            "growing variant magnitude (colour, scale, shape, each alone and together).\n",
            markdown_table(stats, columns)]


def _side_by_side_sections(config: StudyConfig, paths: StudyPaths, rows: list[dict[str, Any]],
                           logs: dict[tuple[str, str], Path]) -> list[str]:
    """The aligners on the same queries; with an SfM local model, oracle vs SfM on the same queries."""
    from dataclasses import replace

    from synthleak.core.dataset import load_sequence
    from synthleak.evaluate.compare import side_by_side_markdown
    from synthleak.evaluate.sfm_summary import sfm_objects_markdown

    parts = []
    if len(config.attack.aligners) > 1:
        parts += ["## Aligners side by side (same queries)\n",
                  "Presence P/R; success: GT-present pairs placed within 10°/0.25 m (unplaced ones fail); medians "
                  "over the GT-present pairs every aligner placed (`common`).\n",
                  side_by_side_markdown({a: [r for r in rows if r["aligner"] == a] for a in config.attack.aligners},
                                        variant_label="aligner")]
    if config.attack.local_model == "sfm":
        oracle = attack_rows(replace(config, attack=replace(config.attack, local_model="oracle")), paths, logs)
        objects = load_index(paths.dataset)["attacker_objects"]
        models = {o["id"]: _sfm_model(config, paths.root / "sfm", o["id"],
                                      load_sequence(paths.dataset / "attackers" / o["id"])) for o in objects}
        parts += ["## Local model: SfM of the attacker's orbit\n",
                  "pycolmap incremental SfM per orbit, scaled by the object's known size. Scored against the GT "
                  "orbit: `misregistered` views lie off the LO-RANSAC Sim(3) onto the GT camera centres; "
                  "`seconds` is the build time (the `all` line: registered share, median |scale error|, total "
                  "seconds).\n",
                  sfm_objects_markdown(models),
                  "## Local model: oracle vs SfM (same queries)\n",
                  "The same query logs attacked with the exact local poses (`oracle`) and the SfM ones (`sfm`); "
                  "views SfM did not register are left out of the SfM attack.\n",
                  side_by_side_markdown({"oracle": oracle, "sfm": rows}, ("tier", "aligner", "delta_r_deg",
                                                                          "delta_t_m"), variant_label="local model")]
    return parts


def stage_report(config: StudyConfig, paths: StudyPaths, rows: list[dict[str, Any]],
                 logs: dict[tuple[str, str], Path], timings: dict[str, float],
                 sweep_rows: list[dict[str, Any]] | None = None,
                 world_rows: list[dict[str, Any]] | None = None) -> Path:
    """``report.md`` with the paper-shaped tables, placement and defense figures, and the plots."""
    from synthleak.evaluate.absent_pairs import absent_funnel_markdown, presence_by_absent_kind_markdown
    from synthleak.evaluate.defense_sweep import defense_tradeoff
    from synthleak.evaluate.paper_reference import tier_ordering_markdown
    from synthleak.evaluate.plots import plot_defense_tradeoff, plot_placement_cdfs, plot_presence_pr
    from synthleak.evaluate.tables import (
        markdown_table,
        placement_summary,
        presence_pr_per_room,
        presence_rules_markdown,
        recall_funnel_markdown,
        table1_markdown,
        table2_markdown,
    )

    paths.plots.mkdir(parents=True, exist_ok=True)
    world = world_summary(config, paths)
    atomic_write_text(paths.results / "world.json", json.dumps(world, indent=1))
    genuine = genuine_localization(paths, logs)
    tradeoff = defense_tradeoff(defense_queries(logs), config.defense.sweep_fractions,
                                config.defense.sweep_min_instances)
    atomic_write_text(paths.results / "genuine_localization.json", json.dumps(genuine, indent=1))
    atomic_write_text(paths.results / "defense_tradeoff.json", json.dumps(tradeoff, indent=1, default=str))
    plots = [plot_presence_pr(presence_pr_per_room(rows), paths.plots / "presence_pr.png"),
             plot_placement_cdfs(rows, paths.plots / "placement_cdf.png"),
             plot_defense_tradeoff(tradeoff, paths.plots / "defense_tradeoff.png"),
             *_room_plots(config, paths, rows)]
    index = load_index(paths.dataset)
    n_present = sum(len(o.get("present_in", {})) for o in index["attacker_objects"])
    parts = [
        f"# synthleak study `{config.name}`\n",
        f"{config.description}\n",
        f"seed {config.seed}; {len(index['rooms'])} rooms; {len(index['attacker_objects'])} attacker objects; "
        f"{n_present} present (room, object) pairs of {len(index['rooms']) * len(index['attacker_objects'])}; "
        f"renderer {config.render.renderer} {config.render.width}x{config.render.height}; "
        f"tiers {', '.join(config.localize.tiers)}; aligners {', '.join(config.attack.aligners)}; "
        f"local model {config.attack.local_model}.\n",
        *_world_section(config, world),
        "## Genuine queries (held-out frames: walk-through and close-ups)\n",
        markdown_table(genuine, ["tier", "room", "n", "localized", "closeups", "closeups_localized",
                                 "median_rot_err_deg", "median_trans_err_m"]),
        "## Presence (paper Table 1 shape)\n",
        table1_markdown(rows),
        "## Tier ordering beside the paper's (Table 1)\n",
        tier_ordering_markdown(rows),
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
        "## Presence by kind of absent pair\n",
        "False positives among the absent pairs of each kind, and the precision counting only that kind of "
        "absent pair (all present pairs).\n",
        presence_by_absent_kind_markdown(rows),
        presence_rules_markdown(rows, config.attack.presence),
        "## Placement against ground truth\n",
        placement_summary(rows, config.attack.thresholds),
        *_side_by_side_sections(config, paths, rows, logs),
        *_defense_online_section(config, paths, rows, logs),
        "## Defense trade-off (paper Fig. 6, exact instance labels)\n",
        "Among the queries the server localizes: genuine queries kept (all, walk-through frames, close-ups of one "
        "object or a small group) and attacker queries rejected, pooled over tiers.\n",
        markdown_table([t for t in tradeoff if t.get("tier") == "all"],
                        [k for k in (tradeoff[0] if tradeoff else {}) if k != "tier"]),
        *_sweep_section(sweep_rows or [], paths, plots),
        *_world_sweep_section(config, world_rows or [], paths, plots),
        "## Plots\n",
        "\n".join(f"![{p.stem}](plots/{p.name})" for p in plots) + "\n",
        "## Wall time per stage (this run; cached stages take ~0 s)\n",
        markdown_table([{"stage": k, "seconds": v} for k, v in timings.items()], ["stage", "seconds"], 1),
    ]
    atomic_write_text(paths.report, "\n".join(parts))
    return paths.report


# -------------------------------------------------------------------------------------------- the study
def run_study(config: StudyConfig, out: Path, force: Sequence[str] = (), server_url: str | None = None,
              progress: bool = True, workers: int = 1, executor: str | Executor = "local",
              address: str | None = None) -> Path:
    """Run or resume every stage of a study; returns the report's path.

    Rendering, maps and queries run over ``executor``: ``"local"`` with ``workers`` processes, ``"ray"``
    (``address``: a running cluster, e.g. ``"auto"``; None starts a local Ray), or an
    :class:`~synthleak.executors.Executor`. Result files are the same bytes whatever the executor."""
    import time

    from synthleak.executors import make_executor

    if isinstance(executor, str):
        with make_executor(executor, workers, address) as pool:
            return run_study(config, out, force, server_url, progress, workers, pool)

    forced = _check_force(force)
    check_config(config, config.name)  # a config built in Python fails here, not after the renders
    check_tiers_installed(config.localize.tiers)
    paths = StudyPaths(Path(out))
    paths.root.mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}

    def timed(name: str, fn, *args, **kwargs):
        start = time.perf_counter()
        value = fn(*args, **kwargs)
        timings[name] = round(time.perf_counter() - start, 2)
        return value

    render_key = timed("render", stage_render, config, paths, forced, progress, executor)
    maps = timed("maps", stage_maps, config, paths, render_key, forced, progress, executor)
    if server_url is None:
        timed("features", stage_features, config, paths, maps, forced, progress, executor=executor)
    logs = timed("queries", stage_queries, config, paths, maps, forced, progress, server_url, executor=executor)
    rows = timed("attack", stage_attack, config, paths, logs, forced)
    sweep_rows = timed("sweep", stage_sweep, config, paths, render_key, maps, forced, progress, server_url,
                       executor)
    world_rows = timed("world sweep", stage_world_sweep, config, paths, forced, progress, server_url, executor)
    report = timed("report", stage_report, config, paths, rows, logs, timings, sweep_rows, world_rows)
    atomic_write_text(paths.root / "timings.json", json.dumps(timings, indent=1))
    return report
