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

All use RANSAC PnP with a 12 px threshold (HLoc's default; ``LocalizeConfig.pnp_max_error_px`` overrides it for
the ``strict`` profile: the study presets scale it to their image width, see ``render_configs/study.toml``).

Server profiles (``[localize] profile``, :data:`PROFILES`, :func:`profile_tier`): ``strict`` is the table above;
``hloc`` sets each tier's matching and PnP fields to HLoc's published defaults (``docs/learned-tiers.md``, "Server
profiles", has the table and its sources).

Adding a tier is one registration: :func:`register_tier` with its :class:`Tier` definition, an extractor
factory and (unless mutual-NN + ratio matching suits it) a matcher factory, here or in the module that holds the
extractor. The config's ``[localize] tiers``, ``synthleak map --tier`` and ``get_tier`` read this registry
(``docs/ARCHITECTURE.md``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.localize.features import Extractor, Features, OpenCVExtractor, SiftExtractor
from synthleak.localize.matching import match_features, pair_scores
from synthleak.plugins import resolve

Matcher = Callable[[Features, Features], np.ndarray]
"""``matcher(a, b) -> (M, 2)`` indices into ``a`` and ``b``."""


@dataclass(frozen=True)
class Tier:
    """One robustness tier: names its extractor/matcher and their strictness.

    Its fields are the tier's *definition*: a learned tier's maps and query features record them (``map.json``,
    the study's cache keys), so a change rebuilds them. The extractor and matcher are found by name in the
    registry (:func:`register_tier`)."""

    name: str
    ratio: float
    mutual: bool
    pnp_max_error_px: float
    """RANSAC PnP threshold (px), used where ``LocalizeConfig.pnp_max_error_px`` is 0."""
    min_inliers: int
    """Fewest PnP inliers of a localized query, used where ``LocalizeConfig.min_inliers`` is 0."""
    needs_torch: bool = False
    max_keypoints: int = 0
    """Keypoint budget per image (0: none beyond ``LocalizeConfig.max_keypoints``)."""
    learned_matcher: bool = False
    """Queries are matched only against the ``top_k`` retrieved map images."""
    weights: tuple[str, ...] = ()
    """Weight files loaded (keys of :data:`synthleak.localize.deep.WEIGHTS`)."""
    match_threshold: float = 0.0
    """Learned matchers: the match score a match must exceed (LightGlue's ``filter_threshold``)."""
    ratio_both_ways: bool = False
    """Nearest-neighbour matchers: the ratio test also from the map image's side before the mutual check (HLoc's
    ``NN-ratio``, hloc/matchers/nearest_neighbor.py:51-58); False: from the query side only."""

    def definition(self) -> dict[str, Any]:
        """The fields that enter maps' and cache keys: every field, except those added after keys were first
        written (:data:`LATER_FIELDS`) while they hold their default (so existing maps and keys stay valid)."""
        return {k: v for k, v in asdict(self).items() if not (k in LATER_FIELDS and v == LATER_FIELDS[k])}

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
        """The registered extractor, keeping at most :meth:`keypoint_budget` keypoints per image."""
        return _registered(self.name)[0](self, self.keypoint_budget(max_keypoints), weights_dir)

    def make_matcher(self, weights_dir: Path | None = None) -> Matcher:
        """The registered matcher."""
        return _registered(self.name)[1](self, weights_dir)


LATER_FIELDS: dict[str, Any] = {"ratio_both_ways": False}
"""Tier fields added after maps recorded tier definitions, with the default a definition leaves out."""

ExtractorFactory = Callable[[Tier, int, Path | None], Extractor]
"""``factory(tier, max_keypoints, weights_dir) -> Extractor`` (``max_keypoints`` already capped by the tier)."""
MatcherFactory = Callable[[Tier, Path | None], Matcher]
"""``factory(tier, weights_dir) -> Matcher``."""

TIERS: dict[str, Tier] = {}
"""The registered tiers by name, in registration order (least to most robust)."""
_FACTORIES: dict[str, tuple[ExtractorFactory | str, MatcherFactory | str]] = {}
_DESCRIPTIONS: dict[str, str] = {}
"""What each tier's features and matcher are, in words (not part of the definition: no cache key reads it)."""


def nn_matcher(tier: Tier, weights_dir: Path | None = None) -> Matcher:
    """Nearest-neighbour matching with the tier's ratio test and mutual check (the default matcher factory)."""
    ratio, mutual, both_ways = tier.ratio, tier.mutual, tier.ratio_both_ways
    return lambda a, b: match_features(a, b, ratio, mutual, both_ways=both_ways)


SharedMatcher = Callable[[Features, Features], list[np.ndarray]]
"""``matcher(a, b) -> [matches of each tier]``: one pair matched under several tiers' rules at once."""


def uses_nn_matcher(tier: Tier) -> bool:
    """True when ``tier`` matches with :func:`nn_matcher` (its rule a filter of one pair's scores)."""
    return _registered_matcher(tier.name) is nn_matcher


def _registered_matcher(name: str) -> MatcherFactory | str:
    try:
        return _FACTORIES[name][1]
    except KeyError:
        raise ValueError(f"tier {name!r}: no extractor registered (known: {', '.join(_FACTORIES)})") from None


def shared_matcher(tiers: list[Tier], weights_dir: Path | None = None) -> SharedMatcher:
    """One pair's matches under each of ``tiers`` (one tier under several server profiles), with the work they
    share done once: nearest-neighbour tiers (:func:`nn_matcher`) score the pair once and each applies its own
    ratio and mutual rule to the same scores (the same matches as each tier's own matcher, bit for bit); other
    matchers run once per distinct definition."""
    if all(uses_nn_matcher(t) for t in tiers):
        rules = [(t.ratio, t.mutual, t.ratio_both_ways) for t in tiers]

        def match_all(a: Features, b: Features) -> list[np.ndarray]:
            scores = pair_scores(a, b)
            return [scores.matches(ratio, mutual, both_ways=both_ways) for ratio, mutual, both_ways in rules]

        return match_all
    distinct: dict[Tier, Matcher] = {}
    for t in tiers:
        distinct.setdefault(t, t.make_matcher(weights_dir))
    matchers = [distinct[t] for t in tiers]

    def match_each(a: Features, b: Features) -> list[np.ndarray]:
        done: dict[int, np.ndarray] = {}
        for m in matchers:
            if id(m) not in done:
                done[id(m)] = m(a, b)
        return [done[id(m)] for m in matchers]

    return match_each


def register_tier(
    tier: Tier, extractor: ExtractorFactory | str, matcher: MatcherFactory | str = nn_matcher, *,
    description: str = "",
) -> Tier:
    """Make ``tier`` known by its name (a later registration of the name replaces the earlier one).

    ``extractor`` / ``matcher``: factories, or ``"package.module:function"`` imported on first use
    (:func:`synthleak.plugins.resolve`). ``description``: its features and matcher in words
    (``synthleak tiers`` shows it)."""
    TIERS[tier.name] = tier
    _FACTORIES[tier.name] = (extractor, matcher)
    _DESCRIPTIONS[tier.name] = description
    return tier


def tier_names() -> list[str]:
    """Registered tier names, least to most robust."""
    return list(TIERS)


def tier_description(name: str) -> str:
    """The features and matcher of tier ``name`` in words ("" if it was registered without)."""
    return _DESCRIPTIONS.get(get_tier(name).name, "")


def list_tiers(profile: str = "strict") -> list[dict[str, Any]]:
    """Every registered tier, least to most robust: its name, :func:`tier_description` and definition fields
    (under server ``profile``: :func:`profile_tier`)."""
    return [{"name": name, "description": tier_description(name),
             **{k: v for k, v in asdict(profile_tier(tier, profile)).items() if k != "name"}}
            for name, tier in TIERS.items()]


def get_tier(name: str) -> Tier:
    """The tier called ``name``; raises naming the known tiers."""
    try:
        return TIERS[name]
    except KeyError:
        raise ValueError(f"unknown localization tier {name!r} (known: {', '.join(TIERS)})") from None


def _registered(name: str) -> tuple[ExtractorFactory, MatcherFactory]:
    try:
        extractor, matcher = _FACTORIES[name]
    except KeyError:
        raise ValueError(f"tier {name!r}: no extractor registered (known: {', '.join(_FACTORIES)})") from None
    return resolve(extractor), resolve(matcher)


# ------------------------------------------------------------------------------------------ built-in tiers
# The torch-based factories import synthleak.localize.deep (torch, kornia) only when the tier is used.


def _opencv(tier: Tier, max_keypoints: int, weights_dir: Path | None) -> Extractor:
    return OpenCVExtractor(tier.name, max_keypoints)


def _sift(tier: Tier, max_keypoints: int, weights_dir: Path | None) -> Extractor:
    return SiftExtractor(max_keypoints)


def _kornia_sift(tier: Tier, max_keypoints: int, weights_dir: Path | None) -> Extractor:
    from synthleak.localize import deep

    return deep.KorniaSiftExtractor(max_keypoints)


def _kornia_matcher(tier: Tier, weights_dir: Path | None) -> Matcher:
    from synthleak.localize import deep

    return deep.KorniaDescriptorMatcher(tier.ratio)


def _learned(extractor: str) -> ExtractorFactory:
    """The factory of :mod:`synthleak.localize.deep`'s ``extractor`` class (max_keypoints, weights_dir)."""

    def make(tier: Tier, max_keypoints: int, weights_dir: Path | None) -> Extractor:
        from synthleak.localize import deep

        return getattr(deep, extractor)(max_keypoints, weights_dir)

    return make


def _lightglue(tier: Tier, weights_dir: Path | None) -> Matcher:
    """LightGlue (or LighterGlue) for the tier's features: the name's first part (``disk``-lightglue)."""
    from synthleak.localize import deep

    return deep.LightGlueMatcher(tier.name.split("-")[0], weights_dir, tier.match_threshold)


register_tier(Tier("orb", ratio=0.75, mutual=True, pnp_max_error_px=12.0, min_inliers=20), _opencv,
              description="OpenCV ORB (binary) / Hamming NN")
register_tier(Tier("akaze", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15), _opencv,
              description="OpenCV AKAZE (binary; absent from OpenCV 5 main) / Hamming NN")
register_tier(Tier("sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15), _sift,
              description="COLMAP SIFT (pycolmap) / L2 NN")
register_tier(Tier("kornia-sift", ratio=0.8, mutual=True, pnp_max_error_px=12.0, min_inliers=15, needs_torch=True),
              _kornia_sift, _kornia_matcher, description="kornia SIFTFeature / kornia DescriptorMatcher smnn")
register_tier(Tier("xfeat", ratio=0.9, mutual=True, pnp_max_error_px=12.0, min_inliers=30, needs_torch=True,
                   max_keypoints=4096, weights=("xfeat",)), _learned("XFeatExtractor"),
              description="XFeat (learned, 64-D) / L2 NN")
register_tier(Tier("xfeat-lighterglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30,
                   needs_torch=True, max_keypoints=1024, learned_matcher=True,
                   weights=("xfeat", "xfeat-lighterglue"), match_threshold=0.3),
              _learned("XFeatExtractor"), _lightglue, description="XFeat / LighterGlue (learned matcher)")
register_tier(Tier("disk-lightglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30,
                   needs_torch=True, max_keypoints=1024, learned_matcher=True, weights=("disk", "disk-lightglue"),
                   match_threshold=0.3),
              _learned("DiskExtractor"), _lightglue, description="DISK / LightGlue (learned matcher)")
register_tier(Tier("aliked-lightglue", ratio=0.0, mutual=False, pnp_max_error_px=12.0, min_inliers=30,
                   needs_torch=True, max_keypoints=1024, learned_matcher=True,
                   weights=("aliked-n16", "aliked-lightglue"), match_threshold=0.3),
              _learned("AlikedExtractor"), _lightglue, description="ALIKED-N16 / LightGlue (learned matcher)")


# ---------------------------------------------------------------------------------------------- profiles
PROFILE_FIELDS = ("ratio", "mutual", "min_inliers", "pnp_max_error_px", "match_threshold", "ratio_both_ways")
"""The :class:`Tier` fields a server profile may set: matching and PnP only. A tier's extractor and keypoint
budget are the same under every profile, so query features are too (the study's features stage shares them)."""

DEFAULT_PROFILE = "strict"

_HLOC_LOCALIZE = {"pnp_max_error_px": 12.0, "min_inliers": 3}
"""hloc/localize_sfm.py:137,154 (``ransac_thresh=12`` -> ``estimation.ransac.max_error``); localized: pycolmap's
``estimate_and_refine_absolute_pose`` returns a pose (hloc/localize_sfm.py:63-70,203-204), which COLMAP's
LO-RANSAC does once its best model has at least ``P3PEstimator::kMinNumSamples`` = 3 inliers
(colmap src/colmap/optim/loransac.h:368-372, src/colmap/estimators/solvers/absolute_pose.h:65)."""
_HLOC_NN_RATIO = {"ratio": 0.8, "mutual": True, "ratio_both_ways": True}
"""hloc/match_features.py:69-76 ``NN-ratio``: mutual check, ratio 0.8 (hloc/matchers/nearest_neighbor.py:11: on
squared distances against ratio**2, the same test as ours on distances), applied from both images' side before
the mutual check (nearest_neighbor.py:51-58)."""
_HLOC_NN_MUTUAL = {"ratio": 0.0, "mutual": True}
"""hloc/match_features.py:77-83 ``NN-mutual``: mutual check only (no ratio, no distance threshold:
hloc/matchers/nearest_neighbor.py:28-32)."""
_HLOC_LIGHTGLUE = {"match_threshold": 0.1}
"""hloc/match_features.py:31-44 ``disk+lightglue`` / ``aliked+lightglue`` set no ``filter_threshold``
(hloc/matchers/lightglue.py:7-12), so LightGlue's default: 0.1 (cvg/LightGlue lightglue/lightglue.py:333; XFeat's
LighterGlue: 0.1 too, verlab/accelerated_features modules/lighterglue.py:25)."""

PROFILES: dict[str, dict[str, dict[str, Any]]] = {
    "strict": {},
    "hloc": {
        "orb": {**_HLOC_NN_MUTUAL, **_HLOC_LOCALIZE},
        "akaze": {**_HLOC_NN_MUTUAL, **_HLOC_LOCALIZE},
        "sift": {**_HLOC_NN_RATIO, **_HLOC_LOCALIZE},
        "kornia-sift": {**_HLOC_NN_RATIO, **_HLOC_LOCALIZE},
        "xfeat": {**_HLOC_NN_MUTUAL, **_HLOC_LOCALIZE},
        "xfeat-lighterglue": {**_HLOC_LIGHTGLUE, **_HLOC_LOCALIZE},
        "disk-lightglue": {**_HLOC_LIGHTGLUE, **_HLOC_LOCALIZE},
        "aliked-lightglue": {**_HLOC_LIGHTGLUE, **_HLOC_LOCALIZE},
    },
}
"""Server profiles: per tier, the :data:`PROFILE_FIELDS` that replace the tier's own (``[localize] profile``).

``strict`` (the default) is the registered tiers as they are. ``hloc`` is HLoc's defaults for the closest HLoc
configuration (cvg/Hierarchical-Localization at c13273b; every tier keeps its features and keypoint budget):

================== ============================== ===== ====== ========== =========== ======
tier               HLoc configuration             ratio mutual LightGlue  min inliers PnP px
================== ============================== ===== ====== ========== =========== ======
orb, akaze         ``NN-mutual`` (Hamming)        none  yes    --         3           12
sift, kornia-sift  ``NN-ratio`` (ratio both ways) 0.8   yes    --         3           12
xfeat              ``NN-mutual``                  none  yes    --         3           12
xfeat-lighterglue  LightGlue default (LighterGlue) --    --     > 0.1      3           12
disk-lightglue     ``disk+lightglue``             --    --     > 0.1      3           12
aliked-lightglue   ``aliked+lightglue``           --    --     > 0.1      3           12
================== ============================== ===== ====== ========== =========== ======

Sources: matchers hloc/match_features.py:24-83 and hloc/matchers/nearest_neighbor.py:27-32; LightGlue's
``filter_threshold`` cvg/LightGlue lightglue/lightglue.py:333 (hloc/matchers/lightglue.py:7-12 leaves it);
PnP hloc/localize_sfm.py:137,154 (no pipeline of hloc/pipelines/ changes it); min inliers: no threshold in
hloc/localize_sfm.py, a pose is pycolmap's success, 3 inliers (COLMAP loransac.h:368). HLoc has no XFeat: its
``NN-mutual`` is what HLoc pairs with learned descriptors that have no dedicated matcher (R2D2, D2-Net; the paper's
R2D2 + NN) and what XFeat's own matcher does (mutual NN, ``min_cossim=-1``: verlab/accelerated_features
modules/xfeat.py:166,328-342). Nor binary features: ORB and AKAZE get ``NN-mutual`` on Hamming distances.

A profile is a plain table: a plugin tier gets values under a profile with ``PROFILES["hloc"]["name"] = {...}``."""


def profile_names() -> list[str]:
    """The server profiles, ``strict`` first."""
    return list(PROFILES)


def profile_fixes(tier: Tier | str, profile: str | list[str] = DEFAULT_PROFILE) -> frozenset[str]:
    """The :data:`PROFILE_FIELDS` server ``profile`` sets for ``tier``: these the profile fixes, and a config's
    ``[localize] pnp_max_error_px`` / ``min_inliers`` override only the others (``hloc`` keeps HLoc's 12 px on
    any image size; the override tunes ``strict`` servers). A list of profiles (a study's): none fixed."""
    if not isinstance(profile, str) or profile == DEFAULT_PROFILE:
        return frozenset()
    name = tier if isinstance(tier, str) else tier.name
    return frozenset(PROFILES.get(profile, {}).get(name, {}))


def profile_tier(tier: Tier | str, profile: str = DEFAULT_PROFILE) -> Tier:
    """The tier (a :class:`Tier` or a registered name) as server ``profile`` defines it: ``strict``, the tier
    itself; another profile, the tier with that profile's :data:`PROFILE_FIELDS` for it. Raises ``ValueError``
    for an unknown profile, or one that has no values for the tier."""
    spec = get_tier(tier) if isinstance(tier, str) else tier
    try:
        table = PROFILES[profile]
    except KeyError:
        raise ValueError(f"unknown server profile {profile!r} (known: {', '.join(PROFILES)})") from None
    if profile == DEFAULT_PROFILE:
        return spec
    if spec.name not in table:
        raise ValueError(f"server profile {profile!r} has no values for tier {spec.name!r} "
                         f"(it has: {', '.join(table)})")
    overrides = table[spec.name]
    unknown = sorted(set(overrides) - set(PROFILE_FIELDS))
    if unknown:
        raise ValueError(f"server profile {profile!r}, tier {spec.name!r}: {', '.join(unknown)} cannot be set by a "
                         f"profile (only {', '.join(PROFILE_FIELDS)})")
    return replace(spec, **overrides)
