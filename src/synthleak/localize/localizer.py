"""In-process localization against a map: features -> retrieval -> 2D-3D matches -> RANSAC PnP."""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import camera_dist_coeffs
from synthleak.core.types import Camera
from synthleak.localize.defense import DefenseDecision, DefensePolicy
from synthleak.localize.features import Features
from synthleak.localize.images import MAX_QUERY_PIXELS, InvalidImageError, decode_image, fit_to_pixels
from synthleak.localize.pnp import estimate_pose
from synthleak.localize.representations import map_representation, read_represented_map
from synthleak.localize.retrieval import RETRIEVAL_METHODS, BowIndex
from synthleak.localize.store import MapData, MapError
from synthleak.localize.tiers import DEFAULT_PROFILE, Tier, profile_fixes, profile_tier
from synthleak.localize.two_view import verified_matches
from synthleak.schema import as_list

RANSAC_SEED = 0


def undistorted_keypoints(keypoints: np.ndarray, camera: Camera) -> tuple[np.ndarray, Camera]:
    """``keypoints`` of a distorted ``camera`` as the pinhole camera of the same intrinsics sees them (and that
    camera); a pinhole camera's unchanged. A keypoint beyond the lens model's range goes far outside the image
    (it matches no line)."""
    dist = camera_dist_coeffs(camera)
    if dist is None:
        return keypoints, camera
    from synthleak.render.distortion import undistort_normalized

    x, y = undistort_normalized((keypoints[:, 0] - camera.cx) / camera.fx, (keypoints[:, 1] - camera.cy) / camera.fy,
                                dist, strict=False)
    out = np.stack([x * camera.fx + camera.cx, y * camera.fy + camera.cy], axis=1)
    out[~np.isfinite(out).all(axis=1)] = -1e9
    return out, Camera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)


def with_image_size(query: Features, camera: Camera) -> Features:
    """``query`` with the camera's image size where its features carry none."""
    return replace(query, image_size=(camera.width, camera.height)) if query.image_size == (0, 0) else query


@dataclass
class LocalizationResult:
    """Outcome of one query. ``cam_from_world`` is a 4x4 float64 pose or None (not localized)."""

    success: bool
    cam_from_world: np.ndarray | None = None
    num_inliers: int = 0
    num_matches: int = 0
    inlier_instance_counts: dict[int, int] = field(default_factory=dict)
    defense: DefenseDecision | None = None
    retrieved: list[str] = field(default_factory=list)
    """Names of the map images the query was matched against (the retrieval's top k, or all), sorted."""
    timings: dict[str, float] = field(default_factory=dict)
    """Seconds: ``features``, ``retrieval``, ``matching`` (retrieval + matching), ``pnp``, ``total``."""
    withheld_cam_from_world: np.ndarray | None = None
    """The pose PnP found for a query the enabled defense refused (server-side only: the HTTP answer is
    ``{"success": false}``); studies log it to attack the same queries with and without the defense."""
    inlier_matches: np.ndarray | None = None
    """(K, 2) ``(query keypoint, map point)`` PnP inliers, one per query keypoint (in process only; benchmarks
    read where a query's inliers lie in its image)."""


class Localizer:
    """Answers pose queries against one map. Not thread-safe (serialise calls)."""

    def __init__(
        self,
        data: MapData,
        tier: Tier,
        config: LocalizeConfig,
        defense: DefensePolicy | None = None,
        weights_dir: Path | None = None,
        decision_log: Path | None = None,
    ) -> None:
        if config.retrieval not in RETRIEVAL_METHODS:
            raise ValueError(f"LocalizeConfig.retrieval: unknown method {config.retrieval!r} "
                             f"(known: {', '.join(RETRIEVAL_METHODS)})")
        self.data, self.tier, self.config = data, tier, config
        self.defense = defense or DefensePolicy()
        self.decision_log = decision_log
        self.extractor = tier.make_extractor(config.max_keypoints, weights_dir)
        self.matcher = tier.make_matcher(weights_dir)
        fixed = profile_fixes(tier, config.profile)  # a profile's own values win over the config's override
        self.min_inliers = tier.min_inliers if "min_inliers" in fixed else config.min_inliers or tier.min_inliers
        self.max_error_px = (tier.pnp_max_error_px if "pnp_max_error_px" in fixed
                             else config.pnp_max_error_px or tier.pnp_max_error_px)
        self.two_view_min_inliers = int(config.two_view_min_inliers)
        # Only keypoints with a 3D point take part in 2D-3D matching.
        self._db: list[tuple[Features, np.ndarray]] = []
        self._mapped: list[np.ndarray] = []
        for f, idx in zip(data.features, data.point_index, strict=True):
            keep = np.nonzero(idx >= 0)[0]
            self._db.append((f.subset(keep), idx[keep]))
            self._mapped.append(keep)
        self._bow: BowIndex | None = None
        self.max_query_pixels = MAX_QUERY_PIXELS

    @classmethod
    def load(
        cls,
        map_dir: Path,
        config: LocalizeConfig | None = None,
        defense: DefensePolicy | None = None,
        weights_dir: Path | None = None,
        decision_log: Path | None = None,
    ) -> Localizer:
        """Load a map built by :func:`synthleak.localize.build_map`; the tier is the map's, as ``config.profile``
        defines it (:func:`~synthleak.localize.tiers.profile_tier`). Raises :class:`MapError` when the map was
        built under another server profile (its matches were filtered with other thresholds)."""
        map_dir = Path(map_dir)
        config = config or LocalizeConfig()
        data = read_represented_map(map_dir, config.representation)  # refuses another representation's map
        built = data.meta.get("settings", {}).get("profile", DEFAULT_PROFILE)
        if built not in as_list(config.profile):
            raise MapError(f"{map_dir / 'map.json'}: built with [localize] profile = {built!r}, but this "
                           f"server's config has profile = {config.profile!r}: serve it with a config of "
                           f"profile {built!r}, or rebuild the map")
        # a study's lists of profiles and representations: the ones of this map
        config = replace(config, profile=built, representation=map_representation(data.meta))
        loc = cls(data, profile_tier(data.meta["tier"], config.profile), config, defense, weights_dir,
                  decision_log)
        if loc.config.retrieval == "bow" or loc.tier.learned_matcher:  # a learned matcher: top_k images only
            with np.load(map_dir / "bow.npz") as arrays:
                loc._bow = BowIndex.from_arrays(arrays)
        return loc

    @property
    def camera(self) -> Camera:
        """The map's intrinsics (used when a query gives none)."""
        return self.data.camera

    def candidates(self, query: Features) -> np.ndarray:
        """Indices of the map images the query is matched against, ascending: the retrieval's top k, or all."""
        if self._bow is None:
            return np.arange(len(self._db))
        return np.sort(self._bow.query(query, self.config.top_k))

    def localize(self, image: np.ndarray | bytes, camera: Camera | None = None) -> LocalizationResult:
        """Pose of ``image`` (RGB array or encoded bytes) or not localized.

        Encoded images over :data:`~synthleak.localize.images.MAX_QUERY_PIXELS` are refused from their
        header (:class:`~synthleak.localize.images.ImageTooLargeError`); an image with more pixels than the
        map's images is downscaled to their pixel count with its intrinsics scaled, so no query costs more
        than a map image to extract (:func:`~synthleak.localize.images.fit_to_pixels`)."""
        t0 = time.perf_counter()
        rgb = decode_image(image, self.max_query_pixels)
        camera = camera or self.camera
        if (rgb.shape[1], rgb.shape[0]) != (camera.width, camera.height):
            raise InvalidImageError(f"image is {rgb.shape[1]}x{rgb.shape[0]} but the camera is "
                                    f"{camera.width}x{camera.height}")
        rgb, camera = fit_to_pixels(rgb, camera, self.camera.width * self.camera.height)
        query = self.extractor(rgb)
        t1 = time.perf_counter()
        result = self.localize_features(query, camera)
        result.timings |= {"features": t1 - t0, "total": time.perf_counter() - t0}
        return result

    def localize_features(self, query: Features, camera: Camera | None = None,
                          candidates: np.ndarray | None = None, matches: list[np.ndarray] | None = None,
                          ) -> LocalizationResult:
        """Pose from the query's already extracted features (this map's tier and ``max_keypoints``): the same
        result as :meth:`localize` on the image they came from, without extracting them again.
        ``candidates`` (map image indices) replaces the retrieval (benchmarks compare retrievals with it);
        ``matches``, the candidates' :meth:`pair_matches` made before (shared with another server of the tier, or
        cached), replaces the matching: the result is then the pose estimation's alone."""
        camera = camera or self.camera
        query = with_image_size(query, camera)
        t1 = time.perf_counter()
        if not len(query):  # a blank image: nothing to match
            return LocalizationResult(False, timings={"features": 0.0, "retrieval": 0.0, "matching": 0.0,
                                                      "pnp": 0.0, "total": 0.0})
        if candidates is None:
            candidates = self.candidates(query)
        t_retrieval = time.perf_counter() - t1
        if matches is None:
            matches = self.pair_matches(query, candidates)
        corr, num_matches = self._verified(query, candidates, matches, camera)
        t2 = time.perf_counter()
        result = self.pose_from_matches(query, corr, camera, num_matches)
        t3 = time.perf_counter()
        result.timings = {"features": 0.0, "retrieval": t_retrieval, "matching": t2 - t1, "pnp": t3 - t2,
                          "total": t3 - t1}
        result.retrieved = sorted(self.data.names[int(i)] for i in candidates)
        return result

    def pair_matches(self, query: Features, candidates: np.ndarray) -> list[np.ndarray]:
        """Per candidate map image, the (M, 2) ``(query keypoint, map image keypoint)`` matches (indices into the
        map image's keypoints that have a 3D point or line)."""
        return [self.matcher(query, self._db[i][0]) for i in candidates]

    def mapped_keypoints(self, image: int) -> np.ndarray:
        """Indices, ascending, of map image ``image``'s keypoints that have a 3D point or line: the columns
        :meth:`pair_matches` indexes."""
        return self._mapped[image]

    def correspondences(self, query: Features, candidates: np.ndarray) -> np.ndarray:
        """(M, 2) unique ``(query keypoint, map point)`` matches against the ``candidates`` map images, sorted."""
        return self._point_matches(candidates, self.pair_matches(query, candidates))

    def verified_correspondences(self, query: Features, candidates: np.ndarray, camera: Camera | None = None
                                 ) -> tuple[np.ndarray, int]:
        """The matches :meth:`correspondences` gives that pass two-view verification (``[localize]
        two_view_min_inliers``, :mod:`synthleak.localize.two_view`; all of them when it is 0), and how many
        matches there were before it. ``camera``: the query's (default: the map's)."""
        return self._verified(query, candidates, self.pair_matches(query, candidates), camera)

    def _verified(self, query: Features, candidates: np.ndarray, matches: list[np.ndarray], camera: Camera | None
                  ) -> tuple[np.ndarray, int]:
        every = self._point_matches(candidates, matches)
        if not self.two_view_min_inliers:
            return every, len(every)
        return self.verify_pairs(query, candidates, matches, camera), len(every)

    def verify_pairs(self, query: Features, candidates: np.ndarray, matches: list[np.ndarray],
                     camera: Camera | None = None, min_inliers: int | None = None) -> np.ndarray:
        """The ``(query keypoint, map point)`` matches, unique and sorted, of the ``candidates``' pair
        ``matches`` (:meth:`pair_matches`) that are essential-matrix inliers of a pair with at least
        ``min_inliers`` of them (default: the config's ``two_view_min_inliers``)."""
        pairs = [(m, self._db[i][0].keypoints, self._db[i][1]) for i, m in zip(candidates, matches, strict=True)]
        kept = verified_matches(query.keypoints, pairs, camera or self.camera, self.camera, float(self.max_error_px),
                                self.two_view_min_inliers if min_inliers is None else int(min_inliers),
                                seed=RANSAC_SEED)
        return self._union(kept)

    def _point_matches(self, candidates: np.ndarray, matches: list[np.ndarray]) -> np.ndarray:
        """The union of the ``candidates``' pair ``matches`` as ``(query keypoint, map point)``, sorted."""
        return self._union([np.stack([m[:, 0], self._db[i][1][m[:, 1]]], axis=1)
                            for i, m in zip(candidates, matches, strict=True)])

    @staticmethod
    def _union(parts: list[np.ndarray]) -> np.ndarray:
        pairs: set[tuple[int, int]] = set()
        for part in parts:
            pairs.update(zip(part[:, 0].tolist(), part[:, 1].tolist(), strict=True))
        return np.array(sorted(pairs), dtype=np.int64).reshape(-1, 2)

    def pose_from_matches(self, query: Features, corr: np.ndarray, camera: Camera,
                          num_matches: int | None = None) -> LocalizationResult:
        """RANSAC PnP on 2D-3D matches (``min_inliers``, ``max_error_px``), inlier instance counts, defense.
        ``num_matches``: the matches before two-view verification (default ``len(corr)``), on which the line
        server's success count is computed and which the result reports."""
        num_matches = len(corr) if num_matches is None else int(num_matches)
        if len(corr) < max(self.min_inliers, 3):  # P3P: 3 matches (COLMAP, HLoc)
            return LocalizationResult(False, num_matches=num_matches)
        lines = getattr(self.data, "lines", None)
        min_inliers = self.min_inliers
        if lines is not None:  # a line-cloud map (Speciale et al. 2019): the same result, from 2D-3D-line matches
            from synthleak.localize.line_cloud import (
                LineRansacOptions,
                equivalent_line_threshold,
                estimate_pose_from_lines,
                line_min_inliers,
            )

            threshold = equivalent_line_threshold(float(self.max_error_px), camera)  # as many chance inliers
            keypoints, pinhole = undistorted_keypoints(query.keypoints[corr[:, 0]], camera)
            # as rarely accepted by chance as the point server's min_inliers at max_error_px on as many matches
            min_inliers = line_min_inliers(num_matches, self.min_inliers, float(self.max_error_px), threshold,
                                           pinhole)
            est = estimate_pose_from_lines(
                keypoints, lines.directions[corr[:, 1]], lines.anchors[corr[:, 1]], pinhole,
                LineRansacOptions(max_error_px=threshold, min_inliers=min_inliers), seed=RANSAC_SEED)
            if est is None:
                return LocalizationResult(False, num_matches=num_matches)
            cam_from_world, inlier_mask = est["cam_from_world"].matrix(), np.asarray(est["inlier_mask"], dtype=bool)
        else:  # undistorted keypoints, the pinhole camera (:mod:`synthleak.localize.pnp`)
            keypoints, pinhole = undistorted_keypoints(query.keypoints[corr[:, 0]], camera)
            solved = estimate_pose(keypoints, self.data.xyz[corr[:, 1]], pinhole, float(self.max_error_px),
                                   RANSAC_SEED, self.config.pnp_solver)
            if solved is None:
                return LocalizationResult(False, num_matches=num_matches)
            cam_from_world, inlier_mask = solved.cam_from_world, solved.inlier_mask
        inliers = corr[inlier_mask]
        _, first = np.unique(inliers[:, 0], return_index=True)  # one vote per query keypoint
        counts = Counter(int(self.data.instance[p]) for p in inliers[first, 1])
        counts_sorted = {k: counts[k] for k in sorted(counts)}
        num_inliers = len(first)
        pose = np.eye(4)
        pose[:3] = cam_from_world
        success = num_inliers >= min_inliers
        decision = self.defense.apply(counts_sorted) if success else None
        withheld = None
        if decision is not None:
            self._log(decision, num_inliers)
            if self.defense.enabled and not decision.accepted:
                success, withheld = False, pose
        return LocalizationResult(success, pose if success else None, num_inliers, num_matches, counts_sorted,
                                  decision, withheld_cam_from_world=withheld, inlier_matches=inliers[first])

    def _log(self, decision: DefenseDecision, num_inliers: int) -> None:
        if self.decision_log is not None:
            log_decision(self.decision_log, self.defense, decision, num_inliers)


def log_decision(path: Path, defense: DefensePolicy, decision: DefenseDecision, num_inliers: int) -> None:
    """Append one defense decision (with its inlier counts) to the JSONL decision log at ``path``."""
    record = {"time": time.time(), "enabled": defense.enabled, "num_inliers": num_inliers, **decision.to_json()}
    with open(path, "a") as fh:
        fh.write(json.dumps(record) + "\n")
