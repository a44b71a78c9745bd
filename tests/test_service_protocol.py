"""The external localization-service protocol (docs/service-protocol.md): ``synthleak export-maps``, the
``--server`` URL routing, the multi-map ``synthleak serve``, and a ci-tiny study against separate
``synthleak serve`` processes over real HTTP giving the in-process study's ``results/results.json`` bytes."""

from __future__ import annotations

import hashlib
import json
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import numpy as np
import pycolmap
import pytest

from synthleak.config import load_config
from synthleak.core.dataset import colmap_camera_model, load_sequence, read_index
from synthleak.evaluate.query_log import read_query_log
from synthleak.localize.client import server_urls
from synthleak.study import run_study
from synthleak.study.export import EXPORT_FORMAT, export_maps

CLI = [sys.executable, "-m", "synthleak.cli"]


def _rooms(study: Path) -> list[str]:
    return [room["name"] for room in read_index(study / "dataset" / "stages")["rooms"]]


# --- export-maps -------------------------------------------------------------------------------------------


def test_export_holds_the_map_frames_with_their_poses_and_nothing_of_the_attackers(ci_tiny_study, tmp_path):
    out = tmp_path / "export"
    manifest = json.loads(export_maps(ci_tiny_study, out).read_text())
    assert manifest["format"] == EXPORT_FORMAT and manifest["servers"] == ["sift"]
    rooms = _rooms(ci_tiny_study)
    assert [r["name"] for r in manifest["rooms"]] == rooms and [r["index"] for r in manifest["rooms"]] == [0, 1]
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*") if p.is_file())
    assert sorted(manifest["files"]) == [f for f in files if f != "manifest.json"]
    for name, digest in manifest["files"].items():
        assert hashlib.sha256((out / name).read_bytes()).hexdigest() == digest, name
    # nothing of the attacker's, no object label
    assert not any(part in {"attackers", "instance", "bop", "stages", "maps", "queries", "features", "sfm"}
                   for f in files for part in Path(f).parts), files
    assert not any(Path(f).name == "objects.json" for f in files)
    for room in rooms:
        seq = load_sequence(ci_tiny_study / "dataset" / "scenes" / room)
        folder = out / "rooms" / room
        held_out = set(seq.query_frames) | set(seq.split.get("closeup", []))
        assert held_out and not held_out & set(seq.map_frames)
        images = sorted(p.name for p in (folder / "images").iterdir())
        assert images == sorted(seq.map_frames) and not held_out & set(images)
        assert sorted(p.name for p in (folder / "depth").iterdir()) == sorted(
            seq.depth_path(f).name for f in seq.map_frames)
        for frame in seq.map_frames:
            assert (folder / "images" / frame).read_bytes() == seq.image_path(frame).read_bytes()
            assert (folder / "depth" / seq.depth_path(frame).name).read_bytes() == seq.depth_path(frame).read_bytes()
        assert json.loads((folder / "split.json").read_text()) == {"map": seq.map_frames}
        # the COLMAP model reads back with pycolmap, with the dataset's poses and cameras
        model = pycolmap.Reconstruction(str(folder / "colmap"))
        assert len(model.points3D) == 0
        by_name = {image.name: image for image in model.images.values()}
        assert sorted(by_name) == sorted(seq.map_frames)
        for frame, image in by_name.items():
            pose = image.cam_from_world
            pose = (pose() if callable(pose) else pose).matrix()
            np.testing.assert_allclose(pose, seq.cam_from_world[frame][:3], atol=1e-12)
            camera, expected = model.cameras[image.camera_id], seq.camera_of(frame)
            model_name, params = colmap_camera_model(expected)
            assert camera.model.name == model_name and (camera.width, camera.height) == (expected.width,
                                                                                         expected.height)
            np.testing.assert_allclose(camera.params, params, atol=1e-12)


def test_export_maps_cli_without_depth_and_refusing_a_foreign_folder(ci_tiny_study, tmp_path):
    out = tmp_path / "export"
    result = subprocess.run([*CLI, "export-maps", str(ci_tiny_study), "--out", str(out), "--no-depth"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert not list(out.rglob("depth")) and json.loads((out / "manifest.json").read_text())["depth"] is False
    assert len(list(out.glob("rooms/*/images/*.png"))) == sum(
        len(load_sequence(ci_tiny_study / "dataset" / "scenes" / r).map_frames) for r in _rooms(ci_tiny_study))
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match=r"foreign: exists and is not an export"):
        export_maps(ci_tiny_study, foreign)
    with pytest.raises(FileNotFoundError, match=r"index\.json: missing"):
        export_maps(tmp_path / "nothing", tmp_path / "out2")


# --- routing -------------------------------------------------------------------------------------------------


PAIRS = [("sift", "room_000"), ("sift", "room_001"), ("sift+line-cloud", "room_000"), ("sift+line-cloud", "room_001")]
ROOMS = ["room_000", "room_001"]


def test_server_urls_templates_maps_lists_and_plain_urls():
    assert server_urls("http://h:1/{server}/{room}/", PAIRS, ROOMS)[("sift+line-cloud", "room_001")] == \
        "http://h:1/sift+line-cloud/room_001"
    ports = server_urls("http://h:81{room_index:02d}", PAIRS[:2], ROOMS)
    assert ports == {PAIRS[0]: "http://h:8100", PAIRS[1]: "http://h:8101"}
    assert set(server_urls("http://h:9/", PAIRS, ROOMS).values()) == {"http://h:9"}  # the old behaviour
    listed = [{"server": s, "room": r, "path": f"/{s}/{r}"} for s, r in PAIRS[:3]] + \
             [{"server": "sift+line-cloud", "room": "room_001", "url": "http://other:5/"}]
    urls = server_urls("http://h:9", PAIRS, ROOMS, listed)
    assert urls[PAIRS[0]] == "http://h:9/sift/room_000" and urls[PAIRS[3]] == "http://other:5/"
    with pytest.raises(ValueError, match=r"sends sift/room_000 and sift\+line-cloud/room_000 to the same URL"):
        server_urls("http://h:1/{tier}/{room}", PAIRS, ROOMS)
    with pytest.raises(ValueError, match=r"bad URL template .*'port'.*placeholders: \{server\}"):
        server_urls("http://h:{port}/{room}", PAIRS, ROOMS)
    with pytest.raises(ValueError, match=r"/maps: the service has no map for sift\+line-cloud/room_001"):
        server_urls("http://h:9", PAIRS, ROOMS, listed[:3])


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.mark.parametrize("template", ["", "/{server}/{room}"])
def test_a_study_against_no_service_fails_before_it_renders(tmp_path, capsys, template):
    """A ``--server`` URL where nothing listens is one line naming it, before any render (it used to render and
    build maps for minutes, then end in an httpx traceback)."""
    from synthleak.cli import main

    url = f"http://127.0.0.1:{_closed_port()}{template}"
    assert main(["study", "ci-tiny", "--out", str(tmp_path / "study"), "--server", url, "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and url in err and "no service answers" in err
    assert not (tmp_path / "study" / "dataset").exists()


def test_a_service_gone_mid_study_is_named():
    from synthleak.errors import ServiceUnreachableError
    from synthleak.localize.client import HttpLocalizer

    url = f"http://127.0.0.1:{_closed_port()}/sift/room_000"
    with HttpLocalizer(url) as client, pytest.raises(ServiceUnreachableError, match=f"POST {url}/localize"):
        client.localize(np.zeros((8, 8, 3), np.uint8))


def test_multi_map_app_routes_lists_and_answers_labels_only_when_asked(ci_tiny_study):
    from fastapi.testclient import TestClient

    from synthleak.localize.localizer import Localizer
    from synthleak.localize.server import create_maps_app, find_maps

    maps = find_maps(ci_tiny_study / "maps")
    assert list(maps) == [("sift", room) for room in _rooms(ci_tiny_study)]
    client = TestClient(create_maps_app({("sift", "room_000"): Localizer.load(maps[("sift", "room_000")],
                                                                               load_config("ci-tiny").localize)}))
    assert client.get("/maps").json() == [{"server": "sift", "room": "room_000", "path": "/sift/room_000"}]
    assert client.get("/sift/room_000/health").json() == {"status": "ok"}
    assert client.get("/sift/room_001/health").status_code == 404
    seq = load_sequence(ci_tiny_study / "dataset" / "scenes" / "room_000")
    frame = seq.query_frames[0]
    body = seq.image_path(frame).read_bytes()
    plain = client.post("/sift/room_000/localize", content=body).json()
    assert plain["success"] and set(plain) == {"success", "cam_from_world"}  # the attacker's view: the pose only
    labelled = client.post("/sift/room_000/localize", content=body, params={"labels": "true"}).json()
    assert labelled["cam_from_world"] == plain["cam_from_world"] and labelled["num_inliers"] > 0
    assert sum(labelled["inlier_instance_counts"].values()) <= labelled["num_inliers"]
    assert labelled["retrieved"] and set(labelled["retrieved"]) <= set(seq.map_frames)
    bad = client.post("/sift/room_000/localize", content=body, params={"labels": "maybe"})
    assert bad.status_code == 422 and "labels='maybe'" in bad.json()["detail"]
    with pytest.raises(ValueError, match=r"neither a map \(no map\.json\) nor a folder of maps"):
        find_maps(ci_tiny_study / "dataset")


# --- real HTTP ----------------------------------------------------------------------------------------------


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _free_port_block(n: int) -> int:
    """A prefix P such that ports P*100 .. P*100 + n - 1 are free on loopback."""
    for prefix in range(420, 650):
        try:
            for i in range(n):
                with socket.socket() as sock:
                    sock.bind(("127.0.0.1", prefix * 100 + i))
        except OSError:
            continue
        return prefix
    raise RuntimeError("no free block of loopback ports")


class _Serve:
    """``synthleak serve ARGS`` in its own process on ``port`` (its output in ``log_path``)."""

    def __init__(self, port: int, log_path: Path, *args: str) -> None:
        self.port, self.url, self.log_path = port, f"http://127.0.0.1:{port}", log_path
        self.log: str | None = None
        with log_path.open("w") as log:
            self.process = subprocess.Popen([*CLI, "serve", *args, "--port", str(port), "--workers", "1"],
                                            stdout=log, stderr=subprocess.STDOUT, text=True)

    def wait(self) -> _Serve:
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            assert self.process.poll() is None, self.log_path.read_text()
            try:
                if httpx.get(f"{self.url}/health", timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                time.sleep(0.3)
        raise AssertionError(f"synthleak serve on {self.port} did not start")

    def stop(self) -> str:
        if self.log is None:
            self.process.terminate()
            self.process.wait(timeout=60)
            self.log = self.log_path.read_text()
        return self.log


def _rerun_queries(study: Path, config, url: str) -> bytes:
    (study / "results" / "results.json").unlink()
    run_study(config, study, server_url=url, force=("queries", "attack"), progress=False, workers=1)
    return (study / "results" / "results.json").read_bytes()


def _assert_logs_match(study: Path, reference: Path, servers: list[str]) -> None:
    """The HTTP answers are the in-process ones, server-side labels included (the poses to the quaternion's
    round trip)."""
    for server in servers:
        for room in _rooms(reference):
            remote = read_query_log(study / "queries" / server / room / "queries.jsonl")
            local = read_query_log(reference / "queries" / server / room / "queries.jsonl")
            assert len(remote) == len(local) > 0
            assert sum(q["success"] for q in remote) > 0
            for a, b in zip(remote, local, strict=True):
                pose_a, pose_b = a.pop("cam_from_world"), b.pop("cam_from_world")
                assert a == b  # retrieved, num_inliers, inlier_instance_counts, success...
                assert (pose_a is None) == (pose_b is None)
                if pose_a is not None:
                    np.testing.assert_allclose(pose_a, pose_b, atol=1e-12)


def test_study_against_separate_serve_processes_equals_the_in_process_study(ci_tiny_study, tmp_path):
    """One single-map ``synthleak serve`` process per room, addressed by a port template: the same
    ``results.json`` bytes as in process; every query went over HTTP."""
    study = tmp_path / "study"
    shutil.copytree(ci_tiny_study, study)
    rooms = _rooms(study)
    prefix = _free_port_block(len(rooms))
    services = [_Serve(prefix * 100 + i, tmp_path / f"serve-{room}.log", str(study / "maps" / "sift" / room),
                       "--config", "ci-tiny")
                for i, room in enumerate(rooms)]
    try:
        for service in services:
            service.wait()
        assert httpx.get(f"{services[0].url}/maps").status_code == 404  # a single map lists none
        results = _rerun_queries(study, load_config("ci-tiny"), f"http://127.0.0.1:{prefix}{{room_index:02d}}")
    finally:
        logs = [service.stop() for service in services]
    assert results == (ci_tiny_study / "results" / "results.json").read_bytes()
    _assert_logs_match(study, ci_tiny_study, ["sift"])
    for room, log in zip(rooms, logs, strict=True):
        n = len(read_query_log(study / "queries" / "sift" / room / "queries.jsonl"))
        assert log.count("POST /localize?labels=1") == n, log[-2000:]


@pytest.mark.slow
def test_line_cloud_study_against_one_multi_map_service_equals_the_in_process_study(ci_tiny_study, tmp_path):
    """Servers ``sift`` and ``sift+line-cloud``: ``synthleak serve STUDY/maps`` in one process, found through
    its ``GET /maps`` from a plain URL; the results are the in-process study's bytes."""
    config_path = tmp_path / "lines.toml"
    config_path.write_text('extends = "ci-tiny"\n[localize]\nrepresentation = ["points", "line-cloud"]\n')
    config = load_config(config_path)
    reference = tmp_path / "reference"
    shutil.copytree(ci_tiny_study, reference)
    run_study(config, reference, progress=False, workers=1)  # the line-cloud maps and queries, in process
    study = tmp_path / "study"
    shutil.copytree(reference, study)
    service = _Serve(_free_port(), tmp_path / "serve.log", str(study / "maps"), "--config", str(config_path))
    try:
        service.wait()
        maps = httpx.get(f"{service.url}/maps").json()
        assert sorted((m["server"], m["room"]) for m in maps) == [
            (s, r) for s in ("sift", "sift+line-cloud") for r in _rooms(study)]
        missing = httpx.post(f"{service.url}/sift/room_999/localize", content=b"x")
        assert missing.status_code == 404 and "sift/room_000" in missing.json()["detail"]
        results = _rerun_queries(study, config, service.url)
    finally:
        log = service.stop()
    assert results == (reference / "results" / "results.json").read_bytes()
    assert any(row["tier"] == "sift+line-cloud" for row in json.loads(results))
    _assert_logs_match(study, reference, ["sift", "sift+line-cloud"])
    assert "line-cloud/room_001/localize?labels=1" in log  # uvicorn logs the path quoted (%2B)
