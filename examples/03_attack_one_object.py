"""The attack on one object: place it in a room from the server's answers to the attacker's images (paper Alg. 1).

The attacker photographs its own copy of an object (an attacker sequence: its local, here oracle, poses
``cam_from_object``) and sends the images to a room's server, which returns ``cam_from_world`` for those it
localizes. Each answer gives a hypothesis ``scene_from_object = inv(cam_from_world) @ cam_from_object``;
Alg. 1 keeps the one most answers agree with (within δr, δt), averages it over them, and reports the inlier
ratio ε = inliers / images sent. For an object that is in the room, the placement is scored against GT.

    python examples/03_attack_one_object.py                 # ci-tiny into runs/examples, localized live
    python examples/03_attack_one_object.py --study STUDY   # the server answers of a finished study's query log
    python examples/03_attack_one_object.py --study STUDY --room room_001 --object a02_sideboard --delta-t 0.5
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from synthleak.attack.local_model import oracle_local_poses
from synthleak.attack.run import run_attack
from synthleak.config import load_config
from synthleak.core.dataset import load_sequence, read_index
from synthleak.evaluate.score import score_placement
from synthleak.localize import Localizer, build_map
from synthleak.render.pipeline import generate
from synthleak.study import StudyPaths, read_query_log


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="ci-tiny")
    parser.add_argument("--out", type=Path, default=Path("runs/examples"), help="OUT/dataset, OUT/maps (no --study)")
    parser.add_argument("--study", type=Path, help="a finished study: read its query log instead of localizing")
    parser.add_argument("--dataset", type=Path, help="no --study: localize against this dataset's room "
                        "(default: OUT/dataset, generated if missing)")
    parser.add_argument("--room", help="default: the first room of stages/index.json")
    parser.add_argument("--object", help="attacker object id (default: the first one present in the room)")
    parser.add_argument("--tier", default="sift")
    parser.add_argument("--aligner", default="alg1", help="alg1 (the paper's), robust, pivot, sim3, upright")
    parser.add_argument("--delta-r", type=float, default=10.0, help="δr, degrees")
    parser.add_argument("--delta-t", type=float, default=0.25, help="δt, metres")
    args = parser.parse_args(argv)
    np.set_printoptions(precision=4, suppress=True)
    dataset = args.study / "dataset" if args.study else args.dataset or args.out / "dataset"
    if args.study is None and args.dataset is None and not (dataset / "manifest.json").is_file():
        generate(load_config(args.preset), dataset, progress=False)
    index = read_index(dataset / "stages")
    room = args.room or index["rooms"][0]["name"]
    objects = [o for o in index["attacker_objects"]
               if (o["id"] == args.object if args.object else room in o["present_in"])]
    if not objects:
        parser.error(f"no attacker object {args.object or 'present in ' + room} in {dataset / 'stages'}")
    obj = objects[0]
    attacker = load_sequence(dataset / "attackers" / obj["id"])
    local = oracle_local_poses(attacker)  # frame -> cam_from_object

    if args.study:  # what the study's server answered (None: not localized)
        log = StudyPaths(args.study).query_log(args.tier, room)
        server = {q["frame"]: np.array(q["cam_from_world"]) if q["success"] else None
                  for q in read_query_log(log) if q["attacker_object"] == obj["id"]}
    else:
        config = load_config(args.preset)
        map_dir = build_map(dataset / "scenes" / room, args.tier, args.out / "maps" / args.tier / room,
                            config.localize, progress=False)
        localizer = Localizer.load(map_dir, config.localize)
        server = {f: localizer.localize(attacker.image_path(f).read_bytes()).cam_from_world for f in attacker.frames}
    local = {f: pose for f, pose in local.items() if f in server}  # the images sent: N of eps = |inliers| / N
    alignment = run_attack(local, server, args.aligner, args.delta_r, args.delta_t)
    print(f"{obj['id']} against {args.tier}/{room}: {alignment.n_localized} of {alignment.n_total} images localized")
    print(f"{args.aligner} (δr {args.delta_r} deg, δt {args.delta_t} m): eps = {alignment.eps:.4f} "
          f"({len(alignment.inliers)} inliers of {alignment.n_total} sent)")
    print(f"scene_from_object (estimated):\n{alignment.scene_from_object}")

    gt_id = obj["present_in"].get(room)
    if gt_id is None:
        print(f"{obj['id']} is not in {room}: nothing to score (a small eps is the right answer)")
        return
    gt = load_sequence(dataset / "scenes" / room).objects_by_id()[gt_id]
    target = attacker.objects_by_id()[attacker.target_instance_id]
    score = score_placement(alignment.scene_from_object, gt.world_from_object, gt.extents, target.extents,
                            symmetry=gt.symmetry)
    print(f"scene_from_object (GT, instance {gt_id}):\n{gt.world_from_object}")
    print(f"placement error: rotation {score['rot_err_deg']:.4f} deg, translation {score['trans_err_m']:.4f} m, "
          f"IoU {score['iou3d']:.4f}")


if __name__ == "__main__":
    main()
