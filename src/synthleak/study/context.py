"""What every stage of a study runs with (:class:`StudyContext`) and what every stage is (:class:`Stage`)."""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from synthleak.cache import done_key, is_done, mark_done
from synthleak.config import StudyConfig, config_to_dict
from synthleak.core.dataset import read_index
from synthleak.evaluate.defense_online import online_policy
from synthleak.executors import Executor, LocalExecutor
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.servers import Server, server_by_name, study_servers
from synthleak.study.paths import StudyPaths


@dataclass
class StudyContext:
    """One study run (or one sweep point of it): its config, its folders and how it runs."""

    config: StudyConfig
    paths: StudyPaths
    force: frozenset[str] = frozenset()
    """Names of the stages to redo even where their outputs are up to date."""
    progress: bool = True
    executor: Executor = field(default_factory=lambda: LocalExecutor(1))
    """Where frames, maps, features and queries run (results do not depend on it)."""
    server_url: str | None = None
    """Attack running HTTP services instead of in-process localizers: one URL, a multi-map service's URL (its
    ``GET /maps``) or a URL template with ``{server}``, ``{tier}``, ``{room}``, ``{room_index}``
    (docs/service-protocol.md; :meth:`server_urls`)."""
    outputs: dict[str, Any] = field(default_factory=dict)
    """What the stages run so far returned, by stage name (the attack's rows, the sweeps' rows)."""
    timings: dict[str, float] = field(default_factory=dict)
    """Wall seconds of each stage of this run, by timings label."""
    keys: list[str] = field(default_factory=list)
    """The content keys of every output the stages run so far (sweep points included) are made of."""
    defense: DefensePolicy | None = field(init=False)
    """The policy the in-process server applies (``[defense] enabled``), or None."""

    def __post_init__(self) -> None:
        self.defense = online_policy(self.config.defense)

    def section(self, name: str) -> dict[str, Any]:
        """One section of the config as a plain dict (for content keys)."""
        return config_to_dict(self.config)[name]

    @property
    def genuine(self) -> bool:
        """True when the study sends its rooms' genuine held-out frames too (not a variant-sweep point)."""
        return self.paths.rooms is None

    @property
    def render_key(self) -> str | None:
        """The content key of the rooms' renders."""
        return done_key(self.paths.scene_dataset)

    def rooms(self) -> list[dict[str, Any]]:
        """The rooms' ``index.json`` entries."""
        return read_index(self.paths.scene_dataset / "stages")["rooms"]

    def servers(self) -> dict[tuple[str, str], Path]:
        """The map of every (server, room) pair: servers (:func:`~synthleak.localize.servers.study_servers`: a tier,
        or ``tier@profile+representation``) in config order, rooms in index order."""
        rooms = self.rooms()
        return {(server.name, room["name"]): self.paths.map_dir(server.name, room["name"])
                for server in study_servers(self.config.localize) for room in rooms}

    def server_urls(self) -> dict[tuple[str, str], str]:
        """The service URL of every (server, room) pair of :meth:`servers` ({} in process): ``server_url`` as a
        template, else the pairs a multi-map service lists at ``GET /maps``, else that one URL for every pair
        (:func:`synthleak.localize.client.server_urls`)."""
        if self.server_url is None:
            return {}
        from synthleak.localize.client import is_url_template, list_maps, server_urls

        maps = None if is_url_template(self.server_url) else list_maps(self.server_url)
        return server_urls(self.server_url, list(self.servers()), [room["name"] for room in self.rooms()], maps)

    def server(self, name: str) -> Server:
        """The server called ``name`` (a key of :meth:`servers`)."""
        return server_by_name(self.config.localize)[name]

    def logs(self) -> dict[tuple[str, str], Path]:
        """The query log of every (tier, room) server."""
        return {name: self.paths.query_log(*name) for name in self.servers()}

    def point(self, paths: StudyPaths, config: StudyConfig | None = None, force: frozenset[str] = frozenset()
              ) -> StudyContext:
        """The context of a sweep point: its own folders (and config), the stages in ``force`` redone too; the
        outputs are its own, the content keys are recorded with this study's."""
        return dataclasses.replace(self, paths=paths, config=config or self.config, force=self.force | force,
                                   outputs={}, timings={})


@dataclass(frozen=True)
class Unit:
    """One output folder of a stage and the content key of what it is made from."""

    folder: Path
    key: str
    item: Any = None
    """What the folder holds (a tier, a (tier, room) server...)."""


class Stage(ABC):
    """One step of a study. Its outputs are folders (:meth:`units`), each marked with the content key of its
    inputs (:mod:`synthleak.cache`); :meth:`run` makes the ones forced, missing or made from other inputs."""

    name: ClassVar[str]
    """The stage's name (``--force NAME``)."""
    label: ClassVar[str] = ""
    """Its row in the wall-time table (default: the name)."""
    reads: ClassVar[tuple[str, ...]] = ()
    """The stages whose outputs this one reads and whose forced remake can change them under an unchanged key (a
    code change): forcing one of them forces this one too (:func:`~synthleak.study.run.forced_stages`). None
    lists ``render``: a forced render only renders missing frames, the rest are kept."""

    def units(self, ctx: StudyContext) -> list[Unit]:
        """The stage's output folders and their content keys (none: the stage runs every time)."""
        return []

    def is_current(self, ctx: StudyContext, unit: Unit) -> bool:
        """True when ``unit`` holds the complete output for its key."""
        return is_done(unit.folder, unit.key)

    @abstractmethod
    def make(self, ctx: StudyContext, todo: list[Unit]) -> Any:
        """Make the folders of ``todo`` (the other units are up to date); return the stage's output."""

    def run(self, ctx: StudyContext) -> Any:
        """Make what is not up to date, mark it done, record the keys; return the stage's output."""
        units = self.units(ctx)
        todo = [unit for unit in units if self.name in ctx.force or not self.is_current(ctx, unit)]
        output = self.make(ctx, todo)
        for unit in todo:
            mark_done(unit.folder, unit.key)
        ctx.keys.extend(unit.key for unit in units)
        return output

    @classmethod
    def timings_label(cls) -> str:
        return cls.label or cls.name
