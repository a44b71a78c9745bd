"""The scripts of examples/ run (each in its own interpreter) on ci-tiny data and print what they should: the
numbers a script prints are checked against ground truth and against the session study's own results."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from synthleak.core.dataset import load_sequence
from synthleak.geometry.poses import camera_centre, rotation_error_deg

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
NUMBER = r"([-+0-9.eE]+|nan)"


def run_example(script: str, *args: object, cwd: Path) -> str:
    """The stdout of ``examples/<script> args`` (run in ``cwd``), which must exit 0."""
    proc = subprocess.run([sys.executable, str(EXAMPLES / script), *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=1200)
    assert proc.returncode == 0, f"{script} exited {proc.returncode}\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def numbers(pattern: str, text: str) -> list[float]:
    """The numbers of the first match of ``pattern`` (``{}`` marks each number) in ``text``."""
    match = re.search(pattern.replace("{}", NUMBER), text)
    assert match, f"no line matching {pattern!r} in:\n{text}"
    return [float(g) for g in match.groups()]


def results_row(study: Path, room: str, obj: str, delta_r: float = 10.0, delta_t: float = 0.25) -> dict:
    rows = json.loads((study / "results" / "results.json").read_text())
    return next(r for r in rows if (r["room"], r["object"], r["tier"], r["aligner"], r["delta_r_deg"],
                                    r["delta_t_m"]) == (room, obj, "sift", "alg1", delta_r, delta_t))


def check_read_back(out: str, dataset: Path, room: str) -> None:
    """Example 1's output: the frame counts of the room, BOP = COLMAP = objects.json, depth on the GT mesh."""
    seq = load_sequence(dataset / "scenes" / room)
    assert f"{room}: {len(seq.frames)} frames ({len(seq.map_frames)} map, {len(seq.query_frames)} query)" in out
    assert numbers(r"BOP cam_from_world - COLMAP cam_from_world: max \|diff\| {}", out)[0] < 1e-6
    assert numbers(r"BOP scene_from_object - objects.json world_from_object: max \|diff\| {}", out)[0] < 1e-6
    median_mm, p90_mm = numbers(r"vs GT mesh: median {} mm, 90th percentile {} mm", out)
    assert median_mm < 0.5 and p90_mm < 5.0


def test_01_reads_a_dataset(ci_tiny_study: Path, tmp_path: Path) -> None:
    dataset = ci_tiny_study / "dataset"
    out = run_example("01_generate_and_read.py", "--dataset", dataset, "--room", "room_001", "--frame", 5,
                      cwd=tmp_path)
    check_read_back(out, dataset, "room_001")
    assert "000005.png cam_from_world" in out
    assert not list(tmp_path.iterdir())  # --dataset only reads


@pytest.mark.slow
def test_01_generates_the_preset_as_the_study_does(ci_tiny_study: Path, tmp_path: Path) -> None:
    out = run_example("01_generate_and_read.py", "--out", tmp_path / "ex", cwd=tmp_path)
    dataset = tmp_path / "ex" / "dataset"
    check_read_back(out, dataset, "room_000")
    manifest = json.loads((dataset / "manifest.json").read_text())
    study_manifest = json.loads((ci_tiny_study / "dataset" / "manifest.json").read_text())
    assert manifest["files"] == study_manifest["files"]  # the same bytes as the study's renders


def test_02_localizes_a_genuine_query(ci_tiny_study: Path, tmp_path: Path) -> None:
    room, frame = "room_000", "000009.png"
    out = run_example("02_map_and_localize.py", "--dataset", ci_tiny_study / "dataset", "--out", tmp_path,
                      "--room", room, "--query", frame, cwd=tmp_path)
    assert (tmp_path / "maps" / "sift" / room / "map.json").is_file()
    rot_err, trans_err = numbers(r"error: rotation {} deg, translation {} m", out)
    assert rot_err < 2.0 and trans_err < 0.1
    # the map built here answers as the study's server did
    logged = next(q for q in map(json.loads, (ci_tiny_study / "queries" / "sift" / room / "queries.jsonl")
                                 .read_text().splitlines()) if q["genuine"] and q["frame"] == frame)
    est = np.array(logged["cam_from_world"])
    gt = load_sequence(ci_tiny_study / "dataset" / "scenes" / room).cam_from_world[frame]
    assert rot_err == pytest.approx(rotation_error_deg(est, gt), abs=1e-4)
    assert trans_err == pytest.approx(float(np.linalg.norm(camera_centre(est) - camera_centre(gt))), abs=1e-4)
    assert f"{logged['num_inliers']} inliers" in out


def check_attack(out: str, row: dict) -> None:
    """Example 3's eps and placement errors are the study's results row."""
    eps, inliers, sent = numbers(r"eps = {} \({} inliers of {} sent\)", out)
    assert eps == pytest.approx(row["eps"], abs=1e-4) and sent == row["n_queries"]
    assert inliers == round(row["eps"] * row["n_queries"])
    assert numbers(r": {} of {} images localized", out) == [row["n_localized"], row["n_queries"]]
    if row["present_gt"]:
        rot, trans, iou = numbers(r"placement error: rotation {} deg, translation {} m, IoU {}", out)
        assert rot == pytest.approx(row["rot_err_deg"], abs=1e-4)
        assert trans == pytest.approx(row["trans_err_m"], abs=1e-4)
        assert iou == pytest.approx(row["iou3d"], abs=1e-4)
    else:
        assert "is not in" in out


def test_03_attacks_from_the_study_query_logs(ci_tiny_study: Path, tmp_path: Path) -> None:
    index = json.loads((ci_tiny_study / "dataset" / "stages" / "index.json").read_text())
    present = next(o for o in index["attacker_objects"] if "room_000" in o["present_in"])
    out = run_example("03_attack_one_object.py", "--study", ci_tiny_study, cwd=tmp_path)  # room_000, first present
    assert out.startswith(f"{present['id']} against sift/room_000")
    row = results_row(ci_tiny_study, "room_000", present["id"])
    assert row["present_gt"] and row["n_localized"] > 0
    check_attack(out, row)
    absent = next(o for o in index["attacker_objects"] if "room_001" not in o["present_in"])
    out = run_example("03_attack_one_object.py", "--study", ci_tiny_study, "--room", "room_001", "--object",
                      absent["id"], "--delta-r", 30, "--delta-t", 0.5, cwd=tmp_path)
    check_attack(out, results_row(ci_tiny_study, "room_001", absent["id"], 30.0, 0.5))


def test_03_attacks_through_a_live_server(ci_tiny_study: Path, tmp_path: Path) -> None:
    out = run_example("03_attack_one_object.py", "--dataset", ci_tiny_study / "dataset", "--out", tmp_path,
                      cwd=tmp_path)
    obj = out.split()[0]
    check_attack(out, results_row(ci_tiny_study, "room_000", obj))


def test_04_sweeps_the_defense_and_plots_it(ci_tiny_study: Path, tmp_path: Path) -> None:
    from PIL import Image

    study = tmp_path / "study"  # the default path (OUT/study) on a copy: run_study resumes, nothing to redo
    shutil.copytree(ci_tiny_study, study)
    out = run_example("04_sweep_and_plot.py", "--out", tmp_path, "--min-instances", 2, 3, cwd=tmp_path)
    png = tmp_path / "defense_sweep.png"
    with Image.open(png) as image:
        image.verify()
    with Image.open(png) as image:
        assert image.format == "PNG" and min(image.size) > 100
    printed = {(int(k), x): (kept, rejected) for k, x, kept, rejected in
               (map(float, m) for m in re.findall(r"^ *(\d+) +([0-9.]+) +([0-9.]+) +([0-9.]+)$", out, re.M))}
    assert len(printed) == 2 * 10
    reference = [r for r in json.loads((study / "results" / "defense_tradeoff.json").read_text())
                 if r["tier"] == "all" and r["min_instances"] in (2, 3)]
    assert reference
    for r in reference:
        kept, rejected = printed[(r["min_instances"], r["min_fraction"])]
        assert kept == pytest.approx(r["genuine_kept"], abs=1e-3)
        assert rejected == pytest.approx(r["attacker_rejected"], abs=1e-3)
