"""Generate a dataset from a preset and read it back: camera, a frame's pose, an object's ground truth.

Reads one room's PINHOLE camera and one frame's ``cam_from_world`` (COLMAP text files, via ``load_sequence``),
then the same frame's BOP files: ``scene_camera.json`` (``cam_from_world`` again, in mm) and ``scene_gt.json``
(``cam_from_object`` per instance), whose composition ``world_from_cam @ cam_from_object`` is the object's
``scene_from_object``, checked against ``objects.json``. Last, the rendered depth of the object's pixels,
back-projected with the GT pose into the object frame, is compared with its GT mesh (``bop/models``).

    python examples/01_generate_and_read.py                       # renders ci-tiny into runs/examples/dataset once
    python examples/01_generate_and_read.py --dataset STUDY/dataset --room room_001 --frame 5
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import trimesh

from synthleak.config import load_config
from synthleak.core.dataset import frame_name, load_sequence, read_index
from synthleak.geometry.poses import invert, make_pose, transform_points
from synthleak.render.pipeline import generate


def bop_pose(rotation: list[float], translation_mm: list[float]) -> np.ndarray:
    """A 4x4 pose from BOP's row-major rotation and millimetre translation."""
    return make_pose(np.reshape(rotation, (3, 3)), np.asarray(translation_mm) / 1000.0)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="ci-tiny", help="config generated when --dataset is not given")
    parser.add_argument("--out", type=Path, default=Path("runs/examples"), help="generates OUT/dataset")
    parser.add_argument("--dataset", type=Path, help="read this existing dataset instead (nothing generated)")
    parser.add_argument("--room", help="default: the first room of stages/index.json")
    parser.add_argument("--frame", type=int, default=0)
    args = parser.parse_args(argv)
    np.set_printoptions(precision=4, suppress=True)
    dataset = args.dataset or args.out / "dataset"
    if args.dataset is None and not (dataset / "manifest.json").is_file():  # manifest.json: a finished dataset
        generate(load_config(args.preset), dataset, progress=False)  # stages + renders, resumable

    room = args.room or read_index(dataset / "stages")["rooms"][0]["name"]
    seq, name = load_sequence(dataset / "scenes" / room), frame_name(args.frame)
    cam_from_world = seq.cam_from_world[name]
    print(f"{room}: {len(seq.frames)} frames ({len(seq.map_frames)} map, {len(seq.query_frames)} query), {seq.camera}")
    print(f"{name} cam_from_world (colmap/images.txt):\n{cam_from_world}")
    print(f"camera centre (world_from_cam translation): {invert(cam_from_world)[:3, 3]}")

    bop = seq.root / "bop"
    camera_entry = json.loads((bop / "scene_camera.json").read_text())[str(args.frame)]
    bop_cam_from_world = bop_pose(camera_entry["cam_R_w2c"], camera_entry["cam_t_w2c"])
    diff = np.abs(bop_cam_from_world - cam_from_world).max()
    print(f"BOP cam_from_world - COLMAP cam_from_world: max |diff| {diff:.1e}")
    instance = seq.instance(name)  # the furniture piece covering the most pixels of the frame
    obj = max((o for o in seq.objects if o.role == "object"), key=lambda o: int((instance == o.instance_id).sum()))
    entry = next(e for e in json.loads((bop / "scene_gt.json").read_text())[str(args.frame)]
                 if e["obj_id"] == obj.instance_id)
    scene_from_object = invert(bop_cam_from_world) @ bop_pose(entry["cam_R_m2c"], entry["cam_t_m2c"])
    print(f"object {obj.instance_id} ({obj.model_id}) scene_from_object (BOP):\n"
          f"{scene_from_object}")
    print(f"BOP scene_from_object - objects.json world_from_object: max |diff| "
          f"{np.abs(scene_from_object - obj.world_from_object).max():.1e}")

    v, u = np.nonzero(instance == obj.instance_id)  # the object's pixels, back-projected through pixel centres
    z, cam = seq.depth(name)[v, u], seq.camera
    points_cam = np.stack([(u + 0.5 - cam.cx) / cam.fx * z, (v + 0.5 - cam.cy) / cam.fy * z, z], axis=1)
    points_object = transform_points(invert(scene_from_object) @ invert(cam_from_world), points_cam)
    mesh = trimesh.load(bop / "models" / f"obj_{obj.instance_id:06d}.ply", force="mesh")  # millimetres
    sample = points_object[:: max(1, len(points_object) // 500)] * 1000.0
    _, distance_mm, _ = trimesh.proximity.closest_point(mesh, sample)
    print(f"depth of {len(u)} object pixels vs GT mesh: median {np.median(distance_mm):.3f} mm, "
          f"90th percentile {np.percentile(distance_mm, 90):.3f} mm ({len(sample)} sampled)")


if __name__ == "__main__":
    main()
