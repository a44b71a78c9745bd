"""The builders of the object library, registered by name in :data:`BUILDERS` when this package is imported:
the parametric furniture and prop builders (see :mod:`.base` for the rules) and ``imported`` (stored meshes,
:mod:`.imported`)."""

from synthleak.assets.builders import (  # noqa: F401  (registers)
    decor,
    imported,
    lighting,
    misc,
    props,
    seating,
    storage,
    tables,
)
from synthleak.assets.builders.base import BUILDERS, BuilderSpec, PartBuilder, SupportSurface, builder

__all__ = ["BUILDERS", "BuilderSpec", "PartBuilder", "SupportSurface", "builder"]
