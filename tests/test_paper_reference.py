"""The paper's Table 1 as transcribed, and the tier ordering the report prints beside it."""

from synthleak.evaluate.paper_reference import paper_means, tier_ordering, tier_ordering_markdown


def _mean(tier: str, dr: float) -> dict:
    return next(m for m in paper_means() if m["tier"] == tier and m["delta_r_deg"] == dr)


def test_paper_means_match_the_published_table():
    # The figures the issue and the paper's text quote: SIFT+NN R ~ 0.34 / P ~ 0.2, SP+SG R ~ 0.58 / P ~ 0.4.
    assert _mean("SIFT+NN", 10.0) == {"tier": "SIFT+NN", "delta_r_deg": 10.0, "delta_t_m": 0.25,
                                      "precision": 0.21, "recall": 0.34}
    assert _mean("SuperPoint+SuperGlue", 10.0)["recall"] == 0.58
    assert _mean("R2D2+NN", 10.0)["recall"] == 0.54
    assert _mean("R2D2+NN", 60.0)["recall"] == 0.64


def _row(tier, room, obj, present, decision, n_loc, dr=10.0, dt=0.25, aligner="alg1"):
    return {"tier": tier, "aligner": aligner, "room": room, "object": obj, "present_gt": present,
            "decision": decision, "n_localized": n_loc, "n_queries": 4, "delta_r_deg": dr, "delta_t_m": dt}


def test_tier_ordering_counts_decisions_and_queries():
    rows = [
        _row("sift", "r0", "a", True, True, 3), _row("sift", "r0", "b", True, False, 0),
        _row("sift", "r0", "c", False, False, 1),
        _row("xfeat", "r0", "a", True, True, 4), _row("xfeat", "r0", "b", True, True, 2),
        _row("xfeat", "r0", "c", False, True, 2),
        _row("xfeat", "r0", "a", True, False, 4, aligner="robust"),  # another aligner: not counted
    ]
    by_tier = {r["tier"]: r for r in tier_ordering(rows)}
    assert by_tier["sift"]["R 10°, 0.25m"] == 0.5 and by_tier["sift"]["P 10°, 0.25m"] == 1.0
    assert by_tier["xfeat"]["R 10°, 0.25m"] == 1.0 and by_tier["xfeat"]["P 10°, 0.25m"] == 0.67
    assert by_tier["sift"]["queries_present"] == "3/8" and by_tier["xfeat"]["queries_absent"] == "2/4"
    assert by_tier["xfeat"]["paper_analogue"] == "R2D2+NN"
    text = tier_ordering_markdown(rows)
    assert "`xfeat` (1.00) > `sift` (0.50)" in text and "higher recall than `sift` here: `xfeat`" in text


def test_the_tier_ordering_names_the_presence_rule_of_the_decision_column() -> None:
    rows = [_row("sift", "r0", "a", True, True, 4)]
    assert "ε rule, pooled over rooms" in tier_ordering_markdown(rows)
    assert "presence classifier, pooled over rooms" in tier_ordering_markdown(rows, presence="classifier")


def test_equal_recalls_are_written_as_a_tie() -> None:
    rows = [_row("sift", "r0", "a", True, True, 3), _row("sift", "r0", "b", True, False, 0),
            _row("xfeat", "r0", "a", True, True, 3), _row("xfeat", "r0", "b", True, False, 0),
            _row("orb", "r0", "a", True, False, 3), _row("orb", "r0", "b", True, False, 0)]
    text = tier_ordering_markdown(rows)
    assert "`sift` (0.50) = `xfeat` (0.50) > `orb` (0.00)" in text
    assert "No learned tier has a higher recall than `sift`" in text
