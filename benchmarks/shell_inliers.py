"""Where the inliers of localized attacker queries lie in the attacker's own photo (issue 30, step 4).

Usage:
    python benchmarks/shell_inliers.py STUDY_DIR CONFIG [--servers sift,xfeat]

The report's shell share counts localized attacker queries whose PnP inliers lie mostly on the *room's* shell
(map side). This script asks the other side: each localized attacker query is localized again in process (the
same features, map and RANSAC seed: the same inliers as the log) and each inlier's query keypoint is looked up in
the attacker frame's GT instance mask: on the photographed object, on the setting's shell (its floor, walls,
ceiling), or elsewhere (pedestal, panel, props). A shell-localized query whose query-side inliers lie on the
setting's background is a background-to-background chance match; one whose inliers lie on the object matched
the object to the room's walls or floor.

Prints per server: localized attacker queries, those mostly on the room's shell, and for each group the share
of their query-side inliers on the object / the setting's shell / other; then, over every server, the inliers
of the shell-localized queries by (setting surface and its texture kind, room shell piece and the room's style).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from synthleak.config import load_config
from synthleak.core.dataset import load_sequence
from synthleak.errors import ConfigError
from synthleak.evaluate.shell_share import mostly_on_shell
from synthleak.localize.feature_files import load_features
from synthleak.localize.localizer import Localizer
from synthleak.localize.servers import server_by_name
from synthleak.scene.plan import FIRST_OBJECT_ID
from synthleak.scene.room import SHELL_IDS
from synthleak.study import StudyPaths, read_query_log


def _where(instance: np.ndarray, xy: np.ndarray, target: int | None) -> np.ndarray:
    """0: the photographed object, 1: the setting's shell, 2: anything else, per keypoint ``xy`` (pixels)."""
    h, w = instance.shape
    cols = np.clip(np.floor(xy[:, 0]).astype(int), 0, w - 1)
    rows = np.clip(np.floor(xy[:, 1]).astype(int), 0, h - 1)
    ids = instance[rows, cols].astype(np.int64)
    out = np.full(len(ids), 2)
    out[(ids > 0) & (ids < FIRST_OBJECT_ID)] = 1
    if target is not None:
        out[ids == target] = 0
    return out


SHELL_NAMES = {v: k for k, v in SHELL_IDS.items()}
META = "synthleak:metadata"


def _stage_metadata(paths: StudyPaths, stage: str) -> dict:
    """A stage's ``synthleak:metadata`` (the setting's surfaces of an attacker stage, the style of a room)."""
    from pxr import Sdf

    layer = Sdf.Layer.FindOrOpen(str(paths.stages / stage))
    return json.loads(dict(layer.customLayerData).get(META, "{}"))


def server_split(paths: StudyPaths, config, name: str, pairs: Counter | None = None) -> dict[str, np.ndarray]:
    """Query-side inlier counts (object, setting shell, other) summed over the localized attacker queries of
    server ``name``, for the queries mostly on the room's shell (``shell``) and the others (``objects``)."""
    server = server_by_name(config.localize)[name]
    totals = {"shell": np.zeros(3, np.int64), "objects": np.zeros(3, np.int64)}
    counts = defaultdict(int)
    sequences = {}
    stages = {o["id"]: o["stage"] for o in json.loads((paths.stages / "index.json").read_text())["attacker_objects"]}
    for log in sorted((paths.queries / name).glob("*/queries.jsonl")):
        room = log.parent.name
        records = [q for q in read_query_log(log) if not q["genuine"] and q["success"]]
        if not records:
            continue
        localizer = Localizer.load(paths.map_dir(name, room), server.localize(config.localize))
        for q in records:
            seq_dir = paths.sequence(q["sequence"], False)
            seq = sequences.get(seq_dir) or sequences.setdefault(seq_dir, load_sequence(seq_dir))
            features, _ = load_features(paths.features_file(server.tier, q["sequence"], q["frame"]))
            result = localizer.localize_features(features, seq.camera_of(q["frame"]))
            if not result.success or result.num_inliers != q["num_inliers"]:
                raise RuntimeError(f"{log}: frame {q['frame']!r} did not localize again as logged")
            xy = features.keypoints[result.inlier_matches[:, 0]]
            where = _where(seq.instance(q["frame"]), xy, seq.target_instance_id)
            group = "shell" if mostly_on_shell(q["inlier_instance_counts"]) else "objects"
            totals[group] += np.bincount(where, minlength=3)
            counts[group] += 1
            if pairs is not None and group == "shell":
                setting = _stage_metadata(paths, stages[q["attacker_object"]]).get("setting", {})
                room_style = _stage_metadata(paths, f"{room}.usda").get("style", "?")
                ids = seq.instance(q["frame"])
                for (x, y), map_point in zip(xy, result.inlier_matches[:, 1], strict=True):
                    iid = int(ids[min(int(y), ids.shape[0] - 1), min(int(x), ids.shape[1] - 1)])
                    surface = SHELL_NAMES.get(iid, "object" if iid == seq.target_instance_id else "other")
                    query_side = f"{surface} ({setting.get(surface, ['-'])[0]})" if iid in SHELL_NAMES else surface
                    map_id = int(localizer.data.instance[map_point])
                    pairs[(query_side, f"{SHELL_NAMES.get(map_id, 'furniture')} ({room_style})")] += 1
    return {"n_" + k: np.int64(v) for k, v in counts.items()} | totals


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("study", type=Path)
    parser.add_argument("config")
    parser.add_argument("--servers", default=None, help="comma-separated server names (default: every one)")
    args = parser.parse_args()
    try:
        config = load_config(args.config)
    except ConfigError as exc:
        parser.exit(2, f"error: {exc}\n")
    paths = StudyPaths(args.study)
    if not paths.queries.is_dir():
        parser.exit(2, f"error: {paths.queries}: no query logs (not a study folder, or its queries stage has "
                       "not run)\n")
    done = sorted(p.name for p in paths.queries.iterdir() if p.is_dir())
    known = set(server_by_name(config.localize))
    names = args.servers.split(",") if args.servers else [n for n in done if n in known]
    unknown = [n for n in names if n not in known or n not in done]
    if unknown:
        parser.exit(2, f"error: --servers: {', '.join(unknown)} not a server of {args.config} with query logs in "
                       f"{paths.queries} (there: {', '.join(n for n in done if n in known)})\n")
    print("| server | localized attacker queries | mostly on the room's shell | their query-side inliers: "
          "object / setting shell / other | the others' query-side inliers: object / setting shell / other |")
    print("|---|---|---|---|---|")
    pairs: Counter = Counter()
    for name in names:
        s = server_split(paths, config, name, pairs)
        n_shell, n_obj = int(s.get("n_shell", 0)), int(s.get("n_objects", 0))

        def shares(v: np.ndarray) -> str:
            return " / ".join(f"{100 * x / max(v.sum(), 1):.0f} %" for x in v)

        print(f"| {name} | {n_shell + n_obj} | {n_shell} | {shares(s['shell'])} | {shares(s['objects'])} |")
    print("\nInliers of the shell-localized queries, every server: query side (setting surface, its texture) -> "
          "map side (room piece, room style)")
    for (query_side, map_side), n in pairs.most_common(25):
        print(f"{n:6d}  {query_side:32s} -> {map_side}")


if __name__ == "__main__":
    main()
