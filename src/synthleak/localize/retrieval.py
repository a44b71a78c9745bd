"""Image retrieval for localization: ``exhaustive`` (every map image) or ``bow`` (bag of visual words).

``bow`` quantises every descriptor with a vocabulary tree (hierarchical k-means, ``branching`` children per
node, ``depth`` levels: up to ``branching ** depth`` words; Nistér & Stewénius 2006) trained on the map's own
descriptors, weights the words tf-idf and scores map images by the L1 distance of L1-normalised histograms
(``2 - |q - d|_1``); the ``top_k`` best map images are matched. Float descriptors of any dimension (SIFT,
learned 64-256-d ones) are clustered as they are, binary ones (ORB, AKAZE) as 0/1 bit vectors. Training is
seeded and single threaded: the same map gives the same index, byte for byte. The parameters are recorded in
the map's ``map.json`` (``retrieval``) and in ``bow.npz``.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.spatial.distance import cdist

from synthleak.localize.features import Features
from synthleak.portable import UNIT_STEP, snap

RETRIEVAL_METHODS = ("exhaustive", "bow")
SCORINGS = ("l1", "l2")


@dataclass(frozen=True)
class BowParams:
    """How a map's bag-of-words index is built (recorded in ``map.json`` under ``retrieval``)."""

    branching: int = 64
    depth: int = 2
    scoring: str = "l1"
    """``l1``: L1-normalised tf-idf, score ``2 - |q - d|_1`` (Nistér & Stewénius); ``l2``: cosine."""
    sample: int = 100_000
    """Descriptors the vocabulary is trained on (a seeded sample of the map's)."""
    iterations: int = 10
    seed: int = 0
    points_only: bool = True
    """Histograms of the keypoints with a 3D point only (the ones 2D-3D matching can use)."""

    def __post_init__(self) -> None:
        if self.branching < 2 or self.depth < 1:
            raise ValueError(f"BowParams: branching >= 2 and depth >= 1 needed, got {self.branching}, {self.depth}")
        if self.scoring not in SCORINGS:
            raise ValueError(f"BowParams: scoring must be one of {SCORINGS}, got {self.scoring!r}")

    @property
    def num_words(self) -> int:
        return self.branching ** self.depth

    def to_json(self) -> dict:
        return {"method": "bow", "vocabulary": "tree", **asdict(self), "num_words": self.num_words,
                "weighting": "tf-idf"}


def as_float(features: Features) -> np.ndarray:
    """Descriptors as float32 rows (binary ones unpacked to 0/1 bits)."""
    if features.binary:
        return np.unpackbits(features.descriptors, axis=1).astype(np.float32)
    return np.asarray(features.descriptors, dtype=np.float32)


def sample_rows(data: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``n`` rows of ``data``, a seeded sample kept in row order (all of them, and no draw, when fewer)."""
    if len(data) <= n:
        return data
    return data[np.sort(rng.choice(len(data), n, replace=False))]


def _kmeans(data: np.ndarray, k: int, iterations: int, rng: np.random.Generator) -> np.ndarray:
    """``k`` centres (k-means++ seeded); fewer points than ``k``: the points, the last one repeated."""
    if len(data) <= k:
        return np.concatenate([data, np.repeat(data[-1:], k - len(data), axis=0)]).astype(np.float32)
    data = data.astype(np.float64)
    with warnings.catch_warnings():  # an empty cluster is just an unused word
        warnings.filterwarnings("ignore", message="One of the clusters is empty")
        centres, _ = kmeans2(data, kmeans_pp_seeds(data, k, rng), iter=iterations, minit="matrix")
    return snap(centres, CENTRE_STEP).astype(np.float32)


def kmeans_pp_seeds(data: np.ndarray, k: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding (Arthur & Vassilvitskii 2007) of float64 ``data``: the same draws and the same centres,
    byte for byte, as ``scipy.cluster.vq.kmeans2(..., minit="++")``, in O(n k) instead of O(n k^2).

    scipy recomputes every point's distance to all centres chosen so far for each new centre (over 90 % of a
    4,096-word tree's training time); here each point's nearest squared distance is kept and lowered with the
    newest centre only. ``cdist`` computes each distance exactly as scipy's does and a minimum is exact, so
    the probabilities, the uniform draws and the chosen rows are the same."""
    seeds = np.empty((k, data.shape[1]))
    seeds[0] = data[rng.integers(len(data), dtype="int64")]
    nearest = cdist(seeds[:1], data, metric="sqeuclidean")[0]
    for i in range(1, k):
        cumulative = (nearest / nearest.sum()).cumsum()
        seeds[i] = data[int(np.searchsorted(cumulative, rng.uniform()))]
        np.minimum(nearest, cdist(seeds[i:i + 1], data, metric="sqeuclidean")[0], out=nearest)
    return seeds


CENTRE_STEP = 2.0 ** -10
"""Grid of the vocabulary's centres (descriptor units): a dyadic step, so that with integer descriptors (SIFT's,
binary bits) every product and partial sum of :func:`nearest_centre` is exact in float64."""


def nearest_centre(data: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Index of each row's nearest centre (lowest index on ties): ``argmin |c|^2 - 2 a.c`` in float64. Exact,
    so the same on every CPU and BLAS kernel, for integer-valued rows and centres on :data:`CENTRE_STEP`
    (SIFT and binary tiers); learned float descriptors get float64 rounding."""
    centres = np.asarray(centres, dtype=np.float64)
    score = np.asarray(data, dtype=np.float64) @ (-2.0 * centres).T
    score += np.einsum("ij,ij->i", centres, centres)[None, :]
    return np.argmin(score, axis=1)


class VocabularyTree:
    """Hierarchical k-means: ``centres[l]`` holds ``branching ** (l + 1)`` rows, the children of node ``n`` of
    level ``l`` being rows ``n * branching ... n * branching + branching - 1``; a word is a leaf's index."""

    def __init__(self, centres: list[np.ndarray], branching: int) -> None:
        self.centres, self.branching = centres, branching

    @property
    def num_words(self) -> int:
        return len(self.centres[-1])

    @classmethod
    def train(cls, data: np.ndarray, branching: int, depth: int, iterations: int,
              rng: np.random.Generator) -> VocabularyTree:
        if not len(data):
            raise ValueError("VocabularyTree.train: no descriptors")
        centres: list[np.ndarray] = []
        node = np.zeros(len(data), np.int64)
        for _ in range(depth):
            level = np.empty((len(centres[-1]) * branching if centres else branching, data.shape[1]), np.float32)
            for n in range(len(level) // branching):
                members = data[node == n]
                rows = slice(n * branching, (n + 1) * branching)
                if len(members):
                    level[rows] = _kmeans(members, branching, iterations, rng)
                else:  # an empty node: children copy their parent, never chosen over it (argmin takes the first)
                    level[rows] = centres[-1][n] if centres else 0.0
            centres.append(level)
            node = cls._descend(level, node, data, branching)
        return cls(centres, branching)

    @staticmethod
    def _descend(level: np.ndarray, node: np.ndarray, data: np.ndarray, branching: int) -> np.ndarray:
        child = np.empty(len(data), np.int64)
        for n in np.unique(node):
            idx = np.nonzero(node == n)[0]
            children = level[n * branching:(n + 1) * branching]
            child[idx] = n * branching + nearest_centre(data[idx], children)
        return child

    def words(self, data: np.ndarray) -> np.ndarray:
        """The word (leaf index) of each float32 row."""
        node = np.zeros(len(data), np.int64)
        for level in self.centres:
            node = self._descend(level, node, data, self.branching)
        return node


class BowIndex:
    """Vocabulary tree, idf weights and the map images' normalised histograms."""

    def __init__(self, tree: VocabularyTree, idf: np.ndarray, histograms: np.ndarray, params: BowParams) -> None:
        self.tree, self.idf, self.histograms, self.params = tree, idf, histograms, params

    @classmethod
    def build(cls, features: list[Features], params: BowParams | None = None) -> BowIndex:
        """Train the vocabulary on (a seeded sample of) the given map images' descriptors and index them."""
        params = params or BowParams()
        rng = np.random.default_rng(params.seed)
        data = np.concatenate([as_float(f) for f in features if len(f)] or [np.zeros((0, 1), np.float32)])
        if not len(data):
            raise ValueError("BowIndex.build: the map images have no descriptors")
        data = sample_rows(data, params.sample, rng)
        tree = VocabularyTree.train(data, params.branching, params.depth, params.iterations, rng)
        raw = np.stack([cls._counts(tree, f) for f in features])
        df = (raw > 0).sum(0)
        idf = snap(np.log((len(features) + 1) / (df + 1)), UNIT_STEP).astype(np.float32)  # log: CPU-dispatched
        index = cls(tree, idf, np.zeros_like(raw), params)
        index.histograms = np.stack([index._normalise(r) for r in raw])
        return index

    @staticmethod
    def _counts(tree: VocabularyTree, features: Features) -> np.ndarray:
        if not len(features):
            return np.zeros(tree.num_words, np.float32)
        return np.bincount(tree.words(as_float(features)), minlength=tree.num_words).astype(np.float32)

    def _normalise(self, counts: np.ndarray) -> np.ndarray:
        h = counts * self.idf
        norm = np.abs(h).sum() if self.params.scoring == "l1" else np.linalg.norm(h)
        return h / max(float(norm), 1e-12)

    def scores(self, features: Features) -> np.ndarray:
        """Similarity of the query to each map image (higher is more similar)."""
        q = self._normalise(self._counts(self.tree, features))
        if self.params.scoring == "l1":
            return 2.0 - np.abs(self.histograms - q[None]).sum(1)
        return self.histograms @ q

    def query(self, features: Features, top_k: int) -> np.ndarray:
        """Indices of the ``top_k`` most similar map images, best first (ties by index)."""
        score = self.scores(features)
        return np.lexsort((np.arange(len(score)), -score))[:top_k]

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = {f"bow_centres_{level}": c for level, c in enumerate(self.tree.centres)}
        params = np.array([self.params.branching, self.params.depth, self.params.sample, self.params.iterations,
                           self.params.seed, int(self.params.points_only)], np.int64)
        return arrays | {"bow_idf": self.idf, "bow_histograms": self.histograms, "bow_params": params,
                         "bow_scoring": np.array(self.params.scoring)}

    @classmethod
    def from_arrays(cls, data) -> BowIndex:
        branching, depth, sample, iterations, seed, points_only = (int(v) for v in data["bow_params"])
        params = BowParams(branching, depth, str(data["bow_scoring"]), sample, iterations, seed, bool(points_only))
        tree = VocabularyTree([data[f"bow_centres_{level}"] for level in range(depth)], branching)
        return cls(tree, data["bow_idf"], data["bow_histograms"], params)
