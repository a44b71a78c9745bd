"""Milliseconds per effect of ``synthleak.render.capture.capture`` on a 640x480 frame.

A synthetic frame (smooth gradients, texture and a depth ramp) goes through the ``phone``,
``phone-low-light`` and ``web-photo`` profiles (web-photo resized to 512 px: its 1024-2048 px would enlarge
a 640x480 frame, which it does not do); each runs ``--repeat`` times after a warm-up run (which builds the
cached encoder tables) and the median ms per stage is printed. The budget: everything except defocus and JPEG well
under 100 ms.

    python benchmarks/capture.py [--repeat 5] [--render]

Each profile also gets a ``motion_blur`` row (the hand shake drawn for photo 0 over the shutter AE chose) and,
with ``--render``, the ratio of the whole capture step to the render time of one 640x480 mitsuba frame of the
example stage at the study's 4 spp (the budget: +10 %).
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace

import numpy as np

from synthleak.core.types import Camera
from synthleak.render.capture import capture
from synthleak.render.devices import draw_device, profile
from synthleak.render.motion_blur import MotionBlur

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
    parser.add_argument("--render", action="store_true", help="also time a 640x480 mitsuba frame (the budget)")
    args = parser.parse_args()
    render_ms = render_time_ms() if args.render else None
    linear, depth = frame()
    camera = Camera.from_hfov(640, 480, 65.0)
    for name in ("phone", "phone-low-light", "web-photo"):
        params = replace(profile(name), motion_blur=draw_device(name, 0).motion_blur)
        if params.resize is not None:
            params = replace(params, resize=replace(params.resize, longest_px=512))
        capture(linear, params, 0, depth, camera=camera)  # warm-up: encoder tables, disc kernels
        runs: list[dict[str, float]] = []
        totals = []
        for k in range(args.repeat):
            timings: dict[str, float] = {}
            start = time.perf_counter()
            capture(linear, params, k, depth, timings=timings, camera=camera)
            totals.append(time.perf_counter() - start)
            runs.append(timings)
        print(f"{name} (640x480, median of {args.repeat}):")
        fast = 0.0
        for stage in runs[0]:
            ms = statistics.median(r[stage] for r in runs) * 1e3
            fast += 0.0 if stage in SLOW else ms
            print(f"  {stage:<18} {ms:8.2f} ms{'  (outside the budget)' if stage in SLOW else ''}")
        print(f"  {'all but defocus/JPEG':<18} {fast:8.2f} ms")
        total_ms = statistics.median(totals) * 1e3
        print(f"  {'total':<18} {total_ms:8.2f} ms")
        if render_ms is not None:
            print(f"  {'capture / render':<18} {100 * total_ms / render_ms:8.1f} %  (render {render_ms:.0f} ms)")
    strong = replace(profile("phone-low-light"), motion_blur=MotionBlur(angular_velocity_deg_s=(20.0, 20.0, 5.0)))
    timings = {}
    record = capture(linear, strong, 0, depth, timings=timings, camera=camera).record
    print(f"motion_blur at {record['motion_blur_px']:.1f} px, {record['motion_blur_samples']} samples (worst case): "
          f"{timings['motion_blur'] * 1e3:.2f} ms")
    walk = replace(strong, motion_blur=MotionBlur(angular_velocity_deg_s=(20.0, 20.0, 5.0), velocity_m_s=(0.5, 0, 0.5)))
    timings = {}
    record = capture(linear, walk, 0, depth, timings=timings, camera=camera).record
    print(f"motion_blur with translation (depth-aware remap), {record['motion_blur_samples']} samples: "
          f"{timings['motion_blur'] * 1e3:.2f} ms")


def render_time_ms(repeat: int = 2) -> float:
    """Median ms of one 640x480 mitsuba frame (4 spp, the study's) of the example stage, after ``prepare``."""
    from synthleak.config import RenderConfig
    from synthleak.paths import scenes_usd_dir
    from synthleak.render.pipeline import load_stage
    from synthleak.render.registry import get_renderer
    from synthleak.render.trajectories import walkthrough

    scene = load_stage(scenes_usd_dir() / "example" / "room_example.usda")
    renderer = get_renderer(RenderConfig(spp=4))
    renderer.prepare(scene)
    pose = walkthrough(scene, 3, np.random.default_rng(0))[1]
    camera = Camera.from_hfov(640, 480, 65.0)
    times = []
    for k in range(repeat + 1):
        start = time.perf_counter()
        renderer.render(camera, pose, k)
        times.append(time.perf_counter() - start)
    return statistics.median(times[1:]) * 1e3


if __name__ == "__main__":
    main()
