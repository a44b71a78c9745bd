"""Milliseconds per effect of ``synthleak.render.capture.capture`` on a 640x480 frame.

A synthetic frame (smooth gradients, texture and a depth ramp) goes through the ``phone``,
``phone-low-light`` and ``web-photo`` profiles (web-photo resized to 512 px: its 1024-2048 px would enlarge
a 640x480 frame, which it does not do); each runs ``--repeat`` times after a warm-up run (which builds the
cached encoder tables) and the median ms per stage is printed. The budget: everything except defocus and JPEG well
under 100 ms.

    python benchmarks/capture.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from synthleak.render.capture import capture
from synthleak.render.devices import profile

SLOW = {"defocus", "jpeg", "recompress"}
"""Stages outside the 100 ms budget."""


def frame(height: int = 480, width: int = 640, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A render-like linear frame (median ~0.1) and a z-depth map from 0.8 m to 6 m."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:height, 0:width].astype(np.float32)
    base = 0.05 + 0.25 * (u / width)[..., None] * np.array([1.0, 0.8, 0.6], np.float32)
    texture = 0.05 * rng.random((height // 8, width // 8, 3), dtype=np.float32).repeat(8, 0).repeat(8, 1)
    depth = (0.8 + 5.2 * v / height).astype(np.float32)
    return (base + texture).astype(np.float32), depth


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    linear, depth = frame()
    for name in ("phone", "phone-low-light", "web-photo"):
        params = profile(name)
        if params.resize is not None:
            params = replace(params, resize=replace(params.resize, longest_px=512))
        capture(linear, params, 0, depth)  # warm-up: encoder tables, disc kernels
        runs: list[dict[str, float]] = []
        totals = []
        for k in range(args.repeat):
            timings: dict[str, float] = {}
            start = time.perf_counter()
            capture(linear, params, k, depth, timings=timings)
            totals.append(time.perf_counter() - start)
            runs.append(timings)
        print(f"{name} (640x480, median of {args.repeat}):")
        fast = 0.0
        for stage in runs[0]:
            ms = statistics.median(r[stage] for r in runs) * 1e3
            fast += 0.0 if stage in SLOW else ms
            print(f"  {stage:<18} {ms:8.2f} ms{'  (outside the budget)' if stage in SLOW else ''}")
        print(f"  {'all but defocus/JPEG':<18} {fast:8.2f} ms")
        print(f"  {'total':<18} {statistics.median(totals) * 1e3:8.2f} ms")


if __name__ == "__main__":
    main()
