"""The layout of a study's output folder: every path a stage reads or writes is built here."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class StudyPaths:
    """Where each stage of a study writes, under ``root``::

        dataset/                 stages/ (USD + index.json), scenes/<room>/, attackers/<object>/ (renders)
        dataset.<key[:12]>/      renders made with another config, kept aside
        maps/<tier>/<room>/      one localization map per server
        features/<tier>/<sequence>/<frame>.npz   query features, once per tier
        queries/<tier>/<room>/queries.jsonl      the query log of each server
        sfm/<object>/            the attacker's SfM of each orbit (local_model = "sfm")
        results/  plots/  report.md  timings.json
        sweep/<point>/           a sweep point: a study of its own (world sweep) or attackers only (variant sweep)

    ``rooms``: the study whose rooms (scene renders, maps) this one attacks (a variant-sweep point: its own
    attacker renders, features and queries against the main study's servers); None: its own rooms."""

    root: Path
    rooms: StudyPaths | None = None

    @property
    def dataset(self) -> Path:
        """The renders this study made (for a variant-sweep point: its attackers only)."""
        return self.root / "dataset"

    @property
    def stages(self) -> Path:
        return self.dataset / "stages"

    @property
    def scene_dataset(self) -> Path:
        """The dataset holding the rooms' scene sequences."""
        return (self.rooms or self).dataset

    @property
    def maps(self) -> Path:
        return (self.rooms or self).root / "maps"

    @property
    def features(self) -> Path:
        return self.root / "features"

    @property
    def queries(self) -> Path:
        return self.root / "queries"

    @property
    def sfm(self) -> Path:
        return self.root / "sfm"

    @property
    def results(self) -> Path:
        return self.root / "results"

    @property
    def plots(self) -> Path:
        return self.root / "plots"

    @property
    def report(self) -> Path:
        return self.root / "report.md"

    @property
    def timings(self) -> Path:
        return self.root / "timings.json"

    def kept_dataset(self, key: str) -> Path:
        """Where renders made with the config of ``key`` are kept when the config changes."""
        return self.root / f"dataset.{key[:12]}"

    def scene(self, room: str) -> Path:
        """A room's scene sequence."""
        return self.scene_dataset / "scenes" / room

    def attacker(self, obj_id: str) -> Path:
        """An attacker object's orbit sequence."""
        return self.dataset / "attackers" / obj_id

    def sequence(self, relative: str, genuine: bool) -> Path:
        """A query's sequence (``relative`` to its dataset: the rooms' for a genuine query, else the attackers')."""
        return (self.scene_dataset if genuine else self.dataset) / relative

    def map_dir(self, tier: str, room: str) -> Path:
        return self.maps / tier / room

    def features_dir(self, tier: str) -> Path:
        return self.features / tier

    def features_file(self, tier: str, sequence: str, frame: str) -> Path:
        """The features of one query image (``sequence``: relative to its dataset)."""
        return self.features_dir(tier) / sequence / f"{frame}.npz"

    def query_dir(self, tier: str, room: str) -> Path:
        return self.queries / tier / room

    def query_log(self, tier: str, room: str) -> Path:
        return self.query_dir(tier, room) / "queries.jsonl"

    def sfm_dir(self, obj_id: str) -> Path:
        return self.sfm / obj_id

    def sweep_point(self, name: str, attacker_only: bool = False) -> StudyPaths:
        """The folder of one sweep point: a whole study, or (``attacker_only``) attackers against this study's
        rooms."""
        return StudyPaths(self.root / "sweep" / name, self if attacker_only else None)
