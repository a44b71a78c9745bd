"""A study's servers: tiers x ``[localize] profile`` (x ``representation``), on the same query features."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import pytest

from synthleak.cache import done_key
from synthleak.config import ConfigError, LocalizeConfig, config_to_dict, load_config
from synthleak.localize.servers import Server, base_tier, server_by_name, study_servers
from synthleak.study import run_study


def test_server_names_leave_the_defaults_out():
    assert Server("sift").name == "sift"
    assert Server("xfeat", "hloc").name == "xfeat@hloc"
    assert Server("sift", representation="line-cloud").name == "sift+line-cloud"
    assert Server("xfeat", "hloc", "line-cloud").name == "xfeat@hloc+line-cloud"
    for name in ("xfeat@hloc+line-cloud", "xfeat+line-cloud", "xfeat@hloc", "xfeat"):
        assert base_tier(name) == "xfeat"


def test_study_servers_span_tiers_then_profiles():
    localize = LocalizeConfig(tiers=["sift", "xfeat"], profile=["strict", "hloc"])
    assert [s.name for s in study_servers(localize)] == ["sift", "sift@hloc", "xfeat", "xfeat@hloc"]
    one = server_by_name(localize)["xfeat@hloc"].localize(localize)
    assert one.profile == "hloc" and one.tiers == ["sift", "xfeat"]
    # a single server's config has the content key it had before profiles could be a list
    strict = server_by_name(localize)["sift"].localize(localize)
    assert "profile" not in config_to_dict(strict)
    assert [s.name for s in study_servers(LocalizeConfig(tiers=["orb"], profile="hloc"))] == ["orb@hloc"]


@pytest.mark.parametrize(("value", "message"), [
    ('["strict", "strict"]', r"localize\.profile: values must be distinct"),
    ("[]", r"localize\.profile: must not be empty"),
    ('["strict", "colmap"]', r"localize\.profile\[1\]: unknown name 'colmap'"),
    ("1", r"localize\.profile: expected str or list\[str\], got 1"),
])
def test_a_bad_profile_list_names_the_file_and_key(tmp_path: Path, value: str, message: str):
    path = tmp_path / "bad.toml"
    path.write_text(f'extends = "ci-tiny"\n[localize]\nprofile = {value}\n')
    with pytest.raises(ConfigError, match=rf"bad\.toml: {message}"):
        load_config(path)


def test_servers_keeps_the_named_servers_of_the_span():
    localize = LocalizeConfig(tiers=["sift", "orb", "xfeat"], profile=["strict", "hloc"],
                              servers=["xfeat@hloc", "sift", "orb", "xfeat", "sift@hloc"])
    assert [s.name for s in study_servers(localize)] == ["sift", "sift@hloc", "orb", "xfeat", "xfeat@hloc"]
    assert "orb@hloc" not in server_by_name(localize)
    assert "servers" not in config_to_dict(LocalizeConfig())  # the default leaves content keys as they were


@pytest.mark.parametrize(("value", "message"), [
    ('["orb@hloc"]', r"localize\.servers: 'orb@hloc' is not a server of tiers x profile x representation "
                     r"\(known: sift, sift@hloc, xfeat, xfeat@hloc\)"),
    ('["sift", "sift"]', r"localize\.servers: a server is named twice"),
])
def test_a_bad_server_list_names_the_file_and_key(tmp_path: Path, value: str, message: str):
    path = tmp_path / "bad.toml"
    path.write_text(f'extends = "ci-tiny"\n[localize]\ntiers = ["sift", "xfeat"]\nprofile = ["strict", "hloc"]\n'
                    f"servers = {value}\n")
    with pytest.raises(ConfigError, match=rf"bad\.toml: {message}"):
        load_config(path)


def test_a_study_runs_both_profiles_on_the_same_features(ci_tiny_study: Path, tmp_path: Path):
    """Adding ``hloc`` beside ``strict`` builds the ``sift@hloc`` maps and logs and redoes nothing of ``sift``:
    its maps, features, logs and results rows stay the same bytes, and one features folder serves both."""
    out = tmp_path / "study"
    shutil.copytree(ci_tiny_study, out)
    base = load_config("ci-tiny")
    config = dataclasses.replace(base, localize=dataclasses.replace(base.localize, profile=["strict", "hloc"]))
    rooms = sorted(p.name for p in (out / "maps" / "sift").iterdir() if p.is_dir())
    keys = {room: done_key(out / "maps" / "sift" / room) for room in rooms}
    run_study(config, out, progress=False)

    assert sorted(p.name for p in (out / "features").iterdir()) == ["sift"]
    assert sorted(p.name for p in (out / "queries").iterdir()) == ["sift", "sift@hloc"]
    for room in rooms:
        assert done_key(out / "maps" / "sift" / room) == keys[room]
        assert (out / "queries" / "sift" / room / "queries.jsonl").read_bytes() == \
            (ci_tiny_study / "queries" / "sift" / room / "queries.jsonl").read_bytes()
        meta = json.loads((out / "maps" / "sift@hloc" / room / "map.json").read_text())
        assert meta["settings"]["profile"] == "hloc"
        lines = (out / "queries" / "sift@hloc" / room / "queries.jsonl").read_text().splitlines()
        assert lines and all(json.loads(line)["tier"] == "sift@hloc" for line in lines)

    rows = json.loads((out / "results" / "results.json").read_text())
    before = json.loads((ci_tiny_study / "results" / "results.json").read_text())
    assert {r["tier"] for r in rows} == {"sift", "sift@hloc"}
    assert [r for r in rows if r["tier"] == "sift"] == before
    report = (out / "report.md").read_text()
    assert "servers sift, sift@hloc" in report
    assert "`sift@hloc` (" in report  # the tier ordering lists the hloc server beside the strict one


def test_servers_of_one_tier_answer_together_with_the_bytes_of_each_alone(ci_tiny_study: Path, tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch):
    """In process, a tier's servers of one profile (points and line cloud) answer each chunk of queries in one task,
    each pair of a query and a map image scored once for both (:mod:`synthleak.localize.shared_matching`); their
    logs are the bytes each server logs alone."""
    from synthleak.study import queries as queries_stage

    out = tmp_path / "study"
    shutil.copytree(ci_tiny_study, out)
    base = load_config("ci-tiny")
    config = dataclasses.replace(base, localize=dataclasses.replace(base.localize,
                                                                    representation=["points", "line-cloud"]))
    run_study(config, out, progress=False)  # sift's logs are the fixture's; sift+line-cloud's are made alone
    alone = {p.relative_to(out): p.read_bytes() for p in sorted(out.glob("queries/*/*/queries.jsonl"))}
    assert len({p.parts[1] for p in alone}) == 2
    together: list[bool] = []
    real = queries_stage.shared_pair_matches

    def recording(localizers, query, candidates, shared=True):
        together.append(shared and len(localizers) == 2)
        return real(localizers, query, candidates, shared)

    monkeypatch.setattr(queries_stage, "shared_pair_matches", recording)
    run_study(config, out, force=["queries"], progress=False)
    assert together and all(together)  # every query answered by both servers, sharing the pairs' scores
    assert {p.relative_to(out): p.read_bytes() for p in sorted(out.glob("queries/*/*/queries.jsonl"))} == alone


def test_a_study_attacks_a_line_cloud_beside_the_point_map(ci_tiny_study: Path, tmp_path: Path):
    """``representation = ["points", "line-cloud"]``: a ``sift+line-cloud`` server per room whose map holds no
    ``points.npz``, its own query logs and results rows; the point server's stay the same bytes."""
    out = tmp_path / "study"
    shutil.copytree(ci_tiny_study, out)
    base = load_config("ci-tiny")
    config = dataclasses.replace(base, localize=dataclasses.replace(base.localize,
                                                                    representation=["points", "line-cloud"]))
    run_study(config, out, progress=False)
    assert sorted(p.name for p in (out / "queries").iterdir()) == ["sift", "sift+line-cloud"]
    for room in sorted(p.name for p in (out / "maps" / "sift+line-cloud").iterdir() if p.is_dir()):
        line_map = out / "maps" / "sift+line-cloud" / room
        assert (line_map / "lines.npz").is_file() and not (line_map / "points.npz").exists()
        assert (out / "queries" / "sift" / room / "queries.jsonl").read_bytes() == \
            (ci_tiny_study / "queries" / "sift" / room / "queries.jsonl").read_bytes()
    rows = json.loads((out / "results" / "results.json").read_text())
    lines = [r for r in rows if r["tier"] == "sift+line-cloud"]
    assert lines and [r for r in rows if r["tier"] == "sift"] == \
        json.loads((ci_tiny_study / "results" / "results.json").read_text())
    genuine = json.loads((out / "results" / "genuine_localization.json").read_text())
    assert {g["tier"] for g in genuine} >= {"sift", "sift+line-cloud"}


def test_the_report_puts_utility_beside_leakage_per_server(ci_tiny_study: Path):
    servers = json.loads((ci_tiny_study / "results" / "servers.json").read_text())
    genuine = json.loads((ci_tiny_study / "results" / "genuine_localization.json").read_text())
    rows = json.loads((ci_tiny_study / "results" / "results.json").read_text())
    assert [s["server"] for s in servers] == ["sift"]
    (row,) = servers
    assert row["genuine_localized"] == round(sum(g["localized"] for g in genuine) / sum(g["n"] for g in genuine), 3)
    alg1 = [r for r in rows if r["aligner"] == "alg1" and (r["delta_r_deg"], r["delta_t_m"]) == (10.0, 0.25)]
    present = [r for r in alg1 if r["present_gt"]]
    assert row["attacker_localized_present"] == round(sum(r["n_localized"] for r in present)
                                                      / sum(r["n_queries"] for r in present), 3)
    placed = [r for r in present if r["decision"] and r["rot_err_deg"] <= 10.0 and r["trans_err_m"] <= 0.25]
    assert row["placed_alg1"] == round(len(placed) / len(present), 3)
    assert row["placed_best"] >= row["placed_alg1"]
    assert (ci_tiny_study / "plots" / "utility_vs_leakage.png").stat().st_size > 10_000
    assert "## Utility and leakage per server" in (ci_tiny_study / "report.md").read_text()


def test_the_servers_selection_is_not_part_of_a_servers_keys(ci_tiny_study: Path, tmp_path: Path):
    """Naming the servers to run (``[localize] servers``) redoes nothing of the servers it keeps: their maps and
    query logs keep their keys and bytes (the selection entered every map key before, so a narrowed list redid
    every query)."""
    out = tmp_path / "study"
    shutil.copytree(ci_tiny_study, out)
    base = load_config("ci-tiny")
    config = dataclasses.replace(base, localize=dataclasses.replace(base.localize, profile=["strict", "hloc"],
                                                                    servers=["sift"]))
    rooms = sorted(p.name for p in (out / "maps" / "sift").iterdir() if p.is_dir())
    keys = {room: (done_key(out / "maps" / "sift" / room), done_key(out / "queries" / "sift" / room))
            for room in rooms}
    run_study(config, out, progress=False)
    assert not (out / "maps" / "sift@hloc").exists()
    for room in rooms:
        assert (done_key(out / "maps" / "sift" / room), done_key(out / "queries" / "sift" / room)) == keys[room]
