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


def simd_fallback_env(opencv_baseline: bool = False) -> dict[str, str]:
    """Environment variables that make a fresh Python process compute as an older CPU would: numpy's dispatched
    SIMD features all off (its baseline code only), OpenBLAS's generic kernel and OpenCV's AVX-512 paths off (an
    AVX2 host); ``opencv_baseline``: OpenCV's AVX2, FMA3 and AVX paths off too (a pre-2013 host). For tests and
    ``benchmarks/portability.py``: the same seed must give the same bytes with and without them."""
    from numpy._core import _multiarray_umath as umath

    found = [name for name in umath.__cpu_dispatch__ if umath.__cpu_features__.get(name)]
    opencv = OPENCV_AVX512 + (OPENCV_PRE_AVX2 if opencv_baseline else ())
    return {"NPY_DISABLE_CPU_FEATURES": " ".join(found), "OPENBLAS_CORETYPE": FALLBACK_OPENBLAS_CORE,
            "OPENCV_CPU_DISABLE": ",".join(opencv)}


OPENCV_AVX512 = ("AVX512_SKX", "AVX512_COMMON", "AVX512_KNL", "AVX512_KNM", "AVX512_CNL", "AVX512_CLX")
"""OpenCV's AVX-512 dispatch targets (``OPENCV_CPU_DISABLE``): off, OpenCV computes as on an AVX2 host."""
OPENCV_PRE_AVX2 = ("AVX2", "FMA3", "AVX", "POPCNT", "SSSE3")
"""OpenCV's older dispatch targets: off too, as on a host without AVX2 and FMA. float32 ``GaussianBlur`` and
``filter2D`` give other last bits there (measured: not between AVX-512 and AVX2), so the texture generators'
blurs are CPU-dependent on such hosts (``docs/determinism.md``); the capture model is not."""


def norm(values: np.ndarray, axis: int | None = None, keepdims: bool = False) -> np.ndarray:
    """Euclidean norm without BLAS: ``np.linalg.norm`` of a vector is ``sqrt(dot(x, x))``, whose summation
    order is the BLAS kernel's (other bits on another CPU); an elementwise square and numpy's sum are not."""
    values = np.asarray(values, dtype=np.float64)
    return np.sqrt((values * values).sum(axis=axis, keepdims=keepdims))


def result_float(value: float) -> float:
    """A finite results value on :data:`RESULT_STEP`, then to :data:`RESULT_DIGITS` significant digits."""
    return float(f"{float(snap(value, RESULT_STEP)):.{RESULT_DIGITS}g}")


def matmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` for small float64 matrices or vectors in Python floats: every product and sum an IEEE operation
    in a fixed order, so the same bits on every CPU (numpy's ``@`` calls BLAS, whose kernel and summation order
    depend on the CPU)."""
    a64, b64 = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    left = a64[None, :] if a64.ndim == 1 else a64
    right = b64[:, None] if b64.ndim == 1 else b64
    if left.shape[1] != right.shape[0]:
        raise ValueError(f"matmul: shapes {a64.shape} and {b64.shape} do not chain")
    rows, cols = left.tolist(), right.T.tolist()
    out = np.array([[sum_in_order(x * y for x, y in zip(r, c, strict=True)) for c in cols] for r in rows])
    if a64.ndim == 1:
        out = out[0]
    if b64.ndim == 1:
        out = out[..., 0]
    return out


def sum_in_order(values) -> float:
    """Left-to-right float sum (``sum`` starting from 0.0): one IEEE addition after another."""
    total = 0.0
    for v in values:
        total += v
    return total


def inv3(m: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 float64 matrix by its adjugate, in Python floats (the same bits on every CPU, unlike
    LAPACK's); a ValueError when it is singular."""
    (a, b, c), (d, e, f), (g, h, i) = np.asarray(m, dtype=np.float64).tolist()
    co = [[e * i - f * h, c * h - b * i, b * f - c * e],
          [f * g - d * i, a * i - c * g, c * d - a * f],
          [d * h - e * g, b * g - a * h, a * e - b * d]]
    det = a * co[0][0] + b * co[1][0] + c * co[2][0]
    if det == 0.0:
        raise ValueError("inv3: singular matrix")
    return np.array([[v / det for v in row] for row in co])


def apply_matrix3(image: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) float32 with each pixel ``p`` replaced by ``m @ p``, as elementwise float32 products
    and sums in a fixed order (``cv2.transform`` and ``@`` pick SIMD and FMA paths by CPU)."""
    m32 = np.asarray(m, dtype=np.float32)
    x = np.asarray(image, dtype=np.float32)
    out = np.empty_like(x)
    for row in range(3):
        out[..., row] = x[..., 0] * m32[row, 0]
        out[..., row] += x[..., 1] * m32[row, 1]
        out[..., row] += x[..., 2] * m32[row, 2]
    return out


TRANSCENDENTAL_STEP = 1e-12
"""Grid of :func:`cos`, :func:`sin`, :func:`exp` and :func:`power` results (values of order 1)."""


def _stable(values: np.ndarray, like: object) -> np.ndarray:
    out = snap(values, TRANSCENDENTAL_STEP)
    dtype = np.asarray(like).dtype
    return out.astype(np.float32) if dtype == np.float32 else out


def cos(x: np.ndarray | float) -> np.ndarray:
    """``np.cos`` evaluated in float64 and snapped to :data:`TRANSCENDENTAL_STEP` (float32 in, float32 out):
    numpy's float32 and float64 ``cos`` pick SIMD kernels by CPU whose last bits differ; float64 and the grid
    leave a difference only within ~1e-16 of a grid midpoint."""
    return _stable(np.cos(np.asarray(x, dtype=np.float64)), x)


def sin(x: np.ndarray | float) -> np.ndarray:
    """``np.sin``, portable as :func:`cos`."""
    return _stable(np.sin(np.asarray(x, dtype=np.float64)), x)


def exp(x: np.ndarray | float) -> np.ndarray:
    """``np.exp``, portable as :func:`cos` (for arguments whose results are of order 1 or less)."""
    return _stable(np.exp(np.asarray(x, dtype=np.float64)), x)


def power(x: np.ndarray | float, exponent: float) -> np.ndarray:
    """``x ** exponent`` for a non-integer ``exponent`` and ``x`` >= 0 of order 1, portable as :func:`cos`."""
    return _stable(np.power(np.asarray(x, dtype=np.float64), float(exponent)), x)
