"""Build a localization map from a room's walk-through and localize one held-out genuine query against it.

The map is triangulated from the map frames' GT poses (``synthleak.localize.build_map``, HLoc's "triangulation
from poses"); ``Localizer`` answers a query image (encoded bytes, as a client sends them) with the server's
``cam_from_world``, compared here with the frame's GT pose (rotation in degrees, camera centre in metres).

    python examples/02_map_and_localize.py                  # renders ci-tiny into runs/examples/dataset once
    python examples/02_map_and_localize.py --dataset STUDY/dataset --room room_001 --query 000009.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from synthleak.config import load_config
from synthleak.core.dataset import load_sequence, read_index
from synthleak.geometry.poses import camera_centre, rotation_error_deg
from synthleak.localize import Localizer, build_map
from synthleak.render.pipeline import generate


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="ci-tiny", help="config of the dataset (and of the map's settings)")
    parser.add_argument("--out", type=Path, default=Path("runs/examples"), help="OUT/dataset (if generated), OUT/maps")
    parser.add_argument("--dataset", type=Path, help="an existing dataset (default: OUT/dataset, generated if missing)")
    parser.add_argument("--room", help="default: the first room of stages/index.json")
    parser.add_argument("--query", help="a held-out frame of the room (default: its first query frame)")
    parser.add_argument("--tier", default="sift", help="feature tier of the map")
    args = parser.parse_args(argv)
    np.set_printoptions(precision=4, suppress=True)
    config = load_config(args.preset)
    dataset = args.dataset or args.out / "dataset"
    if args.dataset is None and not (dataset / "manifest.json").is_file():
        generate(config, dataset, progress=False)

    room = args.room or read_index(dataset / "stages")["rooms"][0]["name"]
    seq = load_sequence(dataset / "scenes" / room)
    map_dir = build_map(seq.root, args.tier, args.out / "maps" / args.tier / room, config.localize, progress=False)
    localizer = Localizer.load(map_dir, config.localize)
    print(f"map {map_dir}: {localizer.data.meta['num_images']} images, {localizer.data.meta['num_points']} points")

    frame = args.query or seq.query_frames[0]
    if frame not in seq.query_frames:
        parser.error(f"--query {frame}: not a held-out query of {room} ({', '.join(seq.query_frames)})")
    result = localizer.localize(seq.image_path(frame).read_bytes())
    print(f"query {room}/{frame}: success {result.success}, {result.num_inliers} inliers of {result.num_matches} "
          f"matches, {1000 * result.timings['total']:.0f} ms")
    if not result.success:
        raise SystemExit("not localized")
    gt = seq.cam_from_world[frame]
    print(f"cam_from_world (server):\n{result.cam_from_world}\ncam_from_world (GT):\n{gt}")
    rot_err = rotation_error_deg(result.cam_from_world, gt)
    trans_err = float(np.linalg.norm(camera_centre(result.cam_from_world) - camera_centre(gt)))
    print(f"error: rotation {rot_err:.4f} deg, translation {trans_err:.4f} m")


if __name__ == "__main__":
    main()
