"""Render throughput: frames per second at 640x480 on one real room stage (study-like preset), and the
time per stage of a tiny ``generate`` run. Prints figures; asserts nothing.

    python benchmarks/render.py [--frames 6] [--spp 4] [--integrator direct]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

import numpy as np

from synthleak.config import RenderConfig, load_config
from synthleak.core.types import Camera
from synthleak.render.pipeline import generate, load_stage
from synthleak.render.raycast import RaycastGT
from synthleak.render.registry import get_renderer
from synthleak.render.trajectories import walkthrough
from synthleak.scene.generate import write_study_stages
from synthleak.seeding import derive_seed, make_rng


def bench_room(stage: Path, config: RenderConfig, frames: int) -> None:
    scene = load_stage(stage)
    renderer = get_renderer(config)
    t0 = time.perf_counter()
    renderer.prepare(scene)
    prep = time.perf_counter() - t0
    camera = Camera.from_hfov(config.width, config.height, config.hfov_deg)
    poses = walkthrough(scene, frames, make_rng(0, "bench"))
    gt = RaycastGT(scene.meshes)
    t0 = time.perf_counter()
    for pose in poses:
        gt.render(camera, pose)
    t_gt = (time.perf_counter() - t0) / frames
    t0 = time.perf_counter()
    frames_out = [renderer.render(camera, pose, derive_seed(0, "bench", i)) for i, pose in enumerate(poses)]
    t_frame = (time.perf_counter() - t0) / frames
    # seed noise: the same view with another seed (mean absolute difference, 8-bit levels)
    other = renderer.render(camera, poses[0], 12345).rgb.astype(float)
    noise = float(np.abs(other - frames_out[0].rgb).mean())
    triangles = sum(len(m.faces) for m in scene.meshes)
    passes = len(getattr(renderer, "_scenes", [])) or 1
    print(
        f"{stage.name}: {triangles} triangles, {len(scene.lights)} lights, {passes} passes; "
        f"{config.width}x{config.height} {config.integrator} spp={config.spp}: prepare {prep:.2f} s, "
        f"{t_frame:.2f} s/frame = {1 / t_frame:.2f} fps (ray-cast GT {t_gt * 1000:.0f} ms of it); "
        f"seed-to-seed noise {noise:.2f} levels"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--spp", type=int, default=4)
    parser.add_argument("--integrator", default="direct")
    args = parser.parse_args()
    study = load_config("ci-tiny")
    with tempfile.TemporaryDirectory() as tmp:
        stages = Path(tmp) / "stages"
        t0 = time.perf_counter()
        write_study_stages(study, stages, progress=False)
        print(f"stages for ci-tiny: {time.perf_counter() - t0:.1f} s")
        config = dataclasses.replace(study.render, width=640, height=480, spp=args.spp, integrator=args.integrator)
        bench_room(next(stages.glob("room_*.usda")), config, args.frames)
        tiny = dataclasses.replace(
            study,
            render=dataclasses.replace(
                study.render, width=320, height=240, spp=args.spp, scene_frames=4, attacker_frames=4
            ),
        )
        out = Path(tmp) / "tiny"
        t0 = time.perf_counter()
        generate(tiny, out, progress=False)
        total = time.perf_counter() - t0
        n_stages = len(list((out / "stages").glob("*.usda")))
        print(
            f"tiny generate (ci-tiny at 320x240, 4 frames per sequence): {total:.1f} s for "
            f"{n_stages} stages, {total / n_stages:.1f} s per stage"
        )


if __name__ == "__main__":
    main()
