"""`synthleak study`: stages -> renders -> maps -> features -> queries -> attack -> sweeps -> report, resumable.

Every stage (:class:`Stage`) writes into its own folders under the study's output (:class:`StudyPaths`) and
marks each with a content key (:mod:`synthleak.cache`); a rerun skips what its inputs did not change, so
changing a scoring threshold re-runs only the attack and the report, and changing a tier does not re-render.
All stages run over one :class:`StudyContext` (config, paths, forced stages, executor, server, defense).

The public API below is imported from its module on first use: every config load reads ``LOCAL_MODELS`` and
``SWEEP_KINDS`` from here, and that must not import the whole pipeline.
"""

from __future__ import annotations

from synthleak.plugins import lazy_exports

_EXPORTS = {
    "run_study": "run", "STAGES": "run", "STAGE_TYPES": "run", "check_force": "run", "forced_stages": "run",
    "study_stages": "run",
    "StudyPaths": "paths",
    "StudyContext": "context", "Stage": "context", "Unit": "context",
    "RenderStage": "render", "MapsStage": "maps", "FeaturesStage": "features", "QueriesStage": "queries",
    "AttackStage": "attack", "attack_rows": "attack",
    "AttackerRenderStage": "sweep", "SweepStage": "sweep", "WorldSweepStage": "sweep", "SWEEP_KINDS": "options",
    "ReportStage": "report", "check_tiers_installed": "tiers",
    "LOCAL_MODELS": "synthleak.attack.local_poses",
    "read_query_log": "synthleak.evaluate.query_log", "defense_queries": "synthleak.evaluate.query_log",
    "load_features": "synthleak.localize.feature_files", "save_features": "synthleak.localize.feature_files",
}
"""Public name -> its module (a bare name: a module of this package)."""

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
