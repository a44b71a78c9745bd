"""Servers of one tier answering the same query: a (query, map image) pair is scored once for all of them where
their maps give the same keypoints of that image a point.

A tier's servers differ in their matching rule (the ``strict`` and ``hloc`` profiles' ratio and mutual checks)
and in their maps' points (each profile triangulates its own), not in the map images' features: the maps of a
tier and room are built from the same extraction (:func:`synthleak.localize.mapping.build_maps`). Where the
servers' maps give the same keypoints of an image a point (the representations of one profile: points and line
clouds), the descriptor scores of the pair are computed once and each server filters them with its own rule: the
same matches as its own :meth:`~synthleak.localize.localizer.Localizer.pair_matches`, bit for bit. Elsewhere each
server scores its own keypoints (gathering a union's columns cost more than the product it saved). Servers whose
matcher is not nearest neighbours match on their own.
"""

from __future__ import annotations

import numpy as np

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
    ``shared`` (a :func:`can_share` group), a map image whose mapped keypoints are the same in every server's map
    (the representations of one profile) is scored once for all of them. Images whose keypoint sets differ (the
    strict and hloc profiles' maps) are scored per server: copying a union's columns costs more than the product
    it saves."""
    if not shared:
        return [loc.pair_matches(query, c) for loc, c in zip(localizers, candidates, strict=True)]
    features = localizers[0].data.features
    columns: dict[int, list[np.ndarray]] = {}
    for loc, cands in zip(localizers, candidates, strict=True):
        for i in cands.tolist():
            columns.setdefault(i, []).append(loc.mapped_keypoints(i))
    scored: dict[int, PairScores] = {i: pair_scores(query, features[i].subset(keeps[0])) for i, keeps in
                                     columns.items()
                                     if len(keeps) > 1 and all(np.array_equal(keeps[0], k) for k in keeps[1:])}
    out = []
    for loc, cands in zip(localizers, candidates, strict=True):
        rule = (loc.tier.ratio, loc.tier.mutual)
        out.append([scored[i].matches(*rule, both_ways=loc.tier.ratio_both_ways) if i in scored
                    else loc.pair_matches(query, np.array([i]))[0] for i in cands.tolist()])
    return out
