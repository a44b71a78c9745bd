"""The names a study config chooses among in ``[sweep]`` (checked when a config loads, so kept light)."""

from __future__ import annotations

from synthleak.assets.mesh import VARIANT_KINDS

SWEEP_KINDS = ("all", *VARIANT_KINDS)
"""``sweep.kinds``: ``all`` varies the kinds of ``scenes.attacker_variant_kinds`` together."""
