"""Frames per second of every importable render backend on one synthetic room, printed as a table.

    python benchmarks/render_backends.py                      # 640x480, 3 timed frames per backend
    /work/venv-blender/bin/python benchmarks/render_backends.py   # the venv where bpy also imports
    python benchmarks/render_backends.py --docs docs/renderers.md  # also writes the table into the page's block

The room: a 5 x 4 x 2.6 m shell (textured floor, walls, ceiling) and 20 boxes / cylinders (~6k triangles),
two sphere lights and a rect light, ambient fill. Each backend renders full frames (RGB + z-depth +
instance ids) from cameras inside the room; ``prepare`` and the first (warm-up) frame are timed apart.
mitsuba runs its ``direct`` integrator at ``--mitsuba-spp`` (default 16) as the reference for the ratio
(its default lighting, one pass per light, and, where the backend offers it, ``lighting="physical"`` and the
vectorised ``llvm_ad_rgb`` variant, which needs libLLVM >= 16).
"""

from __future__ import annotations

import argparse
import builtins
import importlib.util
import inspect
import os
import time
from collections.abc import Callable

import numpy as np
import trimesh

from synthleak.config import RenderConfig
from synthleak.core.types import Camera, Light, RenderMesh, RenderScene
from synthleak.geometry.poses import look_at, make_pose
from synthleak.seeding import make_rng


def _noise_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    coarse = rng.integers(40, 220, size=(size // 16, size // 16, 3)).astype(np.uint8)
    fine = rng.integers(-20, 20, size=(size, size, 3))
    return np.clip(coarse.repeat(16, 0).repeat(16, 1) + fine, 0, 255).astype(np.uint8)


def _quad(name: str, iid: int, corners: np.ndarray, texture: np.ndarray) -> RenderMesh:
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=np.float64)
    return RenderMesh(name, iid, corners, np.array([[0, 1, 2], [0, 2, 3]]), uv, texture)


def benchmark_room(seed: int = 0) -> RenderScene:
    """Shell pieces (ids 1-6) facing inwards and 20 objects (ids 10-29) with textures or flat colours."""
    rng = make_rng(seed, "benchmark_room")
    sx, sy, sz = 5.0, 4.0, 2.6
    c = np.array([[x, y, z] for z in (0, sz) for y in (0, sy) for x in (0, sx)], dtype=np.float64)
    quads = {  # counter-clockwise seen from inside the room
        "floor": [0, 1, 3, 2], "ceiling": [4, 6, 7, 5], "wall_s": [0, 4, 5, 1],
        "wall_n": [2, 3, 7, 6], "wall_w": [0, 2, 6, 4], "wall_e": [1, 5, 7, 3],
    }
    meshes = [_quad(n, i + 1, c[idx], _noise_texture(rng)) for i, (n, idx) in enumerate(quads.items())]
    for k in range(20):
        size = rng.uniform(0.2, 0.8, size=3)
        pos = np.array([rng.uniform(0.6, sx - 0.6), rng.uniform(0.6, sy - 0.6), size[2] / 2])
        if k % 2:
            m = trimesh.creation.cylinder(radius=size[0] / 2, height=size[2], sections=96)
        else:
            m = trimesh.creation.icosphere(subdivisions=3, radius=size[0] / 2) if k % 4 == 0 else \
                trimesh.creation.box(extents=size)
        verts = np.asarray(m.vertices) + pos
        uv = (verts[:, :2] - verts[:, :2].min(0)) / np.maximum(np.ptp(verts[:, :2], axis=0), 1e-9)
        tex = _noise_texture(rng, 128) if k % 3 == 0 else None
        color = tuple(float(x) for x in rng.uniform(0.15, 0.85, size=3))
        meshes.append(RenderMesh(f"obj{k}", 10 + k, verts, np.asarray(m.faces), uv, tex, base_color=color))
    lights = [
        Light("bulb_a", "sphere", make_pose(np.eye(3), [1.5, 1.2, 2.3]), intensity=6.0),
        Light("bulb_b", "sphere", make_pose(np.eye(3), [3.8, 2.9, 2.3]), intensity=5.0),
        Light("panel", "rect", make_pose(np.eye(3), [2.5, 2.0, 2.55]), intensity=6.0, size=(0.8, 0.8)),
    ]
    return RenderScene(meshes=meshes, lights=lights, instances={}, ambient=0.03, source="benchmark_room")


def benchmark_views(width: int, height: int, n: int) -> list[tuple[Camera, np.ndarray]]:
    cam = Camera.from_hfov(width, height, 65.0)
    out = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([2.5 + 1.8 * np.cos(a), 2.0 + 1.4 * np.sin(a), 1.5])
        out.append((cam, look_at(eye, np.array([2.5, 2.0, 0.5]))))
    return out


def _factories(mitsuba_spp: int, spp: int) -> dict[str, tuple[str, Callable[[], object]]]:
    def pyrender() -> object:
        from synthleak.render.pyrender_backend import create_pyrender_renderer

        return create_pyrender_renderer(RenderConfig(renderer="pyrender", spp=spp))

    def blender() -> object:
        from synthleak.render.blender_backend import create_blender_renderer

        return create_blender_renderer(RenderConfig(renderer="blender", spp=spp))

    def mitsuba(**kwargs: str) -> Callable[[], object]:
        def make() -> object:
            from synthleak.render.mitsuba_backend import MitsubaRenderer

            return MitsubaRenderer(spp=mitsuba_spp, integrator="direct", filter="box", **kwargs)

        return make

    factories = {
        "pyrender": ("pyrender", pyrender),
        f"blender {spp} spp": ("bpy", blender),
        f"mitsuba direct {mitsuba_spp} spp": ("mitsuba", mitsuba()),
    }
    if importlib.util.find_spec("mitsuba") is not None:
        from synthleak.render.mitsuba_backend import MitsubaRenderer

        if "lighting" in inspect.signature(MitsubaRenderer).parameters:  # one pass, all emitters at once
            factories[f"mitsuba direct {mitsuba_spp} physical"] = ("mitsuba", mitsuba(lighting="physical"))
        from synthleak.render.mitsuba_backend import find_libllvm

        try:  # vectorised, all lights in one pass
            find_libllvm()
            factories[f"mitsuba llvm direct {mitsuba_spp} spp"] = ("mitsuba", mitsuba(variant="llvm_ad_rgb"))
        except ImportError as exc:
            print(f"mitsuba llvm_ad_rgb skipped: {exc}")
    return factories


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--frames", type=int, default=3, help="timed frames per backend (after a warm-up)")
    parser.add_argument("--spp", type=int, default=8, help="blender samples per pixel")
    parser.add_argument("--mitsuba-spp", type=int, default=16)
    parser.add_argument("--docs", metavar="PAGE",
                        help="write the table into PAGE's block 'render-backends-<mitsuba spp>spp'")
    args = parser.parse_args()
    printed: list[str] = []

    def print(line: str) -> None:  # noqa: A001 (the table also goes to --docs)
        printed.append(line)
        builtins.print(line)

    scene = benchmark_room()
    views = benchmark_views(args.width, args.height, args.frames + 1)
    tris = sum(len(m.faces) for m in scene.meshes)
    print(f"scene: {len(scene.meshes)} meshes, {tris} triangles, {args.width}x{args.height}, "
          f"{args.frames} timed frames; {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    rows = []
    for label, (module, factory) in _factories(args.mitsuba_spp, args.spp).items():
        if importlib.util.find_spec(module) is None:
            rows.append((label, None, None, None, f"{module} not importable here"))
            continue
        t0 = time.perf_counter()
        renderer = factory()
        renderer.prepare(scene)  # type: ignore[attr-defined]
        t1 = time.perf_counter()
        renderer.render(*views[0], seed=0)  # type: ignore[attr-defined]
        t2 = time.perf_counter()
        for i, (cam, pose) in enumerate(views[1:], start=1):
            renderer.render(cam, pose, seed=i)  # type: ignore[attr-defined]
        per_frame = (time.perf_counter() - t2) / args.frames
        rows.append((label, t1 - t0, t2 - t1, per_frame, ""))

    ref = next((r[3] for r in rows if r[0].startswith("mitsuba") and r[3]), None)
    print(f"{'backend':<32}{'prepare s':>10}{'1st frame s':>12}{'s/frame':>10}{'fps':>8}{'x mitsuba':>11}")
    for label, prep, first, per, note in rows:
        if per is None:
            print(f"{label:<32}{'-':>10}{'-':>12}{'-':>10}{'-':>8}{'-':>11}  ({note})")
            continue
        speedup = f"{ref / per:.1f}" if ref else "-"
        print(f"{label:<32}{prep:>10.2f}{first:>12.2f}{per:>10.3f}{1.0 / per:>8.2f}{speedup:>11}")
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (other jobs on the machine inflate all rows)")
    if args.docs:
        from synthleak.evaluate.doc_blocks import write_benchmark_block

        text = "\n".join(printed[:-1])
        write_benchmark_block(args.docs, f"render-backends-{args.mitsuba_spp}spp", f"```\n{text}\n```")


if __name__ == "__main__":
    main()
