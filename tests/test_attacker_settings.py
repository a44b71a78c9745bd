"""Varied attacker settings (scene.attacker_settings) and the shell-inlier share (evaluate.shell_share)."""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from synthleak.config import load_config
from synthleak.evaluate.query_log import read_query_log
from synthleak.evaluate.shell_share import (
    count_shell_top,
    mostly_on_shell,
    shell_fraction,
    shell_share,
    shell_share_from_logs,
)
from synthleak.scene.attacker_settings import (
    OWN_KINDS,
    SETTING_KINDS,
    draw_setting,
    setting_texture,
)
from synthleak.scene.styles import SURFACES, room_styles


def _shell_textures(spec) -> dict[str, str]:
    """sha256 of every shell piece's texture bytes, by piece name."""
    return {o.name: hashlib.sha256(np.ascontiguousarray(p.texture).tobytes()).hexdigest()
            for o in spec.objects if o.role == "shell" for p in o.mesh.parts}


@pytest.fixture(scope="module")
def ci_tiny_specs():
    """The ci-tiny plan's rooms and attacker setups, composed in memory."""
    from synthleak.assets.library import load_library
    from synthleak.scene.attacker_env import compose_attacker
    from synthleak.scene.compose import compose_room
    from synthleak.scene.plan import plan_study

    config = load_config("ci-tiny")
    library = load_library()
    plan = plan_study(config, library)
    rooms = [compose_room(r, library) for r in plan.rooms]
    attackers = [compose_attacker(a, library, plan.seed) for a in plan.attackers]
    return config, plan, rooms, attackers


def test_settings_vary_across_objects_and_walls(ci_tiny_specs):
    _, plan, _, attackers = ci_tiny_specs
    kinds = {spec.metadata["style"] for spec in attackers}
    assert len(kinds) >= 2, kinds
    assert all(spec.metadata["style"] in {k.name for k in SETTING_KINDS} for spec in attackers)
    floors = [_shell_textures(spec)["floor"] for spec in attackers]
    assert len(set(floors)) == len(floors)  # a setting per object, not one hall per study
    for spec in attackers:  # every wall its own draw: groups of orbit views see different backgrounds
        walls = [h for name, h in _shell_textures(spec).items() if name.startswith("wall_")]
        assert len(walls) == 4 and len(set(walls)) == 4
    # over many objects every kind of setting is drawn
    drawn = {draw_setting(plan.seed, f"a{i:02d}_x", np.array([1.0, 1.0, 1.0]), texture_size=64).kind.name
             for i in range(40)}
    assert drawn == {k.name for k in SETTING_KINDS}


def test_orbit_stays_inside_the_setting(ci_tiny_specs):
    """The setting is large enough that the farthest orbit camera (bounding-sphere distance x 1.1) is inside."""
    config, _, _, attackers = ci_tiny_specs
    rc = config.render
    vfov = 2 * np.arctan(np.tan(np.radians(rc.hfov_deg) / 2) * rc.height / rc.width)
    for spec in attackers:
        target = next(o for o in spec.objects if o.instance_id == spec.target_instance_id)
        reach = 1.1 * 0.5 * np.linalg.norm(target.object_extents()) / np.sin(0.5 * min(np.radians(rc.hfov_deg), vfov))
        assert reach < 0.5 * min(spec.room_size[:2]), (spec.name, reach, spec.room_size)


def _room_pairs() -> list[tuple[str, tuple[float, float, float]]]:
    """Every (texture kind, colour) a room shell surface can be drawn with."""
    return [(kind, colour) for style in room_styles() for s in SURFACES
            for kind, colour in itertools.product(style.finishes[s].kinds, style.finishes[s].colours)]


def test_settings_draw_only_their_own_texture_generators():
    """No setting surface comes from a generator the rooms use (shells or furniture): a shared generator in
    another colour still gives the same grey-level features (SETTINGS_FORMAT 1 did, and chance matches of its
    floors to room walls were most of the shell-localized attacker queries' inliers)."""
    from synthleak.assets.textures import TEXTURE_KINDS

    assert not set(OWN_KINDS) & set(TEXTURE_KINDS)
    assert not set(OWN_KINDS) & {k for k, _ in _room_pairs()}
    for setting in SETTING_KINDS:
        for surface, finish in setting.finishes.items():
            assert set(finish.kinds) <= set(OWN_KINDS), (setting.name, surface, finish.kinds)
    with pytest.raises(ValueError, match="'concrete' is not a setting's own"):
        setting_texture("concrete", (0.5, 0.5, 0.5), np.random.default_rng(0), 64)


def test_no_attacker_surface_equals_a_room_shell_texture(ci_tiny_specs):
    _, _, rooms, attackers = ci_tiny_specs
    room_shell = {h for spec in rooms for h in _shell_textures(spec).values()}
    room = _room_pairs()
    for spec in attackers:
        assert not set(_shell_textures(spec).values()) & room_shell, spec.name  # no shell SKU is shared
        for surface, (kind, colour) in spec.metadata["setting"].items():
            assert (kind, tuple(colour)) not in room, (spec.name, surface)


def test_same_seed_same_stage_bytes(ci_tiny_specs, tmp_path):
    from synthleak.assets.library import load_library
    from synthleak.scene.attacker_env import compose_attacker
    from synthleak.scene.usd_write import stage_to_string

    _, plan, _, attackers = ci_tiny_specs
    first = stage_to_string(attackers[0], tmp_path / "a")
    again = stage_to_string(compose_attacker(plan.attackers[0], load_library(), plan.seed), tmp_path / "b")
    assert first == again
    for png in sorted((tmp_path / "a" / "textures").iterdir()):
        assert png.read_bytes() == (tmp_path / "b" / "textures" / png.name).read_bytes()
    other = compose_attacker(plan.attackers[0], load_library(), plan.seed + 1)
    assert _shell_textures(other)["floor"] != _shell_textures(attackers[0])["floor"]


# ------------------------------------------------------------------------------------------- the shell share
def test_shell_share_of_hand_made_log_lines():
    line = ('{"attacker_object": "a00_chair", "genuine": false, "room": "room_000", "tier": "sift", '
            '"frame": "000001.png", "success": true, "num_inliers": 50, '
            '"inlier_instance_counts": {"0": 4, "1": 20, "4": 6, "100": 20}}')
    q = json.loads(line)
    assert shell_fraction(q["inlier_instance_counts"]) == pytest.approx(26 / 50)
    assert mostly_on_shell(q["inlier_instance_counts"])
    assert not mostly_on_shell({"3": 25, "101": 25})  # exactly half is not most
    assert math.isnan(shell_fraction({})) and not mostly_on_shell({})
    failed = {**q, "frame": "000002.png", "success": False}
    on_object = {**q, "frame": "000003.png", "room": "room_001", "inlier_instance_counts": {"2": 5, "300": 30}}
    genuine = {**q, "genuine": True, "attacker_object": None}
    index = {"attacker_objects": [{"id": "a00_chair", "present_in": {"room_000": 100}}]}
    [row] = shell_share_from_logs([q, failed, on_object, genuine], index)
    assert (row["n_localized_present"], row["n_shell_top_present"]) == (1, 1)
    assert (row["n_localized_absent"], row["n_shell_top_absent"]) == (1, 0)
    assert row["shell_share_all"] == 0.5
    assert count_shell_top([q, failed, on_object]) == 1
    with pytest.raises(ValueError, match="inlier_instance_counts.*count"):
        mostly_on_shell({"1": -3})
    with pytest.raises(ValueError, match="attacker_object"):
        shell_share_from_logs([{**q, "attacker_object": "zz"}], index)


def test_shell_share_of_a_ci_tiny_study(ci_tiny_study: Path):
    index = json.loads((ci_tiny_study / "dataset" / "stages" / "index.json").read_text())
    logs = sorted((ci_tiny_study / "queries").glob("*/*/queries.jsonl"))
    records = [q for log in logs for q in read_query_log(log)]
    from_logs = shell_share_from_logs(records, index)
    rows = json.loads((ci_tiny_study / "results" / "results.json").read_text())
    assert shell_share(rows) == from_logs  # the results' pair field agrees with the logs (oracle local poses)
    present_in = {o["id"]: o["present_in"] for o in index["attacker_objects"]}
    for row in from_logs:  # and with a count done here from the raw inlier labels
        for part in ("present", "absent"):
            chosen = [q for q in records if q["tier"] == row["tier"] and not q["genuine"] and q["success"]
                      and (q["room"] in present_in[q["attacker_object"]]) == (part == "present")]
            on_shell = [q for q in chosen if 2 * sum(v for k, v in q["inlier_instance_counts"].items()
                                                     if 0 < int(k) < 100) > q["num_inliers"]]
            assert (row[f"n_localized_{part}"], row[f"n_shell_top_{part}"]) == (len(chosen), len(on_shell))
    assert from_logs and from_logs[0]["n_localized_all"] > 0
    assert "localized on the room's shell" in (ci_tiny_study / "report.md").read_text()
    assert {o.get("setting") for o in index["attacker_objects"]} <= {k.name for k in SETTING_KINDS}


def test_shell_inliers_benchmark_relocalizes_as_logged(ci_tiny_study: Path):
    """``benchmarks/shell_inliers.py`` localizes every localized attacker query again (it raises if one does
    not give the logged inliers) and splits the query-side inliers: the counts add up to the logs' inliers."""
    import importlib.util
    from collections import Counter

    from synthleak.study import StudyPaths

    path = Path(__file__).parents[1] / "benchmarks" / "shell_inliers.py"
    spec = importlib.util.spec_from_file_location("shell_inliers", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    config = load_config("ci-tiny")
    pairs: Counter = Counter()
    split = module.server_split(StudyPaths(ci_tiny_study), config, "sift", pairs)
    records = [q for log in sorted((ci_tiny_study / "queries" / "sift").glob("*/queries.jsonl"))
               for q in read_query_log(log) if not q["genuine"] and q["success"]]
    shell = [q for q in records if mostly_on_shell(q["inlier_instance_counts"])]
    assert int(split.get("n_shell", 0)) == len(shell) and int(split.get("n_objects", 0)) == len(records) - len(shell)
    assert int(split["shell"].sum()) == sum(q["num_inliers"] for q in shell) == sum(pairs.values())
    assert int(split["objects"].sum()) == sum(q["num_inliers"] for q in records if q not in shell)
    assert records and split["objects"][0] > 0  # look-alike localizations: inliers on the photographed object
