"""Localization service: feature tiers, GT-pose mapping, PnP localization, the Sec. 6 defense, HTTP.

    build_map(scene_dir, "sift", map_dir, LocalizeConfig())          # features, pairs, triangulation
    loc = Localizer.load(map_dir, config, defense=DefensePolicy(...))  # in process
    loc.localize(rgb_or_encoded_bytes) -> LocalizationResult
    synthleak.localize.server.serve(map_dir, port=8000)                # HTTP (FastAPI + uvicorn)
    synthleak.localize.client.HttpLocalizer(url).localize(...)         # same interface over HTTP
"""

from __future__ import annotations

import pycolmap as _pycolmap

from synthleak.plugins import lazy_exports

# COLMAP logs an INFO line per feature extractor it creates (one per query): keep warnings and errors only.
_pycolmap.logging.minloglevel = max(int(_pycolmap.logging.minloglevel), int(_pycolmap.logging.WARNING))

_EXPORTS = {
    "DefenseDecision": "defense", "DefensePolicy": "defense", "decide": "defense",
    "LocalizationResult": "localizer", "Localizer": "localizer",
    "build_map": "mapping",
    "TIERS": "tiers", "Tier": "tiers", "get_tier": "tiers", "PROFILES": "tiers", "profile_tier": "tiers",
}
"""Public name -> its module, imported on first use: the tier registry (read by config validation) and the
torch-based ``deep`` module import this package without pulling in the localizer and its config types."""

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
