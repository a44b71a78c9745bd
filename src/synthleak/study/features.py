"""The features stage: every query image's features, once per tier (not once per room server it is sent to)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from synthleak.cache import cache_key, done_key
from synthleak.executors import chunks
from synthleak.localize.feature_files import save_features
from synthleak.localize.images import decode_image
from synthleak.localize.tiers import get_tier
from synthleak.study.context import Stage, StudyContext, Unit
from synthleak.study.plan import query_plans
from synthleak.study.tiers import tier_weights
from synthleak.study.workers import QUERIES_PER_TASK, clear_worker_cache, worker_cached


@dataclass
class FeatureTask:
    """Extract one tier's features of consecutive query images (``(image, out)`` paths), for one worker."""

    tier: str
    max_keypoints: int
    items: list[tuple[str, str]]


def feature_task(task: FeatureTask) -> int:
    """Extract and save the features of the task's images (a worker task; extraction is single threaded)."""
    extractor = worker_cached(repr(("extractor", task.tier, task.max_keypoints)),
                              lambda: get_tier(task.tier).make_extractor(task.max_keypoints))
    for image, out in task.items:
        rgb = decode_image(Path(image).read_bytes())
        save_features(Path(out), extractor(rgb), (rgb.shape[1], rgb.shape[0]))
    return len(task.items)


class FeaturesStage(Stage):
    """Features cached under ``features/<tier>/<sequence>/<frame>.npz`` (in-process servers only), keyed by the
    renders, the tier and the extraction settings; not by ``[localize] profile``, which sets only matching and
    PnP fields (:data:`~synthleak.localize.tiers.PROFILE_FIELDS`), so every profile extracts the same features."""

    name = "features"

    def units(self, ctx: StudyContext) -> list[Unit]:
        config = ctx.config
        return [Unit(ctx.paths.features_dir(tier),
                     cache_key("features", done_key(ctx.paths.scene_dataset), done_key(ctx.paths.dataset),
                               ctx.genuine, tier, config.localize.max_keypoints, config.attack.queries_per_object,
                               *tier_weights(tier)), tier)
                for tier in sorted({ctx.server(name).tier for name, _ in ctx.servers()})]

    def make(self, ctx: StudyContext, todo: list[Unit]) -> None:
        plans = query_plans(ctx) if todo else {}
        tasks = []
        for unit in todo:
            seen: dict[str, tuple[str, str]] = {}
            for plan in plans.values():
                for item in plan:
                    out = ctx.paths.features_file(unit.item, item["sequence"], item["frame"])
                    seen.setdefault(item["_image"], (item["_image"], str(out)))
            items = [seen[k] for k in sorted(seen)]
            tasks += [FeatureTask(unit.item, ctx.config.localize.max_keypoints, c)
                      for c in chunks(items, QUERIES_PER_TASK)]
        ctx.executor.map(feature_task, tasks, "features", ctx.progress)
        clear_worker_cache()
