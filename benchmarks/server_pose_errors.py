"""Why the aligners differ: the server's pose errors for attacker queries of present objects, and per-pair
placement errors of each aligner, on a finished study's query logs (nothing is localized again or written).

Usage:
    python benchmarks/server_pose_errors.py STUDY_DIR CONFIG [--aligners alg1,robust,pivot] [--pairs]

Per tier, over the localized attacker queries of GT-present pairs whose pose is near the truth (rotation error
< 10°, camera centre < 0.5 m; the others are counted as gross): the rotation error split into *swing* (about the
camera's x/y axes) and *turn* (about its optical axis); the camera-centre error across / along the viewing ray;
the object centre placed by the image's own hypothesis (Alg. 1's per-image ``R̂ᵀR``, ``R̂ᵀ(t − t̂)``) across /
along the ray; and the rotation read from camera centres (what a joint centre fit like ``robust``'s leans on)
against the mean of per-image rotations. The truth of a query is its attacker pose ``cam_from_object`` composed
with the room's GT ``world_from_object`` (exact for the identical model, a few % off for scaled variants).
``--pairs`` prints every GT-present pair's rotation / centre error per aligner at 10°/0.25 m.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from synthleak.attack.align import _centres, _per_image_hypotheses, chordal_mean, umeyama
from synthleak.attack.local_model import oracle_local_poses
from synthleak.config import load_config
from synthleak.core.dataset import load_sequence, read_index
from synthleak.geometry.poses import invert
from synthleak.study import StudyPaths, attack_rows, read_query_log


def _rot_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(a @ b.T).magnitude()))


def pose_errors(paths: StudyPaths, tier: str, rooms: list[str]) -> dict[str, list[float]]:
    """Server error components of every localized attacker query of a GT-present pair in ``tier``."""
    index = read_index(paths.dataset / "stages")
    scenes = {r: load_sequence(paths.dataset / "scenes" / r).objects_by_id() for r in rooms}
    out: dict[str, list[float]] = {k: [] for k in (
        "rot", "swing", "turn", "centre_across", "centre_along", "obj_across", "obj_along", "gross",
        "pair_rot_from_rot", "pair_rot_from_centres")}
    for obj in index["attacker_objects"]:
        seq = load_sequence(paths.dataset / "attackers" / obj["id"])
        local = oracle_local_poses(seq)
        centre_obj = np.zeros(3)  # the target's box is centred on its object frame (to_object_frame)
        for room in rooms:
            gt_id = obj.get("present_in", {}).get(room)
            if gt_id is None or gt_id not in scenes[room]:
                continue
            world_from_obj = np.asarray(scenes[room][gt_id].world_from_object)
            recs = [q for q in read_query_log(paths.queries / tier / room / "queries.jsonl")
                    if q["attacker_object"] == obj["id"] and q["success"] and q["frame"] in local]
            loc, srv = [], []
            for q in recs:
                est, truth = np.array(q["cam_from_world"]), local[q["frame"]] @ invert(world_from_obj)
                rot, centre = _rot_deg(est[:3, :3], truth[:3, :3]), np.linalg.norm(_centres(est[None])
                                                                                   - _centres(truth[None]))
                if rot >= 10 or centre >= 0.5:
                    out["gross"].append(1.0)
                    continue
                out["gross"].append(0.0)
                loc.append(local[q["frame"]])
                srv.append(est)
                rotvec = Rotation.from_matrix(est[:3, :3] @ truth[:3, :3].T).as_rotvec()  # camera frame
                out["rot"].append(np.degrees(np.linalg.norm(rotvec)))
                out["swing"].append(np.degrees(np.linalg.norm(rotvec[:2])))
                out["turn"].append(np.degrees(abs(rotvec[2])))
                obj_cam = truth[:3, :3] @ world_from_obj[:3, :3] @ centre_obj + truth[:3, :3] @ world_from_obj[
                    :3, 3] + truth[:3, 3]
                ray = obj_cam / np.linalg.norm(obj_cam)
                d_c = truth[:3, :3] @ (_centres(est[None])[0] - _centres(truth[None])[0])  # camera frame
                out["centre_along"].append(abs(d_c @ ray))
                out["centre_across"].append(np.linalg.norm(d_c - (d_c @ ray) * ray))
                hyp_r, hyp_t = _per_image_hypotheses(local[q["frame"]][None], est[None])
                placed = hyp_r[0] @ centre_obj + hyp_t[0]
                d_o = truth[:3, :3] @ (placed - (world_from_obj[:3, :3] @ centre_obj + world_from_obj[:3, 3]))
                out["obj_along"].append(abs(d_o @ ray))
                out["obj_across"].append(np.linalg.norm(d_o - (d_o @ ray) * ray))
            if len(loc) >= 3:
                loc_a, srv_a = np.array(loc), np.array(srv)
                hyp_r, _ = _per_image_hypotheses(loc_a, srv_a)
                out["pair_rot_from_rot"].append(_rot_deg(chordal_mean(hyp_r), world_from_obj[:3, :3]))
                _, rot_c, _ = umeyama(_centres(loc_a), _centres(srv_a), with_scale=False)
                out["pair_rot_from_centres"].append(_rot_deg(rot_c, world_from_obj[:3, :3]))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("config")
    parser.add_argument("--aligners", default="alg1,robust,pivot")
    parser.add_argument("--pairs", action="store_true")
    args = parser.parse_args()
    paths, config = StudyPaths(args.study), load_config(args.config)
    rooms = [r["name"] for r in read_index(paths.dataset / "stages")["rooms"]]
    print("| tier | n near | gross | med rot ° | med swing ° | med turn ° | centre across m | centre along m | "
          "object across m | object along m | pairs | pair rot from rotations ° | pair rot from centres ° |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for tier in config.localize.tiers:
        e = pose_errors(paths, tier, rooms)
        med = {k: float(np.median(v)) if v else float("nan") for k, v in e.items()}
        print(f"| {tier} | {len(e['rot'])} | {int(sum(e['gross']))} | {med['rot']:.2f} | {med['swing']:.2f} | "
              f"{med['turn']:.2f} | {med['centre_across']:.3f} | {med['centre_along']:.3f} | "
              f"{med['obj_across']:.3f} | {med['obj_along']:.3f} | {len(e['pair_rot_from_rot'])} | "
              f"{med['pair_rot_from_rot']:.2f} | {med['pair_rot_from_centres']:.2f} |")
    if not args.pairs:
        return
    aligners = args.aligners.split(",")
    cfg = dataclasses.replace(config, attack=dataclasses.replace(config.attack, aligners=aligners,
                                                                 thresholds=[(10.0, 0.25)]))
    logs = {(tier, room): paths.queries / tier / room / "queries.jsonl" for tier in config.localize.tiers
            for room in rooms}
    rows = [r for r in attack_rows(cfg, paths, logs) if r["present_gt"]]
    print("\n| tier | room | object | localized | " + " | ".join(f"{a} rot ° / m" for a in aligners) + " |")
    print("|---|---|---|---|" + "---|" * len(aligners))
    keyed = {(r["tier"], r["room"], r["object"], r["aligner"]): r for r in rows}
    for tier, room, obj in sorted({(r["tier"], r["room"], r["object"]) for r in rows}):
        cells = []
        for a in aligners:
            r = keyed[(tier, room, obj, a)]
            cells.append("-" if r["rot_err_deg"] is None else f"{r['rot_err_deg']:.2f} / {r['trans_err_m']:.3f}")
        print(f"| {tier} | {room} | {obj} | {keyed[(tier, room, obj, aligners[0])]['n_localized']} | "
              + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
