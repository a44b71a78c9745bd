"""Parametric furniture and prop builders (registered by name in :data:`BUILDERS`); see :mod:`.base` for the rules."""

from synthleak.assets.builders import decor, lighting, misc, props, seating, storage, tables  # noqa: F401  (registers)
from synthleak.assets.builders.base import BUILDERS, BuilderSpec, PartBuilder, SupportSurface, builder

__all__ = ["BUILDERS", "BuilderSpec", "PartBuilder", "SupportSurface", "builder"]
