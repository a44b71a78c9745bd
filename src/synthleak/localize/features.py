"""Local feature extractors, one per tier family. Keypoints use COLMAP's pixel convention.

COLMAP (and our cameras) put the centre of pixel (0, 0) at (0.5, 0.5); OpenCV and kornia put it at
(0, 0), so their keypoints are shifted by +0.5 here. torch/kornia are imported lazily (see
:mod:`synthleak.localize.deep`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import cv2
import numpy as np

from synthleak.errors import SynthleakError


@dataclass
class Features:
    """Keypoints (N, 2) float64 in COLMAP pixel convention and their descriptors.

    ``binary`` descriptors are packed uint8 bit strings (Hamming distance); others are float32 rows.
    """

    keypoints: np.ndarray
    descriptors: np.ndarray
    binary: bool = False
    scores: np.ndarray | None = None
    image_size: tuple[int, int] = (0, 0)
    """(width, height) of the source image (LightGlue normalises keypoints with it)."""

    def __len__(self) -> int:
        return len(self.keypoints)

    def subset(self, index: np.ndarray) -> Features:
        return Features(self.keypoints[index], self.descriptors[index], self.binary,
                        None if self.scores is None else self.scores[index], self.image_size)


class MissingFeatureError(SynthleakError, RuntimeError):
    """The installed libraries do not provide a tier's detector."""


class Extractor(Protocol):
    """Turns an (H, W, 3) uint8 RGB image into :class:`Features`."""

    def __call__(self, rgb: np.ndarray) -> Features: ...


def to_gray(rgb: np.ndarray) -> np.ndarray:
    """uint8 (H, W) grey image from RGB or grey input."""
    if rgb.ndim == 2:
        return np.ascontiguousarray(rgb, dtype=np.uint8)
    return np.ascontiguousarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))


SIFT_DIM = 128
"""SIFT descriptor length (float32)."""


class SiftExtractor:
    """COLMAP SIFT (pycolmap, CPU), single threaded: COLMAP's uint8 descriptors (L1-root normalised, scaled
    by 512) held as integer-valued float32 rows. Their dot products are integers below 2^24, exact in float32
    whatever the BLAS kernel sums first; the matcher compares them as unit vectors
    (:func:`~synthleak.localize.matching.unit_scores`), so SIFT matches are the same on every CPU
    (``docs/determinism.md``)."""

    def __init__(self, max_keypoints: int) -> None:
        import pycolmap

        self._options = pycolmap.FeatureExtractionOptions()
        self._options.num_threads = 1
        self._options.sift.max_num_features = int(max_keypoints)

    def __call__(self, rgb: np.ndarray) -> Features:
        """The image's features, whatever this extractor saw before: a ``pycolmap.FeatureExtractor`` keeps state
        between images (after a frame of 8 keypoints, a textured frame gave 867 instead of 2262), so each image
        gets a fresh one (0.01 ms to make, against about 200 ms to extract a 480x360 frame)."""
        import pycolmap

        extractor = pycolmap.FeatureExtractor.create(self._options, pycolmap.Device.cpu)
        keypoints, descriptors = extractor.extract_from_uint8_array(to_gray(rgb))
        kp = np.array([[k.x, k.y] for k in keypoints], dtype=np.float64).reshape(-1, 2)
        if not len(kp):  # a blank image: no keypoint, and an empty descriptor matrix of unknown width
            return Features(kp, np.zeros((0, SIFT_DIM), np.float32))
        return Features(kp, np.asarray(descriptors.data, dtype=np.float32).reshape(len(kp), -1))


class OpenCVExtractor:
    """OpenCV ORB or AKAZE: binary descriptors, the strongest ``max_keypoints`` responses kept."""

    def __init__(self, kind: str, max_keypoints: int) -> None:
        self.kind = kind
        self.max_keypoints = int(max_keypoints)
        if kind == "orb":
            self._detector = cv2.ORB_create(nfeatures=self.max_keypoints, fastThreshold=10)
        elif kind == "akaze":
            if not hasattr(cv2, "AKAZE_create"):
                raise MissingFeatureError(
                    f"tier 'akaze': OpenCV {cv2.__version__} has no AKAZE "
                    "(OpenCV 5 moved it to opencv-contrib); "
                    "install an OpenCV build with AKAZE (opencv-contrib-python-headless) or pick another tier"
                )
            self._detector = cv2.AKAZE_create(threshold=3e-4)
        else:
            raise ValueError(f"OpenCVExtractor: unknown kind {kind!r} (orb, akaze)")

    def __call__(self, rgb: np.ndarray) -> Features:
        keypoints, descriptors = self._detector.detectAndCompute(to_gray(rgb), None)
        if descriptors is None or not keypoints:  # a blank image
            return Features(np.zeros((0, 2)), np.zeros((0, self._detector.descriptorSize()), np.uint8), binary=True,
                            scores=np.zeros(0))
        response = np.array([k.response for k in keypoints])
        order = np.argsort(-response, kind="stable")[: self.max_keypoints]
        kp = np.array([keypoints[i].pt for i in order], dtype=np.float64) + 0.5
        return Features(kp, np.ascontiguousarray(descriptors[order]), binary=True, scores=response[order])
