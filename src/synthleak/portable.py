"""Numbers written to disk that are the same bytes on every x86-64 CPU.

numpy dispatches float64 transcendental functions (``sin``, ``cos``, ``exp``, ``arctan2``, ...) to
CPU-specific code (AVX-512 hosts use other kernels than AVX2 hosts) and OpenBLAS picks its matrix kernels
by CPU (SkylakeX, Haswell, Zen: other summation orders), so the same seed gives results that differ in the
last bits from one machine to another (measured: a bicycle's mesh points ``4.6e-18`` on one CPU, ``4.5e-18``
on another). Basic arithmetic and rounding are exact IEEE operations everywhere, so snapping a value to a
grid coarser than those last-bit differences gives the same value on every CPU, except where a value lies
within a few ulps of a grid midpoint (probability ~ulp / step per value: about 1e-10 for a metre-scale
coordinate on the micrometre grid). Every seeded float the generator writes goes through :func:`snap` with
the step of its kind below (``docs/determinism.md``)."""

from __future__ import annotations

import numpy as np

LENGTH_STEP_M = 1e-6
"""Mesh points, extents, sizes (metres): 1 micrometre, far below a pixel at any rendered distance."""
POSE_STEP = 1e-9
"""Entries of written 4x4 poses (rotation entries, translations in metres)."""
UNIT_STEP = 1e-6
"""Dimensionless values: texture coordinates, colours, intensities relative to their scale."""
RESULT_STEP = 1e-9
"""Results (errors in degrees and metres, ratios, scores): residuals of 1e-15 are rounding noise, not zero."""
RESULT_DIGITS = 6
"""Significant digits of a results float: the attack's and the presence classifier's arithmetic (BLAS,
dispatched ``arctan2``, scikit-learn's solver) differs across CPUs by ~1e-9 relative at most, measured."""


def snap(values: np.ndarray | float, step: float) -> np.ndarray:
    """``values`` rounded to the nearest multiple of ``step`` (float64; halves to even); -0.0 becomes 0.0."""
    out = np.rint(np.asarray(values, dtype=np.float64) / step) * step
    out += 0.0  # -0.0 -> 0.0: a sign bit would differ where a tiny value changed sign between CPUs
    return out


def snap_pose(pose: np.ndarray) -> np.ndarray:
    """A 4x4 pose with every entry on the :data:`POSE_STEP` grid (the bottom row stays exactly 0 0 0 1)."""
    return snap(pose, POSE_STEP)


FALLBACK_OPENBLAS_CORE = "Prescott"
"""The OpenBLAS kernel :func:`simd_fallback_env` forces: the generic SSE3 one, unlike any modern host's."""


def simd_fallback_env() -> dict[str, str]:
    """Environment variables that make a fresh Python process compute as an older CPU would: numpy's dispatched
    SIMD features all off (its baseline code only) and OpenBLAS's generic kernel. For tests and
    ``benchmarks/portability.py``: the same seed must give the same bytes with and without them."""
    from numpy._core import _multiarray_umath as umath

    found = [name for name in umath.__cpu_dispatch__ if umath.__cpu_features__.get(name)]
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(found), "OPENBLAS_CORETYPE": FALLBACK_OPENBLAS_CORE}


def norm(values: np.ndarray, axis: int | None = None, keepdims: bool = False) -> np.ndarray:
    """Euclidean norm without BLAS: ``np.linalg.norm`` of a vector is ``sqrt(dot(x, x))``, whose summation
    order is the BLAS kernel's (other bits on another CPU); an elementwise square and numpy's sum are not."""
    values = np.asarray(values, dtype=np.float64)
    return np.sqrt((values * values).sum(axis=axis, keepdims=keepdims))


def result_float(value: float) -> float:
    """A finite results value on :data:`RESULT_STEP`, then to :data:`RESULT_DIGITS` significant digits."""
    return float(f"{float(snap(value, RESULT_STEP)):.{RESULT_DIGITS}g}")
