"""Stage caching of `synthleak study`: a rerun does no work, a threshold change re-runs only the attack, a new
tier builds only its own maps and never re-renders. Work is counted by wrapping the functions that do it."""

from __future__ import annotations

import dataclasses
import json
import shutil
from collections import Counter
from pathlib import Path

import pytest

from synthleak.config import StudyConfig, load_config
from synthleak.study import run_study


@pytest.fixture()
def counted(monkeypatch: pytest.MonkeyPatch) -> Counter:
    """Counts renderer creations, frames rendered, maps built, query images whose features were extracted and
    queries localized (serial runs), by wrapping the functions a study calls (``localize_features`` for
    in-process queries: ``test_new_tier_builds_only_its_maps`` checks the counts are not zero by construction)."""
    import synthleak.localize.localizer as localizer
    import synthleak.localize.mapping as mapping
    import synthleak.render.pipeline as pipeline
    import synthleak.study.features as features

    calls: Counter = Counter()

    def counting(name, fn):
        def wrapper(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapper

    monkeypatch.setattr(pipeline, "get_renderer", counting("renderer", pipeline.get_renderer))
    monkeypatch.setattr(pipeline, "render_frame_task", counting("frame_tasks", pipeline.render_frame_task))
    monkeypatch.setattr(pipeline, "write_frame", counting("frames", pipeline.write_frame))
    monkeypatch.setattr(mapping, "_write_map", counting("maps", mapping._write_map))  # one per map built
    monkeypatch.setattr(localizer.Localizer, "localize", counting("queries", localizer.Localizer.localize))
    monkeypatch.setattr(localizer.Localizer, "localize_features",
                        counting("queries", localizer.Localizer.localize_features))
    monkeypatch.setattr(features, "save_features", counting("features", features.save_features))
    return calls


def _copy(ci_tiny_study: Path, tmp_path: Path) -> Path:
    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study, study)
    return study


def _markers(study: Path) -> dict[str, str]:
    return {str(p.relative_to(study)): p.read_text() for p in sorted(study.rglob(".done.json"))}


def test_rerun_is_a_cache_hit(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    study = _copy(ci_tiny_study, tmp_path)
    before = _markers(study)
    report = (study / "report.md").read_bytes()
    run_study(load_config("ci-tiny"), study, progress=False)
    assert dict(counted) == {}
    assert _markers(study) == before
    assert (study / "report.md").read_bytes() == report  # the report is cached too (its wall times: the first run's)
    run_study(load_config("ci-tiny"), study, force=["report"], progress=False)
    assert dict(counted) == {}
    assert (study / "report.md").read_bytes() != report  # remade: this run's wall times (cached stages ~0 s)
    results = "results/results.json"
    assert (study / results).read_bytes() == (ci_tiny_study / results).read_bytes()


def test_threshold_change_reuses_every_cached_stage(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    study = _copy(ci_tiny_study, tmp_path)
    config = load_config("ci-tiny")
    thresholds = [(15.0, 0.3), (45.0, 1.0)]
    changed = dataclasses.replace(config, attack=dataclasses.replace(config.attack, thresholds=thresholds))
    before = _markers(study)
    run_study(changed, study, progress=False)
    assert dict(counted) == {}  # no renderer, frame, map or query
    after = _markers(study)
    assert {k for k in after if after[k] != before.get(k)} == {"results/.done.json", "plots/.done.json"}
    rows = json.loads((study / "results" / "results.json").read_text())
    rows = rows["rows"] if isinstance(rows, dict) else rows
    assert {(r["delta_r_deg"], r["delta_t_m"]) for r in rows} == set(thresholds)


def test_an_acceptance_change_replays_pose_estimation_only(ci_tiny_study: Path, tmp_path: Path, counted: Counter,
                                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """A map's key holds what builds it: min inliers and the PnP threshold are the queries' settings, and a change
    of them replays pose estimation on each server's kept correspondences (nothing is retrieved or matched), with
    the logs a run that matches from scratch writes."""
    from synthleak.study import queries as queries_stage
    from synthleak.study import read_query_log

    study = _copy(ci_tiny_study, tmp_path)
    assert list(study.glob("queries/*/*/.matches-*/*.npz"))  # the correspondences were kept
    config = load_config("ci-tiny")
    changed = dataclasses.replace(config, localize=dataclasses.replace(config.localize, min_inliers=40,
                                                                       pnp_max_error_px=6.0))
    matched = Counter()
    real = queries_stage.shared_pair_matches
    monkeypatch.setattr(queries_stage, "shared_pair_matches",
                        lambda *args: matched.update(calls=1) or real(*args))
    before = _markers(study)
    run_study(changed, study, progress=False)
    assert counted["maps"] == counted["renderer"] == counted["frames"] == counted["features"] == 0
    sent = sum(len(read_query_log(p)) for p in sorted(study.glob("queries/*/*/queries.jsonl")))
    assert counted["queries"] == sent > 0 and matched["calls"] == 0  # pose estimation only
    after = _markers(study)
    assert all(after[k] == v for k, v in before.items() if k.startswith(("dataset", "maps", "features")))
    assert any(after[k] != v for k, v in before.items() if k.startswith("queries"))
    replayed = {p: p.read_bytes() for p in sorted(study.glob("queries/*/*/queries.jsonl"))}
    assert replayed != {p: (ci_tiny_study / p.relative_to(study)).read_bytes() for p in replayed}  # fewer poses
    run_study(changed, study, force=["queries"], progress=False)  # from scratch: matched again
    assert matched["calls"] > 0
    assert {p: p.read_bytes() for p in sorted(study.glob("queries/*/*/queries.jsonl"))} == replayed


def test_new_tier_builds_only_its_maps(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    study = _copy(ci_tiny_study, tmp_path)
    config: StudyConfig = load_config("ci-tiny")
    changed = dataclasses.replace(config, localize=dataclasses.replace(config.localize, tiers=["sift", "orb"]))
    before = _markers(study)
    run_study(changed, study, progress=False)
    assert counted["renderer"] == counted["frames"] == 0
    assert counted["maps"] == 2  # orb maps of the two rooms; the sift maps are reused
    from synthleak.study import read_query_log

    orb = sum(len(read_query_log(p)) for p in sorted((study / "queries" / "orb").glob("*/queries.jsonl")))
    sift = sum(len(read_query_log(p)) for p in sorted((study / "queries" / "sift").glob("*/queries.jsonl")))
    assert counted["queries"] == orb == sift > 0  # only orb's queries ran (each image against both rooms)
    assert 0 < counted["features"] < orb  # orb features of each query image, once for both rooms
    after = _markers(study)
    assert all(after[k] == v for k, v in before.items() if k.startswith(("dataset", "maps/sift", "queries/sift")))


def test_force_render_redoes_only_missing_frames(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    study = _copy(ci_tiny_study, tmp_path)
    victim = sorted(study.glob("dataset/scenes/*/images/*.png"))[3]
    victim_bytes = victim.read_bytes()
    victim.unlink()
    run_study(load_config("ci-tiny"), study, force=["render"], progress=False)
    assert counted["frames"] == 1 and counted["renderer"] == 1
    assert counted["maps"] == counted["queries"] == 0  # the renders' key did not change
    assert victim.read_bytes() == victim_bytes


def test_force_maps_redoes_what_reads_the_maps(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    """Maps rebuilt by ``--force maps`` (after a code change: other bytes, same key) are queried again, and the
    attack and the report are made again from those queries; renders and query features are not redone."""
    study = _copy(ci_tiny_study, tmp_path)
    results = study / "results" / "results.json"
    results_made = results.stat().st_mtime_ns
    run_study(load_config("ci-tiny"), study, force=["maps"], progress=False)
    from synthleak.study import read_query_log

    sent = sum(len(read_query_log(p)) for p in sorted(study.glob("queries/*/*/queries.jsonl")))
    assert counted["maps"] == 2 and counted["queries"] == sent > 0
    assert counted["renderer"] == counted["frames"] == counted["features"] == 0
    assert results.stat().st_mtime_ns != results_made  # the attack ran again
    assert results.read_bytes() == (ci_tiny_study / "results" / "results.json").read_bytes()  # same code: same bytes


def test_forced_stages_reach_every_reader() -> None:
    from synthleak.study import forced_stages

    assert forced_stages(["maps"]) == {"maps", "queries", "attack", "report"}
    assert forced_stages(["sfm", "features"]) == {"sfm", "features", "queries", "attack", "report"}
    assert forced_stages(["render"]) == {"render"}  # it only renders missing frames: nothing after it changes
    assert forced_stages(["sweep"]) == {"sweep", "report"}


def test_unknown_force_stage(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown stage.*'frames'.*attack, sweep, world-sweep, report"):
        run_study(load_config("ci-tiny"), tmp_path, force=["frames"], progress=False)
    assert not (tmp_path / "dataset").exists()


@pytest.mark.slow
def test_force_sweep_redoes_only_the_sweep(ci_tiny_study: Path, tmp_path: Path, counted: Counter) -> None:
    """A variant-magnitude sweep runs the attacker-side stages on its point (the study's rooms, renders and maps
    reused); ``--force sweep`` redoes the point's stages (its frames exist: none re-rendered) and nothing of the
    study's; a rerun does nothing."""
    study = _copy(ci_tiny_study, tmp_path)
    base = load_config("ci-tiny")
    config = dataclasses.replace(base, sweep=dataclasses.replace(base.sweep, kinds=["colour"], magnitudes=[0.6]))
    n_objects = len(json.loads((study / "dataset" / "stages" / "index.json").read_text())["attacker_objects"])
    run_study(config, study, progress=False)
    assert counted["frames"] == n_objects * base.render.attacker_frames and counted["maps"] == 0
    point = study / "sweep" / "colour-0.6"
    assert sorted(p.name for p in point.iterdir()) == ["dataset", "features", "queries"]
    assert not (point / "dataset" / "scenes").exists()  # attackers only: the rooms are the study's
    rows = (study / "results" / "sweep.json").read_bytes()
    assert {(r["kind"], r["magnitude"]) for r in json.loads(rows)} == {("colour", 0.6)}
    study_markers = {k: v for k, v in _markers(study).items() if not k.startswith("sweep/")}
    counted.clear()
    run_study(config, study, force=["sweep"], progress=False)
    from synthleak.study import read_query_log

    sent = sum(len(read_query_log(p)) for p in sorted((point / "queries").glob("*/*/queries.jsonl")))
    assert counted["frames"] == counted["maps"] == 0
    assert counted["queries"] == sent > 0 and counted["features"] > 0
    assert {k: v for k, v in _markers(study).items() if not k.startswith("sweep/")} == study_markers
    assert (study / "results" / "sweep.json").read_bytes() == rows
    counted.clear()
    run_study(config, study, progress=False)
    assert dict(counted) == {}


def test_newer_code_formats_redo_the_renders(ci_tiny_study: Path, tmp_path: Path, counted: Counter,
                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """The render key names the code's stage, attacker-setting and (photographed studies) capture formats: a
    folder rendered by older code is rendered again, not reused as if current (kept aside as ``dataset.<key>``)."""
    import synthleak.scene.attacker_settings as settings
    from synthleak.study.render import code_formats

    assert [set(f) for f in code_formats(load_config("ci-tiny"))] == [{"stage_format", "settings_format"}]
    assert {"capture_format"} in [set(f) for f in code_formats(load_config("ci-tiny-photo"))]
    study = _copy(ci_tiny_study, tmp_path)
    monkeypatch.setattr(settings, "SETTINGS_FORMAT", settings.SETTINGS_FORMAT + 1)
    run_study(load_config("ci-tiny"), study, progress=False)
    assert counted["frames"] > 0  # rendered again
    assert list(study.glob("dataset.*"))  # the older renders kept aside


def test_a_query_log_redone_with_other_bytes_reruns_the_attack(ci_tiny_study: Path, tmp_path: Path) -> None:
    """``--force queries`` after a code change can give other bytes under the same content key: the attack and the
    report are made again from them, never left from the old logs."""
    study = _copy(ci_tiny_study, tmp_path)
    results = study / "results" / "results.json"
    log = next(p for p in sorted(study.glob("queries/*/*/queries.jsonl"))
               if any(json.loads(line)["success"] and json.loads(line)["attacker_object"]
                      for line in p.read_text().splitlines()))
    records = [json.loads(line) for line in log.read_text().splitlines()]
    for record in records:  # as a changed server would answer: the attacker's poses 2 m away
        if record["success"] and record["attacker_object"]:
            record["cam_from_world"][0][3] += 2.0
    log.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
    run_study(load_config("ci-tiny"), study, progress=False)
    assert results.read_bytes() != (ci_tiny_study / "results" / "results.json").read_bytes()
    made = results.stat().st_mtime_ns, results.read_bytes()
    run_study(load_config("ci-tiny"), study, progress=False)  # and again: a cache hit on the new bytes
    assert (results.stat().st_mtime_ns, results.read_bytes()) == made
