"""Which torch numerics synthleak's torch tiers run with, pinned in the environment before torch starts.

torch reads ``ATEN_CPU_CAPABILITY`` when it first dispatches a kernel and MKL reads ``MKL_CBWR`` when it starts:
set later (after ``import kornia``, which runs kernels, or any torch code), they change nothing. So
``import synthleak`` sets them (:func:`pin_torch_env`) unless ``$SYNTHLEAK_TORCH_NUMERICS`` is ``native``; the
learned tiers check that they took effect (:func:`synthleak.localize.deep.portable_torch`). Other torch code in
the same process runs on the same baseline kernels.
"""

from __future__ import annotations

import os

NUMERICS_ENV = "SYNTHLEAK_TORCH_NUMERICS"
NUMERICS_MODES = ("portable", "native")
PORTABLE_TORCH_ENV = {"ATEN_CPU_CAPABILITY": "default", "MKL_CBWR": "COMPATIBLE"}
"""ATen's ``DEFAULT`` (baseline x86-64) kernels, MKL's conditional numerical reproducibility mode."""


def numerics_mode() -> str:
    """``$SYNTHLEAK_TORCH_NUMERICS`` as given (``portable`` where unset or blank)."""
    return os.environ.get(NUMERICS_ENV, "").strip() or "portable"


def pin_torch_env() -> None:
    """Set :data:`PORTABLE_TORCH_ENV` unless the mode is ``native`` (an unknown mode is refused later, by name)."""
    if numerics_mode() != "native":
        os.environ.update(PORTABLE_TORCH_ENV)
