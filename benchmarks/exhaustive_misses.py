"""Why exhaustive matching misses attacker queries of present objects: a per-query breakdown of a study.

    python benchmarks/exhaustive_misses.py STUDY_DIR --tier sift --out /tmp/misses        # + --in-room

For every attacker query of a GT-present (room, object) pair (the study's own queries and cached features),
matched against EVERY image of the room's map (exhaustive):

* ``expected``: the pose a perfect server would return, the attacker's ``cam_from_object`` moved onto the
  room's instance (``cam_from_object @ object_from_world``); a localization is *correct* within 10° / 0.25 m
  of it (camera centre), the scale at which the attack can use it;
* query side: the object's share of the query's pixels, the camera's distance to and elevation above the
  object's centre;
* map side: the map images that see the instance (>= 0.5 % of their pixels), the largest share it takes in
  one, the map's 3D points on it, and the viewpoint gap: the smallest angle, seen from the object's centre,
  between the query camera and a map camera that sees the object, with the distance ratio (map / query) of
  that map camera (the scale change SIFT has to bridge);
* matching: 2D-3D matches, those on the instance's points, and those *correct* (reprojection under the
  expected pose < the PnP threshold), against the tier's minimum of inliers;
* variants on the same queries: PnP threshold x2, minimum inliers 10, only the query keypoints on the object
  (attacker mask), query keypoints x4 (re-extracted), and ``--in-room``: the same camera poses rendered in
  the room itself (pyrender; room lighting and background, the map's own renderer): lighting + background
  against viewpoint + scale.

Prints the summary and breakdowns (markdown), writes ``rows.json`` and figures into ``--out``.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from synthleak.config import LocalizeConfig, config_from_dict
from synthleak.core.dataset import load_sequence, read_index
from synthleak.geometry.poses import camera_centre, rotation_error_deg
from synthleak.localize.localizer import Localizer
from synthleak.localize.tiers import get_tier
from synthleak.study import load_features, read_query_log

CORRECT_DEG, CORRECT_M = 10.0, 0.25


def pose_ok(est: np.ndarray | None, expected: np.ndarray) -> bool:
    if est is None:
        return False
    return (rotation_error_deg(est[:3, :3], expected[:3, :3]) <= CORRECT_DEG
            and float(np.linalg.norm(camera_centre(est) - camera_centre(expected))) <= CORRECT_M)


def correct_matches(loc: Localizer, query, corr: np.ndarray, expected: np.ndarray, max_px: float) -> np.ndarray:
    """Bool per correspondence: the map point reprojects within ``max_px`` of the query keypoint under the
    expected pose."""
    if not len(corr):
        return np.zeros(0, bool)
    xyz = loc.data.xyz[corr[:, 1]]
    cam = xyz @ expected[:3, :3].T + expected[:3, 3]
    k = loc.camera.K
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (cam @ k.T)[:, :2] / cam[:, 2:3]
    err = np.linalg.norm(uv - query.keypoints[corr[:, 0]], axis=1)
    return (cam[:, 2] > 0) & (err < max_px)


def outcome(loc: Localizer, query, corr: np.ndarray, expected: np.ndarray, gt_id: int,
            min_inliers: int | None = None, max_error_px: float | None = None) -> dict:
    saved = loc.min_inliers, loc.max_error_px
    loc.min_inliers = min_inliers or saved[0]
    loc.max_error_px = max_error_px or saved[1]
    try:
        result = loc.pose_from_matches(query, corr, loc.camera)
    finally:
        loc.min_inliers, loc.max_error_px = saved
    counts = result.inlier_instance_counts
    return {"success": bool(result.success), "correct": pose_ok(result.cam_from_world, expected),
            "inliers": int(result.num_inliers), "on_target": bool(result.success and counts and max(
                counts, key=lambda k: (counts[k], -k)) == gt_id)}


def view_stats(cam_from_object: np.ndarray, centre_obj: np.ndarray, map_cams_obj: list[np.ndarray]) -> dict:
    """Distance/elevation of the query camera from the object's centre, and the closest map view."""
    c = camera_centre(cam_from_object) - centre_obj
    dist = float(np.linalg.norm(c))
    out = {"query_dist_m": dist, "query_elev_deg": float(np.degrees(np.arcsin(c[2] / max(dist, 1e-9))))}
    best = (np.inf, np.nan, np.nan)
    for pose in map_cams_obj:
        m = camera_centre(pose) - centre_obj
        md = float(np.linalg.norm(m))
        gap = float(np.degrees(np.arccos(np.clip(c @ m / max(dist * md, 1e-12), -1, 1))))
        if gap < best[0]:
            best = (gap, md / max(dist, 1e-9), md)
    out |= {"view_gap_deg": best[0], "scale_ratio": best[1], "map_dist_m": best[2]}
    return out


class InRoom:
    """Renders attacker camera poses inside the room (the study's renderer settings)."""

    def __init__(self, study: Path, config) -> None:
        from synthleak.render.pipeline import load_stage
        from synthleak.render.registry import get_renderer

        self.study, self.config, self.load_stage = study, config, load_stage
        self.renderer = get_renderer(config.render)
        self.room = None

    def render(self, room: str, camera, cam_from_world: np.ndarray):
        if self.room != room:
            self.renderer.prepare(self.load_stage(self.study / "dataset" / "stages" / f"{room}.usda"))
            self.room = room
        return self.renderer.render(camera, cam_from_world, 0)


def run(study: Path, tier: str, in_room: bool, more_keypoints: int) -> list[dict]:
    manifest = json.loads((study / "dataset" / "manifest.json").read_text())
    config = config_from_dict(manifest["config"])
    index = read_index(study / "dataset" / "stages")
    localize = LocalizeConfig(retrieval="exhaustive", max_keypoints=config.localize.max_keypoints)
    renderer = InRoom(study, config) if in_room else None
    extractor = get_tier(tier).make_extractor(config.localize.max_keypoints)
    big_extractor = get_tier(tier).make_extractor(more_keypoints) if more_keypoints else None
    rows = []
    pairs = sorted((room, o["id"], int(i)) for o in index["attacker_objects"] for room, i in o["present_in"].items())
    for room in sorted({p[0] for p in pairs}):
        map_dir = study / "maps" / tier / room
        loc = Localizer.load(map_dir, localize)
        min_inl, max_px = loc.min_inliers, loc.max_error_px
        scene = load_sequence(study / "dataset" / "scenes" / room)
        objects = scene.objects_by_id()
        counts = json.loads((map_dir / "image_instances.json").read_text())["images"]
        num_px = loc.camera.width * loc.camera.height
        log = read_query_log(study / "queries" / tier / room / "queries.jsonl")
        all_cands = np.arange(len(loc.data.names))
        for _, obj_id, gt_id in [p for p in pairs if p[0] == room]:
            inst = objects[gt_id]
            world_from_object = np.asarray(inst.world_from_object, dtype=np.float64)
            centre_obj = np.array([0.0, 0.0, 0.5 * float(inst.extents[2])])
            seeing = [n for n in loc.data.names if str(gt_id) in counts[n]]
            map_cams_obj = [scene.pose(n) @ world_from_object for n in seeing]
            max_share = max((counts[n][str(gt_id)] / num_px for n in seeing), default=0.0)
            points_on = int((loc.data.instance == gt_id).sum())
            att = load_sequence(study / "dataset" / "attackers" / obj_id)
            target = att.target_instance_id
            for q in (q for q in log if q["attacker_object"] == obj_id):
                frame = q["frame"]
                cam_from_object = att.pose(frame)
                expected = cam_from_object @ np.linalg.inv(world_from_object)
                query, _ = load_features(study / "features" / tier / f"attackers/{obj_id}" / f"{frame}.npz")
                mask = att.instance(frame)
                kp = np.clip(np.floor(query.keypoints).astype(int), 0, [mask.shape[1] - 1, mask.shape[0] - 1])
                on_obj = mask[kp[:, 1], kp[:, 0]] == target
                corr = loc.correspondences(query, all_cands)
                ok = correct_matches(loc, query, corr, expected, max_px)
                on_t = loc.data.instance[corr[:, 1]] == gt_id if len(corr) else np.zeros(0, bool)
                row = {"room": room, "object": obj_id, "frame": frame, "gt_id": gt_id, "logged": q["success"],
                       "query_share": float((mask == target).mean()), "query_kp": len(query),
                       "query_kp_on_object": int(on_obj.sum()), "map_images_seeing": len(seeing),
                       "map_images": len(loc.data.names), "map_max_share": max_share, "map_points_on": points_on,
                       "matches": len(corr), "matches_on_target": int(on_t.sum()),
                       "matches_correct": int(ok.sum()), "matches_correct_on_target": int((ok & on_t).sum()),
                       "min_inliers": min_inl, **view_stats(cam_from_object, centre_obj, map_cams_obj)}
                row["base"] = outcome(loc, query, corr, expected, gt_id)
                row["thr_x2"] = outcome(loc, query, corr, expected, gt_id, max_error_px=2 * max_px)
                row["min_inliers_10"] = outcome(loc, query, corr, expected, gt_id, min_inliers=10)
                sub = query.subset(np.nonzero(on_obj)[0])
                row["object_only"] = outcome(loc, sub, loc.correspondences(sub, all_cands), expected, gt_id)
                if big_extractor is not None:
                    big = big_extractor(att.rgb(frame))
                    row["query_kp_x4"] = outcome(loc, big, loc.correspondences(big, all_cands), expected, gt_id)
                if renderer is not None:
                    rendered = renderer.render(room, loc.camera, expected)
                    room_q = extractor(rendered.rgb)
                    kp = np.clip(np.floor(room_q.keypoints).astype(int), 0,
                                 [loc.camera.width - 1, loc.camera.height - 1])
                    on_room_obj = rendered.instance[kp[:, 1], kp[:, 0]] == gt_id
                    row["in_room_share"] = float((rendered.instance == gt_id).mean())
                    row["in_room"] = outcome(loc, room_q, loc.correspondences(room_q, all_cands), expected, gt_id)
                    sub = room_q.subset(np.nonzero(on_room_obj)[0])
                    row["in_room_object_only"] = outcome(loc, sub, loc.correspondences(sub, all_cands), expected,
                                                         gt_id)
                    obj_px = rendered.instance == gt_id
                    att_px = mask == target
                    grey = rendered.rgb.mean(2)
                    row["in_room_object_grey"] = float(grey[obj_px].mean()) if obj_px.any() else float("nan")
                    row["hall_object_grey"] = float(att.rgb(frame).mean(2)[att_px].mean())
                rows.append(row)
            done = [r for r in rows if r["object"] == obj_id and r["room"] == room]
            print(f"{room}/{obj_id}: {sum(r['base']['success'] for r in done)}/{len(done)} localized", flush=True)
    return rows


VARIANTS = ("base", "thr_x2", "min_inliers_10", "object_only", "query_kp_x4", "in_room", "in_room_object_only")


def table(rows: list[dict], head: list[str]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        lines.append("| " + " | ".join(f"{v:.2f}" if isinstance(v, float) else str(v) for v in r) + " |")
    return "\n".join(lines)


def summary(rows: list[dict]) -> str:
    n = len(rows)
    out = [f"{n} attacker queries of GT-present pairs; logged exhaustive localizations: "
           f"{sum(r['logged'] for r in rows)}\n"]
    lines = []
    for v in VARIANTS:
        if v not in rows[0]:
            continue
        s = sum(r[v]["success"] for r in rows)
        c = sum(r[v]["correct"] for r in rows)
        t = sum(r[v]["on_target"] for r in rows)
        lines.append([v, f"{s}/{n}", f"{c}/{n}", f"{t}/{n}"])
    out.append(table(lines, ["variant", "localized", "correct (10°, 0.25 m)", "inliers mostly on the object"]))
    # Where the correct matches are: enough correct 2D-3D matches for PnP at all?
    mi = rows[0]["min_inliers"]
    enough = sum(r["matches_correct"] >= mi for r in rows)
    out.append(f"\nQueries with >= {mi} correct 2D-3D matches (reprojection under the expected pose < the PnP "
               f"threshold) among all exhaustive matches: {enough}/{n}; median correct matches "
               f"{np.median([r['matches_correct'] for r in rows]):.0f}, median matches "
               f"{np.median([r['matches'] for r in rows]):.0f}, median matches on the object's points "
               f"{np.median([r['matches_on_target'] for r in rows]):.0f}.")
    return "\n".join(out)


def breakdown(rows: list[dict], key: str, edges: list[float], label: str) -> str:
    lines = []
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        sel = [r for r in rows if lo <= r[key] < hi]
        if not sel:
            continue
        line = [f"{lo:g}–{hi:g}", len(sel), f"{np.mean([r['base']['correct'] for r in sel]):.2f}",
                f"{np.median([r['matches_correct'] for r in sel]):.0f}"]
        if "in_room" in sel[0]:
            line.append(f"{np.mean([r['in_room']['correct'] for r in sel]):.2f}")
        lines.append(line)
    head = [label, "queries", "correct (hall)", "median correct matches"]
    if rows and "in_room" in rows[0]:
        head.append("correct (same view in the room)")
    return table(lines, head)


def per_object(rows: list[dict]) -> str:
    groups = defaultdict(list)
    for r in rows:
        groups[(r["room"], r["object"])].append(r)
    lines = []
    for (room, obj), g in sorted(groups.items()):
        line = [room, obj, f"{sum(r['base']['correct'] for r in g)}/{len(g)}", g[0]["map_images_seeing"],
                f"{100 * g[0]['map_max_share']:.1f}", g[0]["map_points_on"],
                f"{np.median([r['view_gap_deg'] for r in g]):.0f}", f"{np.median([r['scale_ratio'] for r in g]):.1f}",
                f"{np.median([r['matches_correct'] for r in g]):.0f}"]
        if "in_room" in g[0]:
            line.append(f"{sum(r['in_room']['correct'] for r in g)}/{len(g)}")
        lines.append(line)
    head = ["room", "object", "correct", "map images seeing it", "max share %", "3D points on it",
            "median view gap °", "median scale ratio", "median correct matches"]
    if rows and "in_room" in rows[0]:
        head.append("correct in the room")
    return table(lines, head)


def figures(rows: list[dict], out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    paths = []
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    ok = np.array([r["base"]["correct"] for r in rows])
    for ax, key, label in ((axes[0], "view_gap_deg", "viewpoint gap to the closest map view seeing the object (°)"),
                           (axes[1], "scale_ratio", "distance ratio, closest map view / query")):
        x = np.array([r[key] for r in rows], dtype=float)
        y = np.array([r["matches_correct"] for r in rows], dtype=float) + 1
        ax.scatter(x[~ok], y[~ok], s=12, c="tab:red", label="not localized correctly")
        ax.scatter(x[ok], y[ok], s=12, c="tab:green", label="localized correctly")
        ax.axhline(rows[0]["min_inliers"] + 1, color="k", ls="--", lw=0.8, label="tier's minimum inliers")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("correct 2D-3D matches + 1 (exhaustive)")
    axes[0].legend(fontsize=8)
    fig.suptitle("Attacker queries of present objects, exhaustive matching")
    fig.tight_layout()
    paths.append(out / "misses_scatter.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    variants = [v for v in VARIANTS if v in rows[0]]
    fig, ax = plt.subplots(figsize=(8, 3.6))
    n = len(rows)
    succ = [sum(r[v]["success"] for r in rows) / n for v in variants]
    corr = [sum(r[v]["correct"] for r in rows) / n for v in variants]
    x = np.arange(len(variants))
    ax.bar(x - 0.2, succ, 0.4, label="localized")
    ax.bar(x + 0.2, corr, 0.4, label="correct (10°, 0.25 m)")
    ax.set_xticks(x, [v.replace("_", " ") for v in variants], rotation=20, fontsize=8)
    ax.set_ylabel(f"share of {n} queries")
    ax.legend(fontsize=8)
    fig.tight_layout()
    paths.append(out / "misses_variants.png")
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("--tier", default="sift")
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--in-room", action="store_true", help="also render each query's view in the room")
    parser.add_argument("--more-keypoints", type=int, default=0, help="query keypoints of the x4 variant (0: off)")
    parser.add_argument("--rows", type=Path, help="reuse a rows.json instead of recomputing")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.rows:
        rows = json.loads(args.rows.read_text())
    else:
        rows = run(args.study, args.tier, args.in_room, args.more_keypoints)
        (args.out / "rows.json").write_text(json.dumps(rows, indent=0))
    print(summary(rows))
    print("\n" + breakdown(rows, "view_gap_deg", [0, 10, 20, 30, 45, 60, 90, 180], "view gap °"))
    print("\n" + breakdown(rows, "scale_ratio", [0, 1, 1.5, 2, 3, 4, 6, 100], "scale ratio"))
    print("\n" + breakdown(rows, "query_elev_deg", [-90, 15, 30, 45, 90], "query elevation °"))
    print("\n" + breakdown(rows, "map_max_share", [0, 0.01, 0.03, 0.1, 1.01], "object's max share of a map image"))
    print("\n" + per_object(rows))
    for p in figures(rows, args.out):
        print(f"figure: {p}")


if __name__ == "__main__":
    main()
