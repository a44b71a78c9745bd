"""Robustness tiers: a feature extractor, a matcher and its strictness, PnP thresholds. Select by name.

Least to most robust (tier: features / matcher / ratio, mutual / default min inliers):

* ``orb``: OpenCV ORB (binary) / Hamming NN / 0.75, mutual / 20
* ``akaze``: OpenCV AKAZE (binary; absent from OpenCV 5 main) / Hamming NN / 0.8, mutual / 15
* ``sift``: COLMAP SIFT (pycolmap) / L2 NN / 0.8, mutual / 15
* ``kornia-sift``: kornia SIFTFeature / kornia DescriptorMatcher ``smnn`` / 0.8 / 15
* ``xfeat``: XFeat (learned, 64-D) / L2 NN / 0.9, mutual (the paper's R2D2+NN analogue) / 30
* ``xfeat-lighterglue``: XFeat / LighterGlue (learned matcher), match score > 0.3 / 30
* ``disk-lightglue``: DISK / LightGlue (learned matcher), match score > 0.3 / 30
* ``aliked-lightglue``: ALIKED-N16 / LightGlue (learned matcher), match score > 0.3 / 30

Why stricter than the published defaults (plain mutual NN; LightGlue's score threshold 0.1) and more inliers than
SIFT: with those defaults, attacker images of objects absent from a room were localized in it as often as those
of present objects (study-small-pyrender, 480x360: XFeat + mutual NN localized 311 of 312 absent-object queries
with >= 20 inliers, LighterGlue 129), so a localization said nothing. With these settings, on a third of those
queries, none (XFeat) and 1 of 104 (LighterGlue) absent-object queries localize.

The learned tiers (see :mod:`synthleak.localize.deep` for models, weights and threads) have a keypoint budget:
they keep at most ``min(LocalizeConfig.max_keypoints, Tier.max_keypoints)`` keypoints per image. A tier with a
learned matcher matches a query only against the ``top_k`` map images that bag-of-words retrieval ranks first,
whatever ``LocalizeConfig.retrieval`` says (matching every map image would cost a network pass per image).

All use RANSAC PnP with a 12 px threshold (HLoc's default).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synthleak.localize.features import Extractor, Features, OpenCVExtractor, SiftExtractor
from synthleak.localize.matching import match_features

Matcher = Callable[[Features, Features], np.ndarray]
"""``matcher(a, b) -> (M, 2)`` indices into ``a`` and ``b``."""


@dataclass(frozen=True)
class Tier:
    """One robustness tier: names its extractor/matcher and their strictness."""

    name: str
    ratio: float
    mutual: bool
    pnp_max_error_px: float
    min_inliers: int
    needs_torch: bool = False
    max_keypoints: int = 0
    """Keypoint budget per image (0: none beyond ``LocalizeConfig.max_keypoints``)."""
    learned_matcher: bool = False
    """Queries are matched only against the ``top_k`` retrieved map images."""
    weights: tuple[str, ...] = ()
    """Weight files loaded (keys of :data:`synthleak.localize.deep.WEIGHTS`)."""
    match_threshold: float = 0.0
    """Learned matchers: the match score a match must exceed (LightGlue's ``filter_threshold``)."""

    def keypoint_budget(self, max_keypoints: int) -> int:
        """Keypoints kept per image: ``max_keypoints`` capped by the tier's budget."""
        return min(int(max_keypoints), self.max_keypoints) if self.max_keypoints else int(max_keypoints)

    def weights_record(self, weights_dir: Path | None = None) -> dict[str, dict[str, str]]:
        """sha256 and source of each weight file (empty for tiers without weights)."""
        if not self.weights:
            return {}
        from synthleak.localize import deep

        return deep.weights_record(self.weights, weights_dir)

    def make_extractor(self, max_keypoints: int, weights_dir: Path | None = None) -> Extractor:
        max_keypoints = self.keypoint_budget(max_keypoints)
        if self.name == "sift":
            return SiftExtractor(max_keypoints)
        if self.name in ("orb", "akaze"):
            return OpenCVExtractor(self.name, max_keypoints)
        from synthleak.localize import deep

        if self.name == "kornia-sift":
            return deep.KorniaSiftExtractor(max_keypoints)
        if self.name in ("xfeat", "xfeat-lighterglue"):
            return deep.XFeatExtractor(max_keypoints, weights_dir)
        if self.name == "disk-lightglue":
            return deep.DiskExtractor(max_keypoints, weights_dir)
        if self.name == "aliked-lightglue":
            return deep.AlikedExtractor(max_keypoints, weights_dir)
        raise ValueError(f"tier {self.name!r}: no extractor")

    def make_matcher(self, weights_dir: Path | None = None) -> Matcher:
        if self.name == "kornia-sift":
            from synthleak.localize import deep

            return deep.KorniaDescriptorMatcher(self.ratio)
        if self.learned_matcher:
            from synthleak.localize import deep

            return deep.LightGlueMatcher(self.name.split("-")[0], weights_dir, self.match_threshold)
        ratio, mutual = self.ratio, self.mutual
        return lambda a, b: match_features(a, b, ratio, mutual)


TIERS: dict[str, Tier] = {
    t.name: t
    for t in (
        Tier("orb", ratio=0.75, mutual=True, pnp_max_error_px=12.0, min_inliers=20),
        Tier("akaze", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15),
        Tier("sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15),
        Tier("kornia-sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=True),
        Tier("xfeat", ratio=0.9, mutual=True, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
             max_keypoints=4096, weights=("xfeat",)),
        Tier("xfeat-lighterglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
             max_keypoints=1024, learned_matcher=True, weights=("xfeat", "xfeat-lighterglue"), match_threshold=0.3),
        Tier("disk-lightglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
             max_keypoints=1024, learned_matcher=True, weights=("disk", "disk-lightglue"), match_threshold=0.3),
        Tier("aliked-lightglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
             max_keypoints=1024, learned_matcher=True, weights=("aliked-n16", "aliked-lightglue"),
             match_threshold=0.3),
    )
}


def get_tier(name: str) -> Tier:
    """The tier called ``name``; raises naming the known tiers."""
    try:
        return TIERS[name]
    except KeyError:
        raise ValueError(f"unknown localization tier {name!r} (known: {', '.join(TIERS)})") from None
