"""What a study needs to know of its feature tiers: are they installed, and what of a tier enters a content key."""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence
from dataclasses import asdict

from synthleak.errors import MissingDependencyError
from synthleak.localize.deep import EXTRA, INSTALL_HINT
from synthleak.localize.tiers import get_tier


def tier_weights(tier: str) -> list:
    """A learned tier's definition (matching thresholds, budget) and the sha256 of its weight files; nothing for
    the other tiers (their keys stay as they were)."""
    spec = get_tier(tier)
    record = spec.weights_record()
    if not record:
        return []
    return [{"tier": asdict(spec), "weights": {name: entry["sha256"] for name, entry in sorted(record.items())}}]


def check_tiers_installed(tiers: Sequence[str]) -> None:
    """Fail before any rendering when a tier's packages (torch, kornia) or weight files are not installed; the
    error names the ``[learned]`` extra and the install command."""
    for tier in tiers:
        if not get_tier(tier).needs_torch:
            continue
        missing = [m for m in ("torch", "kornia") if importlib.util.find_spec(m) is None]
        if missing:
            raise MissingDependencyError(f"localize.tiers: {tier!r} needs {', '.join(missing)} (the [{EXTRA}] "
                                         f"extra): {INSTALL_HINT}")
        tier_weights(tier)  # a missing weight file raises WeightsNotFoundError naming the package
