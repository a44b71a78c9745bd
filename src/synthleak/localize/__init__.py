"""Localization service: feature tiers, GT-pose mapping, PnP localization, the Sec. 6 defense, HTTP."""

from synthleak.localize.defense import DefenseDecision, DefensePolicy, decide
from synthleak.localize.localizer import LocalizationResult, Localizer
from synthleak.localize.mapping import build_map
from synthleak.localize.tiers import TIERS, Tier, get_tier

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
