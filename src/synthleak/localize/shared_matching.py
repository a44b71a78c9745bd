"""Servers of one tier answering the same query: each (query, map image) pair is scored once for all of them.

A tier's servers differ in their matching rule (the ``strict`` and ``hloc`` profiles' ratio and mutual checks)
and in their maps' points (each profile triangulates its own), not in the map images' features: the maps of a
tier and room are built from the same extraction (:func:`synthleak.localize.mapping.build_maps`). So the
descriptor scores of a query against the union of the keypoints the servers' maps give a point are computed
once, and each server filters the columns of its own mapped keypoints with its own rule: the same matches as
its own :meth:`~synthleak.localize.localizer.Localizer.pair_matches`, bit for bit (each score is its own dot
product, whatever the other columns). Servers whose matcher is not nearest neighbours match on their own.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from synthleak.core.types import Camera
from synthleak.localize.features import Features
from synthleak.localize.localizer import Localizer
from synthleak.localize.matching import PairScores, pair_scores
from synthleak.localize.tiers import uses_nn_matcher


def can_share(localizers: list[Localizer]) -> bool:
    """True when ``localizers`` are nearest-neighbour servers of one tier over maps of the same images and
    features (a study's servers of one tier and room)."""
    if len(localizers) < 2:
        return False
    first = localizers[0]
    for loc in localizers:
        if loc.tier.name != first.tier.name or not uses_nn_matcher(loc.tier) or loc.data.names != first.data.names:
            return False
    return all(np.array_equal(a.keypoints, b.keypoints) and np.array_equal(a.descriptors, b.descriptors)
               for loc in localizers[1:] for a, b in zip(first.data.features, loc.data.features, strict=True))


def shared_pair_matches(localizers: list[Localizer], query: Features, candidates: list[np.ndarray],
                        shared: bool = True) -> list[list[np.ndarray]]:
    """Per localizer, the pair matches of its ``candidates`` (each its :meth:`Localizer.pair_matches`); with
    ``shared`` (a :func:`can_share` group), each map image's scores against the query computed once."""
    if not shared:
        return [loc.pair_matches(query, c) for loc, c in zip(localizers, candidates, strict=True)]
    features = localizers[0].data.features
    columns: dict[int, list[np.ndarray]] = {}
    for loc, cands in zip(localizers, candidates, strict=True):
        for i in cands.tolist():
            columns.setdefault(i, []).append(loc.mapped_keypoints(i))
    scored: dict[int, tuple[np.ndarray, PairScores]] = {}
    for i, keeps in columns.items():
        union = keeps[0] if len(keeps) == 1 else np.unique(np.concatenate(keeps))
        scored[i] = (union, pair_scores(query, features[i].subset(union)))
    out = []
    for loc, cands in zip(localizers, candidates, strict=True):
        rule = (loc.tier.ratio, loc.tier.mutual)
        matches = []
        for i in cands.tolist():
            union, scores = scored[i]
            keep = loc.mapped_keypoints(i)
            if scores.scores is not None and len(keep) != len(union):
                scores = PairScores(scores.scores[:, np.searchsorted(union, keep)] if len(keep) else None,
                                    scores.to_distance, scores.squared)
            matches.append(scores.matches(*rule, both_ways=loc.tier.ratio_both_ways))
        out.append(matches)
    return out


def with_image_size(query: Features, camera: Camera) -> Features:
    """``query`` with the camera's image size where its features carry none (as ``localize_features`` does)."""
    return replace(query, image_size=(camera.width, camera.height)) if query.image_size == (0, 0) else query
