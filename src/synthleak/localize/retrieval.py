"""Image retrieval for localization: ``exhaustive`` (every map image) or ``bow``.

``bow`` is a bag of visual words: a k-means vocabulary (256 words, seeded) over the map's descriptors,
tf-idf weighted L2-normalised histograms, cosine similarity; the ``top_k`` best map images are matched.
Binary descriptors are clustered as 0/1 bit vectors.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.cluster.vq import kmeans2

from synthleak.localize.features import Features

RETRIEVAL_METHODS = ("exhaustive", "bow")


def _as_float(features: Features) -> np.ndarray:
    if features.binary:
        return np.unpackbits(features.descriptors, axis=1).astype(np.float32)
    return features.descriptors.astype(np.float32)


class BowIndex:
    """Vocabulary, idf weights and the map images' histograms."""

    def __init__(self, words: np.ndarray, idf: np.ndarray, histograms: np.ndarray) -> None:
        self.words, self.idf, self.histograms = words, idf, histograms

    @classmethod
    def build(
        cls, features: list[Features], num_words: int = 256, seed: int = 0, sample: int = 20000
    ) -> BowIndex:
        rng = np.random.default_rng(seed)
        data = np.concatenate([_as_float(f) for f in features if len(f)])
        if len(data) > sample:
            data = data[np.sort(rng.choice(len(data), sample, replace=False))]
        k = int(min(num_words, max(2, len(data) // 4)))
        with warnings.catch_warnings():  # an empty cluster is just an unused word
            warnings.filterwarnings("ignore", message="One of the clusters is empty")
            words, _ = kmeans2(data.astype(np.float64), k, iter=10, minit="points", seed=rng)
        words = words.astype(np.float32)
        raw = np.stack([cls._counts(words, f) for f in features])
        df = (raw > 0).sum(0)
        idf = np.log((len(features) + 1) / (df + 1)).astype(np.float32)
        index = cls(words, idf, np.zeros_like(raw))
        index.histograms = np.stack([index._normalise(r) for r in raw])
        return index

    @staticmethod
    def _counts(words: np.ndarray, features: Features) -> np.ndarray:
        if not len(features):
            return np.zeros(len(words), np.float32)
        x = _as_float(features)
        d = (x * x).sum(1, keepdims=True) - 2 * x @ words.T + (words * words).sum(1)[None]
        return np.bincount(np.argmin(d, axis=1), minlength=len(words)).astype(np.float32)

    def _normalise(self, counts: np.ndarray) -> np.ndarray:
        h = counts * self.idf
        return h / max(float(np.linalg.norm(h)), 1e-12)

    def query(self, features: Features, top_k: int) -> np.ndarray:
        """Indices of the ``top_k`` most similar map images, best first (ties by index)."""
        score = self.histograms @ self._normalise(self._counts(self.words, features))
        return np.lexsort((np.arange(len(score)), -score))[:top_k]

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"bow_words": self.words, "bow_idf": self.idf, "bow_histograms": self.histograms}

    @classmethod
    def from_arrays(cls, data) -> BowIndex:
        return cls(data["bow_words"], data["bow_idf"], data["bow_histograms"])
