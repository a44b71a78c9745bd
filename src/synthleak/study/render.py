"""The render stage: the study's USD stages and their renders (rooms and attacker orbits)."""

from __future__ import annotations

from synthleak.cache import cache_key, done_key
from synthleak.render.pipeline import generate
from synthleak.study.context import Stage, StudyContext, Unit


def code_formats(config) -> list[dict[str, int]]:
    """What of the code's versions enters the render key: the stages' formats (a renamed or redrawn attacker
    setting) and, when any capture is photographed, the capture model's. Without them a folder rendered by older
    code was reused as if current (its render key named only the config)."""
    from synthleak.render.capture import CAPTURE_FORMAT
    from synthleak.scene.attacker_settings import SETTINGS_FORMAT
    from synthleak.scene.generate import STAGE_FORMAT

    return [{"stage_format": STAGE_FORMAT, "settings_format": SETTINGS_FORMAT}] + (
        [{"capture_format": CAPTURE_FORMAT}] if config.render.photographed else [])


class RenderStage(Stage):
    """Stages and renders (the render pipeline resumes frame by frame by itself). Renders made with another
    config are kept aside (``dataset.<key>``), never deleted."""

    name = "render"

    def units(self, ctx: StudyContext) -> list[Unit]:
        return [Unit(ctx.paths.dataset, cache_key("render", ctx.config.seed, ctx.section("scenes"),
                                                  ctx.section("render"), *code_formats(ctx.config)))]

    def make(self, ctx: StudyContext, todo: list[Unit]) -> None:
        if not todo:
            return
        old_key = done_key(ctx.paths.dataset)
        if old_key is not None and old_key != todo[0].key:
            ctx.paths.dataset.rename(ctx.paths.kept_dataset(old_key))
        generate(ctx.config, ctx.paths.dataset, progress=ctx.progress, executor=ctx.executor)
