"""Localization service: feature tiers, GT-pose mapping, PnP localization, the Sec. 6 defense, HTTP.

    build_map(scene_dir, "sift", map_dir, LocalizeConfig())          # features, pairs, triangulation
    loc = Localizer.load(map_dir, config, defense=DefensePolicy(...))  # in process
    loc.localize(rgb_or_encoded_bytes) -> LocalizationResult
    synthleak.localize.server.serve(map_dir, port=8000)                # HTTP (FastAPI + uvicorn)
    synthleak.localize.client.HttpLocalizer(url).localize(...)         # same interface over HTTP
"""

import pycolmap as _pycolmap

from synthleak.localize.defense import DefenseDecision, DefensePolicy, decide
from synthleak.localize.localizer import LocalizationResult, Localizer
from synthleak.localize.mapping import build_map
from synthleak.localize.tiers import TIERS, Tier, get_tier

# COLMAP logs an INFO line per feature extractor it creates (one per query): keep warnings and errors only.
_pycolmap.logging.minloglevel = max(int(_pycolmap.logging.minloglevel), int(_pycolmap.logging.WARNING))

__all__ = [
    "TIERS",
    "DefenseDecision",
    "DefensePolicy",
    "LocalizationResult",
    "Localizer",
    "Tier",
    "build_map",
    "decide",
    "get_tier",
]
