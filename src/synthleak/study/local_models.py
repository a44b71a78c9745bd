"""The sfm stage: the attacker's SfM local model of each orbit (``[attack] local_model = "sfm"``), one task per
object over the study's executor, cached under ``sfm/<object>/`` by content."""

from __future__ import annotations

from pathlib import Path

from synthleak.attack.local_poses import sfm_model
from synthleak.core.dataset import load_sequence, read_index
from synthleak.study.context import Stage, StudyContext


def sfm_task(item: tuple[str, str, int]) -> int:
    """Build (or find cached) one orbit's SfM local model; the number of views it registered (a worker task:
    the reconstruction is single threaded and seeded, so the model is the same bytes on any worker)."""
    sequence_dir, workdir, seed = item
    return len(sfm_model(load_sequence(Path(sequence_dir)), Path(workdir), seed).cam_from_local)


class SfmStage(Stage):
    """Every attacker object's SfM, before the attack reads them (which then only loads the caches). Nothing to
    do with the oracle local model. ``--force sfm`` rebuilds them."""

    name = "sfm"

    def make(self, ctx: StudyContext, todo: list) -> None:
        if ctx.config.attack.local_model != "sfm":
            return None
        objects = [o["id"] for o in read_index(ctx.paths.dataset / "stages")["attacker_objects"]]
        if self.name in ctx.force:
            for obj in objects:
                (ctx.paths.sfm_dir(obj) / "model.json").unlink(missing_ok=True)
        items = [(str(ctx.paths.attacker(obj)), str(ctx.paths.sfm_dir(obj)), ctx.config.seed) for obj in objects]
        ctx.executor.map(sfm_task, items, "sfm", ctx.progress)
        return None
