"""Vocabulary-tree build time per map, and a check that the maps' stored ``bow.npz`` is rebuilt byte for byte.

    python benchmarks/vocabulary_build.py STUDY_DIR                      # every (tier, room) map of a study
    python benchmarks/vocabulary_build.py STUDY_DIR --tiers sift --rooms room_002 --scipy-seeding

For each map of a finished study (``maps/<tier>/<room>/``) the bag-of-words index is rebuilt from the map's
own features with the parameters its ``map.json`` records, exactly as ``build_map`` builds it, and compared
array by array with the stored ``bow.npz``. ``--scipy-seeding`` also builds it with scipy's own k-means++
seeding (``kmeans2(minit="++")``, which the maps stage used before ``kmeans_pp_seeds``) and prints both times.
Timings are this process (set OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 for the maps stage's one thread per
worker).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path
from unittest import mock

import numpy as np
from scipy.cluster.vq import kmeans2

from synthleak.localize import retrieval
from synthleak.localize.mapping import bow_features
from synthleak.localize.retrieval import BowIndex, BowParams
from synthleak.localize.store import read_map


def indexed_features(map_dir: Path) -> tuple[list, BowParams]:
    """The features ``build_map`` indexed (keypoints with a 3D point, if ``points_only``) and the map's params."""
    data = read_map(map_dir)
    with np.load(map_dir / "bow.npz") as stored:
        params = BowIndex.from_arrays(stored).params
    return bow_features(data.features, data.point_index, params), params


def scipy_kmeans(data: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """The former ``_kmeans``: scipy's k-means++ seeding inside ``kmeans2``."""
    if len(data) <= k:
        return np.concatenate([data, np.repeat(data[-1:], k - len(data), axis=0)]).astype(np.float32)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="One of the clusters is empty")
        centres, _ = kmeans2(data.astype(np.float64), k, iter=iterations, minit="++", rng=rng)
    return centres.astype(np.float32)


def timed_build(features: list, params: BowParams) -> tuple[dict[str, np.ndarray], float]:
    t0 = time.process_time()
    arrays = BowIndex.build(features, params).to_arrays()
    return arrays, time.process_time() - t0


def same_arrays(a: dict[str, np.ndarray], map_dir: Path) -> bool:
    with np.load(map_dir / "bow.npz") as stored:
        return set(a) == set(stored.files) and all(np.array_equal(a[k], stored[k]) for k in a)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("study_dir", type=Path)
    parser.add_argument("--tiers", nargs="*")
    parser.add_argument("--rooms", nargs="*")
    parser.add_argument("--scipy-seeding", action="store_true", help="also time scipy's k-means++ seeding")
    args = parser.parse_args(argv)
    maps_root = args.study_dir / "maps"
    maps = sorted(p.parent for p in maps_root.glob("*/*/bow.npz"))
    maps = [m for m in maps if (not args.tiers or m.parent.name in args.tiers)
            and (not args.rooms or m.name in args.rooms)]
    if not maps:
        print(f"{maps_root}: no maps with a bow.npz (tiers {args.tiers or 'any'}, rooms {args.rooms or 'any'})",
              file=sys.stderr)
        return 2
    all_same = True
    print("tier  room       descriptors  build s  same bytes" + ("  scipy seeding s  same bytes" if
                                                               args.scipy_seeding else ""))
    for map_dir in maps:
        features, params = indexed_features(map_dir)
        arrays, seconds = timed_build(features, params)
        same = same_arrays(arrays, map_dir)
        line = f"{map_dir.parent.name:5} {map_dir.name:10} {sum(len(f) for f in features):11d}  {seconds:7.1f}  {same}"
        if args.scipy_seeding:
            with mock.patch.object(retrieval, "_kmeans", scipy_kmeans):
                old_arrays, old_seconds = timed_build(features, params)
            old_same = same_arrays(old_arrays, map_dir)
            line += f"  {old_seconds:15.1f}  {old_same}"
            same &= old_same
        print(line, flush=True)
        all_same &= same
    print("every index rebuilt byte for byte" if all_same else "SOME INDEX DIFFERS from the stored bow.npz")
    return 0 if all_same else 1


if __name__ == "__main__":
    sys.exit(main())
