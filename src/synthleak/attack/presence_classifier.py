"""A presence classifier beyond the paper's ε rule, trained leave-one-scene-out exactly like ε⁺/ε⁻.

Per (room, object) trial it sees only what the attacker has (:data:`ATTACKER_FIELDS` of the results rows:
the returned poses or failures through the attack's alignments, and its own local model): ε at each threshold
pair, ε at the trial's own pair, the share of queries the server localized, the trial features of
:mod:`synthleak.attack.presence_features` (support of the second-best hypothesis, the inliers' residual
spread, how far the placements at the other threshold pairs lie from this one), and the ε rule's own evidence
as a signed margin against the object's ε⁺/ε⁻ (:func:`~synthleak.attack.presence.presence_margin`; for a
training row, medians over the rooms that are neither its own nor the held-out one). :func:`attacker_view` drops
every other column before any feature is computed, so ground truth cannot leak in.

Each room is decided by a model trained on the other rooms' trials of the same attack configuration (tier,
aligner, thresholds, variant), pooled over objects (the ε rule keeps per-object medians; two or three
training rooms are too few to fit a model per object): scikit-learn's logistic regression on standardised
features, balanced class weights (present pairs are the minority). Where the training rooms hold a single
class the ε rule's decision is kept (``clf_fallback``).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from typing import Any

import numpy as np

from synthleak.attack.presence import presence_margin
from synthleak.attack.presence_features import TRIAL_FEATURES

KEY_FIELDS = ("room", "object", "tier", "aligner", "delta_r_deg", "delta_t_m", "magnitude", "kind")
"""What identifies a trial."""

ATTACKER_FIELDS = ("eps", "n_queries", "n_localized", *TRIAL_FEATURES)
"""The attacker-side columns of a results row the classifier may read."""

GROUP_FIELDS = ("tier", "aligner", "delta_r_deg", "delta_t_m", "magnitude", "kind")
"""One leave-one-scene-out experiment per value of these (like ``CONFIG_KEYS`` of the tables)."""


def attacker_view(row: dict[str, Any]) -> dict[str, Any]:
    """The trial's key and its attacker-side fields only."""
    return {k: row.get(k) for k in (*KEY_FIELDS, *ATTACKER_FIELDS)}


def feature_names(thresholds: Sequence[tuple[float, float]]) -> list[str]:
    """Feature order of :func:`trial_matrix` for these threshold pairs (the classifier appends the ε rule's
    margin, computed per held-out room)."""
    return [*(f"eps@{r:g}/{t:g}" for r, t in thresholds), "eps", "localized_share", "second_eps",
            "rot_spread", "trans_spread", "disagree_rot", "log1p_disagree_trans"]


def _trial(view: dict[str, Any]) -> tuple:
    """One (room, object, tier, aligner, variant): its rows differ only in the threshold pair."""
    return (view["room"], view["object"], view["tier"], view["aligner"], view["magnitude"], view["kind"])


def trial_matrix(rows: Sequence[dict[str, Any]]) -> tuple[np.ndarray, list[str]]:
    """One feature vector per row (same order), computed from :func:`attacker_view` of the rows only."""
    views = [attacker_view(r) for r in rows]
    thresholds = sorted({(v["delta_r_deg"], v["delta_t_m"]) for v in views})
    eps: dict[tuple, dict[tuple[float, float], float]] = defaultdict(dict)
    for v in views:
        eps[_trial(v)][(v["delta_r_deg"], v["delta_t_m"])] = float(v["eps"])
    out = np.zeros((len(views), len(feature_names(thresholds))))
    for n, v in enumerate(views):
        n_queries = int(v["n_queries"] or 0)
        out[n] = [*(eps[_trial(v)].get(th, 0.0) for th in thresholds), float(v["eps"]),
                  (v["n_localized"] or 0) / n_queries if n_queries else 0.0, float(v["second_eps"]),
                  float(v["rot_spread"]), float(v["trans_spread"]), float(v["disagree_rot_deg"]) / 180.0,
                  math.log1p(float(v["disagree_trans_m"]))]
    return out, feature_names(thresholds)


def _model():
    from sklearn.linear_model import LogisticRegression
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    return make_pipeline(StandardScaler(), LogisticRegression(C=1.0, class_weight="balanced", max_iter=1000))


def _margins(rows: Sequence[dict[str, Any]], members: list[int], eps: np.ndarray, labels: np.ndarray,
             held_out: str) -> np.ndarray:
    """The ε rule's signed margin of every member row, with ε⁺/ε⁻ the medians of the same object's ε over
    rooms other than the row's own and the held-out room (for a held-out row: exactly the ε rule's statistics;
    the held-out room's labels are never read)."""
    out = np.zeros(len(rows))
    by_object: dict[str, list[int]] = defaultdict(list)
    for n in members:
        by_object[rows[n]["object"]].append(n)
    for n in members:
        others = [m for m in by_object[rows[n]["object"]] if rows[m]["room"] not in (rows[n]["room"], held_out)]
        plus = [eps[m] for m in others if labels[m]]
        minus = [eps[m] for m in others if not labels[m]]
        out[n] = presence_margin(eps[n], float(np.median(plus)) if plus else None,
                                 float(np.median(minus)) if minus else None)
    return out


def classifier_decisions(rows: Sequence[dict[str, Any]], fallback: Sequence[bool]) -> list[dict[str, Any]]:
    """Per row (same order): ``clf_score`` (held-out probability of presence, None on a fallback),
    ``decision_clf`` and ``clf_fallback``; each room decided by a model trained on the other rooms of its
    attack configuration. ``fallback``: the ε rule's decisions, kept where the training rooms hold one class.

    The labels (``present_gt``) of the training rooms are the only ground truth read."""
    features, _ = trial_matrix(rows)
    labels = np.array([bool(r["present_gt"]) for r in rows])
    eps = np.array([float(r["eps"]) for r in rows])
    out: list[dict[str, Any]] = [{} for _ in rows]
    groups: dict[tuple, list[int]] = defaultdict(list)
    for n, r in enumerate(rows):
        groups[tuple(r.get(k) for k in GROUP_FIELDS)].append(n)
    for members in groups.values():
        for room in sorted({rows[n]["room"] for n in members}):
            test = [n for n in members if rows[n]["room"] == room]
            train = [n for n in members if rows[n]["room"] != room]
            if len(set(labels[train].tolist())) < 2:
                for n in test:
                    out[n] = {"clf_score": None, "decision_clf": bool(fallback[n]), "clf_fallback": True}
                continue
            margin = _margins(rows, members, eps, labels, held_out=room)
            model = _model().fit(np.column_stack([features[train], margin[train]]), labels[train])
            scores = model.predict_proba(np.column_stack([features[test], margin[test]]))[:, 1]
            for n, score in zip(test, scores, strict=True):
                out[n] = {"clf_score": float(score), "decision_clf": bool(score > 0.5), "clf_fallback": False}
    return out


def has_features(rows: Sequence[dict[str, Any]]) -> bool:
    """True when every row carries the attacker-side trial features (older results files do not)."""
    return bool(rows) and all(r.get(k) is not None for r in rows for k in TRIAL_FEATURES)
