"""The query defense online: a study with ``[defense] enabled`` runs every query through the server's policy,
in process and over HTTP, and its decisions are exactly the offline sweep's for the same X, k and queries.

Reference: the `ci-tiny` study fixture (undefended, in process), whose logged inlier counts the offline sweep
replays (:func:`synthleak.evaluate.defense_sweep.passes_defense`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import shutil
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import load_config
from synthleak.evaluate.defense_sweep import defense_tradeoff, passes_defense
from synthleak.localize.defense import DefensePolicy
from synthleak.study import QueriesStage, StudyContext, StudyPaths, defense_queries, read_query_log, run_study

X, K = 0.1, 3
"""The policy under test (on ci-tiny it refuses some queries of each kind and accepts others)."""


def _defended_config():
    config = load_config("ci-tiny")
    return dataclasses.replace(config, defense=dataclasses.replace(
        config.defense, enabled=True, min_fraction=X, min_instances=K))


def _log_paths(study: Path) -> dict[tuple[str, str], Path]:
    return {("sift", log.parent.name): log for log in sorted((study / "queries" / "sift").glob("*/queries.jsonl"))}


def _logs(study: Path) -> dict[str, list[dict]]:
    return {room: read_query_log(log) for (_, room), log in _log_paths(study).items()}


def _offline(record: dict) -> bool:
    """The offline sweep's answer for an undefended record: localized and passing the rule."""
    return bool(record["success"]) and passes_defense(record["inlier_instance_counts"], X, K)


@pytest.fixture(scope="module")
def defended_study(ci_tiny_study: Path, tmp_path_factory) -> Path:
    """The fixture re-run with the defense on: renders, maps and features cached, queries re-run."""
    out = tmp_path_factory.mktemp("defended") / "study"
    shutil.copytree(ci_tiny_study, out)
    run_study(_defended_config(), out, progress=False)
    return out


def test_in_process_decisions_equal_the_offline_sweep(ci_tiny_study, defended_study):
    plain, defended = _logs(ci_tiny_study), _logs(defended_study)
    assert plain.keys() == defended.keys() and plain
    accepted = refused = 0
    for room, records in plain.items():
        assert [q["frame"] for q in records] == [q["frame"] for q in defended[room]]
        for before, after in zip(records, defended[room], strict=True):
            assert after["inlier_instance_counts"] == before["inlier_instance_counts"]
            assert after["success"] == _offline(before), (room, before["frame"])
            if not before["success"]:
                assert after["defense_accepted"] is None and "withheld_cam_from_world" not in after
                continue
            assert after["defense_accepted"] == _offline(before)
            kept = after["cam_from_world"] if after["success"] else after["withheld_cam_from_world"]
            assert np.array_equal(np.array(kept), np.array(before["cam_from_world"]))
            accepted += after["success"]
            refused += not after["success"]
    assert accepted and refused, (accepted, refused)  # the policy decides both ways on these queries
    # the offline sweep over the defended study's logs sees the same queries localized as without the defense
    grid = {"min_fractions": [0.05, X, 0.3], "min_instances": [2, K]}
    assert (defense_tradeoff(defense_queries(_log_paths(defended_study)), **grid)
            == defense_tradeoff(defense_queries(_log_paths(ci_tiny_study)), **grid))


def test_the_undefended_attack_is_rebuilt_from_the_defended_logs(ci_tiny_study, defended_study):
    """Attacking the defended logs' answers before the defense equals the undefended study's attack, and the
    defended attack localizes fewer queries; the report holds the comparison and the refused shares."""
    before = json.loads((ci_tiny_study / "results" / "results.json").read_text())
    rebuilt = json.loads((defended_study / "results" / "results_no_defense.json").read_text())
    served = json.loads((defended_study / "results" / "results.json").read_text())
    fields = ("room", "object", "aligner", "delta_r_deg", "eps", "decision", "n_localized", "scene_from_object_est")
    assert [[r[f] for f in fields] for r in rebuilt] == [[r[f] for f in fields] for r in before]
    assert sum(r["n_localized"] for r in served) < sum(r["n_localized"] for r in before)
    online = json.loads((defended_study / "results" / "defense_online.json").read_text())
    assert online["check"]["n_decisions"] > 0 and online["check"]["n_differ"] == 0
    assert online["check"]["n_served_differ"] == 0
    pooled = next(r for r in online["refused"] if r["tier"] == "all")
    plain = [q for records in _logs(ci_tiny_study).values() for q in records if q["success"]]
    genuine = [q for q in plain if q["genuine"]]
    assert pooled["n_genuine"] == len(genuine)
    assert math.isclose(pooled["genuine_refused"], sum(not _offline(q) for q in genuine) / len(genuine))
    report = (defended_study / "report.md").read_text()
    assert f"## The defense online (X = {X:g}, k = {K})" in report
    assert f"{pooled['n_genuine'] + pooled['n_attacker']}/{pooled['n_genuine'] + pooled['n_attacker']}" in report


class _Server:
    """``synthleak serve``'s app and localizer pool on a free loopback port, in a thread."""

    def __init__(self, app) -> None:
        import uvicorn

        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            self.port = sock.getsockname()[1]
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="warning"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> str:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert self.server.started
        return f"http://127.0.0.1:{self.port}"

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)


def test_http_server_decisions_equal_the_offline_sweep(ci_tiny_study, tmp_path):
    """The study's ``--server URL`` path against a server whose pool runs the policy: every answer is the
    offline sweep's decision on the same query, and the accepted poses are the undefended ones."""
    from synthleak.localize.pool import LocalizerPool
    from synthleak.localize.server import create_app

    config = dataclasses.replace(_defended_config(), attack=dataclasses.replace(
        load_config("ci-tiny").attack, queries_per_object=4))
    room = "room_000"
    map_dir = ci_tiny_study / "maps" / "sift" / room
    study = tmp_path / "study"  # the fixture's renders and maps, this test's queries
    study.mkdir()
    for folder in ("dataset", "maps"):
        (study / folder).symlink_to(ci_tiny_study / folder)
    with LocalizerPool(map_dir, 1, config.localize, DefensePolicy(X, K, enabled=True)) as pool, \
            _Server(create_app(pool)) as url:
        ctx = StudyContext(config, StudyPaths(study), progress=False, server_url=url)
        stage = QueriesStage()
        logs = stage.make(ctx, [unit for unit in stage.units(ctx) if unit.item == ("sift", room)])
    served = read_query_log(logs[("sift", room)])
    plain = {(q["sequence"], q["frame"]): q for q in _logs(ci_tiny_study)[room]}
    assert len(served) >= 16
    outcomes = []
    for q in served:
        before = plain[(q["sequence"], q["frame"])]
        assert q["success"] == _offline(before), q["frame"]
        assert "defense_accepted" not in q  # an HTTP answer carries no decision
        if q["success"]:
            np.testing.assert_allclose(q["cam_from_world"], before["cam_from_world"], atol=1e-9)
        if before["success"]:
            outcomes.append(q["success"])
    assert any(outcomes) and not all(outcomes), outcomes
