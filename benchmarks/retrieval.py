"""Retrieval recall against exhaustive matching, on a study's own maps and query features.

    python benchmarks/retrieval.py STUDY_DIR                     # every tier of the study, default options
    python benchmarks/retrieval.py STUDY_DIR --tiers sift --top-k 10 30 --json out.json

For every (tier, room) map of a finished study (``maps/``, ``features/``, ``queries/``): every logged query
(genuine and attacker) is matched against every map image once; each retrieval option then keeps only the
matches of its top-k images and runs the localizer's own PnP on them (the same result as a localizer with that
retrieval, at the cost of one exhaustive matching per query). Options: ``legacy-bow256`` (the flat 256-word
vocabulary, cosine, every keypoint: the retrieval before the vocabulary tree), ``vlad64`` (a global VLAD
descriptor over 64 k-means centres, intra- and power-normalised), and vocabulary trees (``tree-B^D``:
branching B, depth D; scoring l1/l2; histograms of the keypoints with 3D points or of all).

By default the attacker queries of absent (room, object) pairs that the study's exhaustive log did not
localize are not run (counted as not localized by every option; ``--all-queries`` runs them): they cannot
count for the recall and are most of the queries.

Prints per tier and option: attacker queries localized (all, and of GT-present pairs) and their recall
against exhaustive matching (the share of the queries exhaustive matching localizes that the option
localizes too), present-pair queries localized with most inliers on the object and whose retrieved images
see it, genuine queries localized, milliseconds per query for retrieval, seconds per query for matching
its top k (measured per image on the exhaustive pass), and the index build time per map. Timings are this
process, single threaded (set OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 for comparable figures).
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.cluster.vq import kmeans2

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import load_sequence, read_index
from synthleak.core.types import Camera
from synthleak.geometry.poses import camera_centre, rotation_error_deg
from synthleak.localize.features import Features
from synthleak.localize.localizer import Localizer
from synthleak.localize.matching import squared_l2
from synthleak.localize.retrieval import BowIndex, BowParams, VocabularyTree, as_float, sample_rows
from synthleak.localize.visibility import read_image_instances, retrieved_sees
from synthleak.study import load_features, read_query_log


class VoteIndex:
    """Approximate nearest-neighbour voting: each query descriptor is compared with the map descriptors (with
    a 3D point) that share one of its ``assign`` nearest vocabulary words; if its nearest one passes the ratio
    test against the nearest of another 3D point, every map image observing that point gets a vote."""

    def __init__(self, tree: VocabularyTree, data: np.ndarray, point: np.ndarray, word_start: np.ndarray,
                 point_images: list[np.ndarray], num_images: int, binary: bool, ratio: float, assign: int) -> None:
        self.tree, self.data, self.point, self.word_start = tree, data, point, word_start
        self.point_images, self.num_images, self.binary = point_images, num_images, binary
        self.ratio, self.assign = ratio, assign

    @classmethod
    def build(cls, features: list[Features], point_index: list[np.ndarray], params: BowParams | None = None,
              ratio: float = 0.8, assign: int = 1, tree: VocabularyTree | None = None) -> VoteIndex:
        """``features``/``point_index``: every map image's keypoints and their 3D point (-1: none)."""
        params = params or BowParams()
        keep = [np.nonzero(idx >= 0)[0] for idx in point_index]
        data = np.concatenate([as_float(f.subset(k)) for f, k in zip(features, keep, strict=True)])
        point = np.concatenate([idx[k] for idx, k in zip(point_index, keep, strict=True)])
        image = np.concatenate([np.full(len(k), i) for i, k in enumerate(keep)])
        if tree is None:
            rng = np.random.default_rng(params.seed)
            tree = VocabularyTree.train(sample_rows(data, params.sample, rng), params.branching, params.depth,
                                        params.iterations, rng)
        words = tree.words(data)
        order = np.argsort(words, kind="stable")
        word_start = np.searchsorted(words[order], np.arange(tree.num_words + 1))
        num_points = int(point.max()) + 1 if len(point) else 0
        by_point = np.argsort(point, kind="stable")
        bounds = np.searchsorted(point[by_point], np.arange(num_points + 1))
        point_images = [np.unique(image[by_point[bounds[p]:bounds[p + 1]]]) for p in range(num_points)]
        binary = bool(features[0].binary) if features else False
        return cls(tree, data[order], point[order], word_start, point_images, len(features), binary, ratio,
                   assign)

    def _leaves(self, x: np.ndarray) -> np.ndarray:
        """(N, assign) leaves: the greedy path to the last level, then its ``assign`` nearest children."""
        node = np.zeros(len(x), np.int64)
        for level in self.tree.centres[:-1]:
            node = self.tree._descend(level, node, x, self.tree.branching)
        b, last = self.tree.branching, self.tree.centres[-1]
        out = np.empty((len(x), self.assign), np.int64)
        for n in np.unique(node):
            idx = np.nonzero(node == n)[0]
            d = squared_l2(x[idx], last[n * b:(n + 1) * b])
            out[idx] = n * b + np.argsort(d, axis=1, kind="stable")[:, :self.assign]
        return out

    def matches(self, features: Features) -> np.ndarray:
        """(M, 2) ``(query keypoint, 3D point)``: the nearest map descriptor among the query descriptor's words,
        kept if closer than ``ratio`` times the nearest descriptor of another 3D point (none: kept)."""
        if not len(features) or not len(self.data):
            return np.zeros((0, 2), np.int64)
        x = as_float(features)
        leaves = self._leaves(x)
        n = len(x)
        d1, d2 = np.full(n, np.inf), np.full(n, np.inf)
        p1 = np.full(n, -1, np.int64)
        for slot in range(self.assign):
            w = leaves[:, slot]
            s1, s2, sp = np.full(n, np.inf), np.full(n, np.inf), np.full(n, -1, np.int64)
            order = np.argsort(w, kind="stable")
            bounds = np.searchsorted(w[order], np.unique(w))
            for qi in np.split(order, bounds[1:]):
                word = w[qi[0]]
                lo, hi = self.word_start[word], self.word_start[word + 1]
                if lo == hi:
                    continue
                d = np.maximum(squared_l2(x[qi], self.data[lo:hi]), 0.0)
                pts = self.point[lo:hi]
                nn = np.argmin(d, axis=1)
                rows = np.arange(len(qi))
                s1[qi], sp[qi] = d[rows, nn], pts[nn]
                s2[qi] = np.where(pts[None, :] == pts[nn][:, None], np.inf, d).min(axis=1)
            # merge this slot's (s1, sp, s2) into the running (d1, p1, d2)
            same = sp == p1
            better = s1 < d1
            new_d2 = np.where(better, np.where(same, np.minimum(s2, d2), np.minimum(s2, d1)),
                              np.where(same, np.minimum(d2, s2), np.minimum(d2, s1)))
            d1, p1, d2 = np.where(better, s1, d1), np.where(better, sp, p1), new_d2
        r = self.ratio if self.binary else self.ratio ** 2
        ok = np.nonzero((p1 >= 0) & (d1 < r * d2))[0]
        return np.stack([ok, p1[ok]], axis=1).astype(np.int64)

    def scores(self, features: Features) -> np.ndarray:
        """Votes per map image: the matched 3D points it observes."""
        votes = np.zeros(self.num_images, np.float64)
        for p in self.matches(features)[:, 1]:
            votes[self.point_images[p]] += 1.0
        return votes

    def query(self, features: Features, top_k: int) -> np.ndarray:
        score = self.scores(features)
        return np.lexsort((np.arange(len(score)), -score))[:top_k]


class LegacyBow:
    """The retrieval before the vocabulary tree: flat k-means (256 words, 20k samples, 10 iterations), tf-idf,
    cosine, histograms of every keypoint."""

    def __init__(self, features: list[Features], num_words: int = 256, seed: int = 0, sample: int = 20000):
        rng = np.random.default_rng(seed)
        data = np.concatenate([as_float(f) for f in features if len(f)])
        data = sample_rows(data, sample, rng)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="One of the clusters is empty")
            words, _ = kmeans2(data.astype(np.float64), min(num_words, len(data) // 4), iter=10, minit="points",
                               seed=rng)
        self.words = words.astype(np.float32)
        raw = np.stack([self._counts(f) for f in features])
        self.idf = np.log((len(features) + 1) / ((raw > 0).sum(0) + 1)).astype(np.float32)
        self.hist = np.stack([self._norm(r) for r in raw])

    def _counts(self, f: Features) -> np.ndarray:
        x = as_float(f)
        d = (x * x).sum(1, keepdims=True) - 2 * x @ self.words.T + (self.words * self.words).sum(1)[None]
        return np.bincount(np.argmin(d, axis=1), minlength=len(self.words)).astype(np.float32)

    def _norm(self, c: np.ndarray) -> np.ndarray:
        h = c * self.idf
        return h / max(float(np.linalg.norm(h)), 1e-12)

    def scores(self, f: Features) -> np.ndarray:
        return self.hist @ self._norm(self._counts(f))


class Vlad:
    """VLAD over ``k`` flat k-means centres of the map's descriptors: residual sums per centre, signed square
    root, per-centre (intra) L2 normalisation, global L2; cosine similarity."""

    def __init__(self, features: list[Features], k: int = 64, seed: int = 0, sample: int = 50000):
        rng = np.random.default_rng(seed)
        data = np.concatenate([as_float(f) for f in features if len(f)])
        data = sample_rows(data, sample, rng)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="One of the clusters is empty")
            centres, _ = kmeans2(data.astype(np.float64), k, iter=10, minit="++", rng=rng)
        self.centres = centres.astype(np.float32)
        self.db = [self._describe_map(f) for f in features]
        if not isinstance(self, RegionVlad):
            self.db = np.stack(self.db)

    def _describe_map(self, f: Features) -> np.ndarray:
        return self._describe_regions(f) if isinstance(self, RegionVlad) else self._describe(f)

    def _describe(self, f: Features) -> np.ndarray:
        x = as_float(f)
        out = np.zeros_like(self.centres)
        if len(x):
            d = (x * x).sum(1, keepdims=True) - 2 * x @ self.centres.T + (self.centres ** 2).sum(1)[None]
            nn = np.argmin(d, axis=1)
            np.add.at(out, nn, x - self.centres[nn])
        out = np.sign(out) * np.sqrt(np.abs(out))
        out /= np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-12)
        v = out.ravel()
        return v / max(float(np.linalg.norm(v)), 1e-12)

    def scores(self, f: Features) -> np.ndarray:
        return self.db @ self._describe(f)


class RegionVlad(Vlad):
    """VLAD of image regions: the whole map image, 3x3 half-size windows (stride 1/4) and 5x5 third-size
    windows (stride 1/6); a map image scores its best region against the whole query (an object filling the
    query may fill only a corner of a map image)."""

    def __init__(self, features: list[Features], size: tuple[int, int], k: int = 32, seed: int = 0,
                 sample: int = 50000):
        self.size = size
        super().__init__(features, k, seed, sample)
        self.owner = np.concatenate([np.full(len(r), i) for i, r in enumerate(self.db)])
        self.db = np.concatenate(self.db).astype(np.float16)

    def _windows(self) -> list[tuple[float, float, float, float]]:
        out = [(0.0, 0.0, 1.0, 1.0)]
        for frac, n in ((1 / 2, 3), (1 / 3, 5)):
            for i in range(n):
                for j in range(n):
                    out.append((i * frac / 2, j * frac / 2, i * frac / 2 + frac, j * frac / 2 + frac))
        return out

    def _describe_regions(self, f: Features) -> np.ndarray:
        w, h = self.size
        rows = []
        for x0, y0, x1, y1 in self._windows():
            inside = ((f.keypoints[:, 0] >= x0 * w) & (f.keypoints[:, 0] < x1 * w)
                      & (f.keypoints[:, 1] >= y0 * h) & (f.keypoints[:, 1] < y1 * h))
            rows.append(self._describe(f.subset(np.nonzero(inside)[0])))
        return np.stack(rows)

    def scores(self, f: Features) -> np.ndarray:
        sim = self.db.astype(np.float32) @ self._describe(f)
        out = np.full(int(self.owner.max()) + 1, -np.inf)
        np.maximum.at(out, self.owner, sim)
        return out


@dataclass(frozen=True)
class Option:
    name: str
    kind: str  # exhaustive | legacy | vlad | tree
    top_k: int = 0
    params: BowParams | None = None


def default_options(top_ks: list[int]) -> list[Option]:
    out = [Option("exhaustive", "exhaustive")]
    for k in top_ks:
        out.append(Option(f"legacy-bow256 top{k}", "legacy", k))
        out.append(Option(f"vlad64 top{k}", "vlad", k))
        for b, d in ((16, 2), (32, 2), (64, 2), (10, 4)):
            for scoring in ("l1", "l2"):
                out.append(Option(f"tree-{b}^{d} {scoring} top{k}", "tree", k, BowParams(b, d, scoring)))
        out.append(Option(f"tree-32^2 l1 all-kp top{k}", "tree", k, BowParams(32, 2, "l1", points_only=False)))
        out.append(Option(f"oracle-matches top{k}", "oracle", k))
        out.append(Option(f"rvlad32 top{k}", "rvlad32", k))
        out.append(Option(f"rvlad64 top{k}", "rvlad64", k))
        for b, d in ((32, 2), (64, 2)):
            for assign in (1, 2):
                out.append(Option(f"vote-{b}^{d} x{assign} top{k}", f"vote{assign}", k, BowParams(b, d)))
                out.append(Option(f"hybrid-{b}^{d} x{assign} top{k}", f"hybrid{assign}", k, BowParams(b, d)))
    for b, d in ((32, 2), (64, 2)):
        for assign in (1, 2, 3):
            out.append(Option(f"direct-{b}^{d} x{assign}", f"direct{assign}", 0, BowParams(b, d)))
    return out


def build_indexes(loc: Localizer, options: list[Option]) -> tuple[dict, dict[str, float]]:
    """One index per distinct (kind, params) of the options, and its build seconds."""
    points = [f.subset(np.nonzero(idx >= 0)[0]) for f, idx in zip(loc.data.features, loc.data.point_index,
                                                                    strict=True)]
    indexes, seconds = {}, {}
    for opt in options:
        key = (opt.kind, opt.params)
        if opt.kind in ("exhaustive", "oracle") or key in indexes:
            continue
        t0 = time.perf_counter()
        if opt.kind == "legacy":
            indexes[key] = LegacyBow(loc.data.features)
        elif opt.kind == "vlad":
            indexes[key] = Vlad(points)
        elif opt.kind.startswith("rvlad"):
            indexes[key] = RegionVlad(points, (loc.camera.width, loc.camera.height), k=int(opt.kind[5:]))
        elif opt.kind[:4] in ("vote", "hybr", "dire"):
            indexes[key] = VoteIndex.build(loc.data.features, loc.data.point_index, opt.params,
                                           assign=int(opt.kind[-1]))
        else:
            indexes[key] = BowIndex.build(points if opt.params.points_only else loc.data.features, opt.params)
        seconds[repr(key)] = time.perf_counter() - t0
    return indexes, seconds


def pose_ok(est: np.ndarray | None, expected: np.ndarray, max_deg: float = 10.0, max_m: float = 0.25) -> bool:
    """Within ``max_deg`` / ``max_m`` (camera centre) of the expected pose."""
    if est is None:
        return False
    return (rotation_error_deg(est[:3, :3], expected[:3, :3]) <= max_deg
            and float(np.linalg.norm(camera_centre(est) - camera_centre(expected))) <= max_m)


def top(scores: np.ndarray, k: int) -> np.ndarray:
    return np.sort(np.lexsort((np.arange(len(scores)), -scores))[:k])


def run_map(study: Path, tier: str, room: str, options: list[Option], gt: dict, all_queries: bool,
            match_cache: Path | None = None) -> tuple[list[dict], dict]:
    map_dir = study / "maps" / tier / room
    loc = Localizer.load(map_dir, LocalizeConfig(retrieval="exhaustive"))
    visible = read_image_instances(map_dir)
    indexes, build_s = build_indexes(loc, options)
    matcher, memo = loc.matcher, {}

    def cached(a, b):
        key = id(b)
        if key not in memo:
            memo[key] = matcher(a, b)
        return memo[key]

    loc.matcher = cached
    db_index = {id(f): i for i, (f, _) in enumerate(loc._db)}
    cache_file = None if match_cache is None else match_cache / f"{tier}_{room}.npz"
    stored: dict[str, np.ndarray] = {}
    if cache_file is not None and cache_file.is_file():
        with np.load(cache_file) as z:
            stored = {k: z[k] for k in z.files}
    fresh: dict[str, np.ndarray] = {}
    records = read_query_log(study / "queries" / tier / room / "queries.jsonl")
    skipped = [] if all_queries else [  # absent-pair attacker queries exhaustive matching did not localize
        q for q in records if not (q["genuine"] or q["success"] or (q["attacker_object"], room) in gt)]
    records = [q for q in records if q not in skipped]
    cameras: dict[str, Camera] = {}
    objects = load_sequence(study / "dataset" / "scenes" / room).objects_by_id()
    attackers: dict[str, object] = {}
    rows = []
    for q in records:
        seq_dir = (study / "dataset" / q["sequence"])
        if q["sequence"] not in cameras:
            cameras[q["sequence"]] = load_sequence(seq_dir).camera
        features, _ = load_features(study / "features" / tier / q["sequence"] / f"{q['frame']}.npz")
        memo.clear()
        qkey = f"{q['sequence']}|{q['frame']}"
        if qkey in stored:  # (img, query kp, db kp) rows of every map image's matches
            m = stored[qkey]
            memo.update({id(loc._db[i][0]): m[m[:, 0] == i, 1:] for i in range(len(loc._db))})
        target = gt.get((q["attacker_object"], room))
        expected = None  # the pose a perfect server returns: the attacker's view moved onto the room's instance
        if target is not None:
            att = attackers.get(q["sequence"]) or attackers.setdefault(q["sequence"], load_sequence(seq_dir))
            world_from_object = np.asarray(objects[target].world_from_object, dtype=np.float64)
            expected = att.pose(q["frame"]) @ np.linalg.inv(world_from_object)
        row = {"tier": tier, "room": room, "frame": q["frame"], "genuine": q["genuine"],
               "object": q["attacker_object"], "present": target is not None, "logged_success": q["success"]}
        for opt in options:
            t0 = time.perf_counter()
            if opt.kind == "exhaustive":
                cand = np.arange(len(loc.data.names))
            elif opt.kind == "oracle":  # the images with most exhaustive matches (reference, not a retrieval)
                cand = top(np.array([len(memo[id(f)]) for f, _ in loc._db], float), opt.top_k)
            elif opt.kind.startswith("direct"):
                cand = np.zeros(0, np.int64)
            else:
                cand = top(indexes[(opt.kind, opt.params)].scores(features), opt.top_k)
            t_ret = time.perf_counter() - t0
            if opt.kind.startswith(("direct", "hybrid")):
                t0 = time.perf_counter()
                direct = indexes[(opt.kind, opt.params)].matches(features)
                t_ret += time.perf_counter() - t0
                corr = np.unique(np.concatenate([loc.correspondences(features, cand), direct]), axis=0)
                result = loc.pose_from_matches(features, corr, cameras[q["sequence"]])
                result.retrieved = sorted(loc.data.names[int(i)] for i in cand)
            else:
                result = loc.localize_features(features, cameras[q["sequence"]], cand)
            counts = result.inlier_instance_counts
            on_target = (target is not None and result.success and bool(counts)
                         and max(counts, key=lambda k: (counts[k], -k)) == target)
            sees = (None if visible is None or target is None or not len(cand)
                    else retrieved_sees(result.retrieved, target, visible))
            correct = expected is not None and pose_ok(result.cam_from_world, expected)
            row[opt.name] = {"success": bool(result.success), "inliers": int(result.num_inliers),
                             "on_target": on_target, "correct": correct, "sees": sees, "retrieval_s": t_ret,
                             "n_images": len(cand)}
            if opt.kind == "exhaustive":  # first option: the memo is empty, every image is matched here
                if qkey in stored:
                    row["match_s_per_image"] = float(stored[qkey + "|t"])
                else:
                    row["match_s_per_image"] = ((result.timings["matching"] - result.timings["retrieval"])
                                                / len(cand))
                    fresh[qkey] = np.concatenate([np.column_stack([np.full(len(m), db_index[k]), m])
                                                  for k, m in memo.items()] or [np.zeros((0, 3), np.int64)])
                    fresh[qkey + "|t"] = np.array(row["match_s_per_image"])
        rows.append(row)
    if cache_file is not None and fresh:
        cache_file.parent.mkdir(parents=True, exist_ok=True)
        np.savez(cache_file, **stored, **fresh)
    for q in skipped:  # counted as not localized by every option (not run)
        rows.append({"tier": tier, "room": room, "frame": q["frame"], "genuine": False, "object": q["attacker_object"],
                     "present": False, "logged_success": False, "skipped": True}
                    | {o.name: {"success": False, "on_target": False, "correct": False, "sees": None}
                       for o in options})
    return rows, build_s


def summarise(rows: list[dict], options: list[Option], build: dict[str, list[float]]) -> list[dict]:
    out = []
    match_s_per_image = float(np.mean([r["match_s_per_image"] for r in rows if not r.get("skipped")]))
    attacker = [r for r in rows if not r["genuine"]]
    present = [r for r in attacker if r["present"]]
    genuine = [r for r in rows if r["genuine"]]
    ex_all = {id(r) for r in attacker if r["exhaustive"]["success"]}
    ex_present = {id(r) for r in present if r["exhaustive"]["success"]}
    ex_correct = {id(r) for r in present if r["exhaustive"]["correct"]}
    for opt in options:
        loc_all = {id(r) for r in attacker if r[opt.name]["success"]}
        loc_present = {id(r) for r in present if r[opt.name]["success"]}
        run = [r for r in rows if not r.get("skipped")]
        n_img = float(np.mean([r[opt.name]["n_images"] for r in run]))  # direct: 0 (its cost is "retrieval")
        key = repr((opt.kind, opt.params))
        out.append({
            "option": opt.name,
            "attacker localized": f"{len(loc_all)}/{len(attacker)}",
            "recall vs exhaustive": len(loc_all & ex_all) / max(len(ex_all), 1),
            "present localized": f"{len(loc_present)}/{len(present)}",
            "present recall": len(loc_present & ex_present) / max(len(ex_present), 1),
            "present correct": f"{sum(r[opt.name]['correct'] for r in present)}/{len(present)}",
            "correct recall": len({id(r) for r in present if r[opt.name]["correct"]} & ex_correct)
            / max(len(ex_correct), 1),
            "present on object": sum(1 for r in present if r[opt.name]["on_target"]),
            "present retrieved sees object": sum(1 for r in present if r[opt.name]["sees"]),
            "genuine localized": f"{sum(r[opt.name]['success'] for r in genuine)}/{len(genuine)}",
            "retrieval ms/query": 1000 * float(np.mean([r[opt.name]["retrieval_s"] for r in run])),
            "matching s/query": n_img * match_s_per_image,
            "build s/map": float(np.mean(build[key])) if key in build else 0.0,
        })
    return out


def markdown(rows: list[dict]) -> str:
    cols = list(rows[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for r in rows:
        lines.append("| " + " | ".join(f"{v:.3f}" if isinstance(v, float) else str(v) for v in r.values()) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("study", type=Path)
    parser.add_argument("--tiers", nargs="+")
    parser.add_argument("--rooms", nargs="+")
    parser.add_argument("--top-k", nargs="+", type=int, default=[10, 20, 30])
    parser.add_argument("--only", nargs="+", help="option names to keep (default: all)")
    parser.add_argument("--all-queries", action="store_true",
                        help="also the absent-pair attacker queries exhaustive matching did not localize (the "
                             "default skips them: they cannot count for the recall, and they are most queries)")
    parser.add_argument("--match-cache", type=Path,
                        help="folder keeping every query's exhaustive matches (reruns skip the matching)")
    parser.add_argument("--json", type=Path, help="write every query's outcome per option here")
    args = parser.parse_args()
    study = args.study
    options = default_options(args.top_k)
    if args.only:
        options = [o for o in options if o.name == "exhaustive" or o.name in args.only]
    index = read_index(study / "dataset" / "stages")
    gt = {(o["id"], room): int(i) for o in index["attacker_objects"] for room, i in o.get("present_in", {}).items()}
    tiers = args.tiers or sorted(p.name for p in (study / "maps").iterdir() if p.is_dir())
    everything = {}
    for tier in tiers:
        rows, build = [], {}
        for room_dir in sorted((study / "maps" / tier).iterdir()):
            if not (room_dir / "map.json").is_file() or (args.rooms and room_dir.name not in args.rooms):
                continue
            t0 = time.perf_counter()
            room_rows, build_s = run_map(study, tier, room_dir.name, options, gt, args.all_queries,
                                         args.match_cache)
            rows += room_rows
            for k, v in build_s.items():
                build.setdefault(k, []).append(v)
            print(f"{tier}/{room_dir.name}: {len(room_rows)} queries, {time.perf_counter() - t0:.0f} s", flush=True)
        table = summarise(rows, options, build)
        print(f"\n## {tier}\n\n{markdown(table)}\n", flush=True)
        everything[tier] = {"rows": rows, "summary": table}
    if args.json:
        args.json.write_text(json.dumps(everything, default=str))


if __name__ == "__main__":
    main()
