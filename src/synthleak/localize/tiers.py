"""Robustness tiers: a feature extractor, a matcher and its strictness, PnP thresholds. Select by name.

Least to most robust (tier: features / matcher / ratio, mutual / default min inliers):

* ``orb``: OpenCV ORB (binary) / Hamming NN / 0.75, mutual / 20
* ``akaze``: OpenCV AKAZE (binary; absent from OpenCV 5 main) / Hamming NN / 0.8, mutual / 15
* ``sift``: COLMAP SIFT (pycolmap) / L2 NN / 0.8, mutual / 15
* ``kornia-sift``: kornia SIFTFeature / kornia DescriptorMatcher ``smnn`` / 0.8 / 15
* ``disk-lightglue``: kornia DISK / kornia LightGlue (learned, no ratio test) / 20

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

    def make_extractor(self, max_keypoints: int, weights_dir: Path | None = None) -> Extractor:
        if self.name == "sift":
            return SiftExtractor(max_keypoints)
        if self.name in ("orb", "akaze"):
            return OpenCVExtractor(self.name, max_keypoints)
        from synthleak.localize import deep

        if self.name == "kornia-sift":
            return deep.KorniaSiftExtractor(max_keypoints)
        if self.name == "disk-lightglue":
            return deep.DiskExtractor(max_keypoints, weights_dir)
        raise ValueError(f"tier {self.name!r}: no extractor")

    def make_matcher(self, weights_dir: Path | None = None) -> Matcher:
        if self.name == "kornia-sift":
            from synthleak.localize import deep

            return deep.KorniaDescriptorMatcher(self.ratio)
        if self.name == "disk-lightglue":
            from synthleak.localize import deep

            return deep.LightGlueMatcher(weights_dir)
        ratio, mutual = self.ratio, self.mutual
        return lambda a, b: match_features(a, b, ratio, mutual)


TIERS: dict[str, Tier] = {
    t.name: t
    for t in (
        Tier("orb", ratio=0.75, mutual=True, pnp_max_error_px=12.0, min_inliers=20),
        Tier("akaze", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15),
        Tier("sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15),
        Tier("kornia-sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=True),
        Tier("disk-lightglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=20,
             needs_torch=True),
    )
}


def get_tier(name: str) -> Tier:
    """The tier called ``name``; raises naming the known tiers."""
    try:
        return TIERS[name]
    except KeyError:
        raise ValueError(f"unknown localization tier {name!r} (known: {', '.join(TIERS)})") from None
