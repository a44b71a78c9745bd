"""What a study needs to know of its feature tiers: are they installed, and what of a tier enters a content key."""

from __future__ import annotations

import importlib.util
from collections.abc import Sequence

from synthleak.errors import ConfigError, MissingDependencyError
from synthleak.localize.deep import EXTRA, INSTALL_HINT, numerics_record
from synthleak.localize.tiers import DEFAULT_PROFILE, get_tier, profile_tier


def tier_weights(tier: str, profile: str = DEFAULT_PROFILE) -> list:
    """What of a tier enters a content key: a torch tier's definition (matching thresholds, budget), the sha256
    of its weight files and its torch numerics (:func:`~synthleak.localize.deep.numerics_record`); under a server
    ``profile`` other than ``strict``, every tier's effective definition
    (:func:`~synthleak.localize.tiers.profile_tier`) and the profile's name. Nothing for the other tiers under
    ``strict`` (their keys stay as they were)."""
    spec = profile_tier(tier, profile)
    record = spec.weights_record()
    if not record and not spec.needs_torch and profile == DEFAULT_PROFILE:
        return []
    entry = {"tier": spec.definition(), "weights": {name: e["sha256"] for name, e in sorted(record.items())}}
    if spec.needs_torch:
        entry["numerics"] = numerics_record()
    return [entry if profile == DEFAULT_PROFILE else {"profile": profile, **entry}]


def check_tiers_installed(tiers: Sequence[str], profile: str = DEFAULT_PROFILE) -> None:
    """Fail before any rendering when a tier's packages (torch, kornia) or weight files are not installed (the
    error names the ``[learned]`` extra and the install command), or when server ``profile`` has no values for a
    tier (a :class:`~synthleak.errors.ConfigError` naming ``localize.profile``)."""
    for tier in tiers:
        spec = get_tier(tier)
        try:
            profile_tier(spec, profile)
        except ValueError as exc:
            raise ConfigError(f"localize.profile: {exc}") from None
        if not spec.needs_torch:
            continue
        missing = [m for m in ("torch", "kornia") if importlib.util.find_spec(m) is None]
        if missing:
            raise MissingDependencyError(f"localize.tiers: {tier!r} needs {', '.join(missing)} (the [{EXTRA}] "
                                         f"extra): {INSTALL_HINT}")
        tier_weights(tier)  # a missing weight file raises WeightsNotFoundError naming the package
