"""The HTTP service under hostile and heavy use: blank, huge, 16-bit and slow uploads, disconnects, a pool
of localizer processes (answers byte-identical whatever the number of workers, ``/health`` answering while
queries run).

Fixture: a small textured box room ray cast with embree (:mod:`synthleak.localize.testscene`), 320x240,
and its sift map.
"""

from __future__ import annotations

import io
import json
import logging
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from fastapi.testclient import TestClient
from PIL import Image

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.localize import Localizer, build_map
from synthleak.localize import testscene as ts
from synthleak.localize.images import MAX_QUERY_PIXELS, ImageTooLargeError, decode_image, read_size
from synthleak.localize.pool import LocalizerPool
from synthleak.localize.server import create_app

CONFIG = LocalizeConfig(max_keypoints=1024, pairs_per_image=4)
CAMERA = Camera.from_hfov(320, 240, 65.0)


def png_bytes(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("room") / "room_000"
    return ts.write_sequence(out, ts.make_room(seed=0), CAMERA, ts.walkthrough_poses(24), query_every=4)


@pytest.fixture(scope="module")
def map_dir(scene, tmp_path_factory) -> Path:
    return build_map(scene, "sift", tmp_path_factory.mktemp("map") / "sift", CONFIG, progress=False)


@pytest.fixture(scope="module")
def localizer(map_dir) -> Localizer:
    return Localizer.load(map_dir, CONFIG)


@pytest.fixture(scope="module")
def client(localizer) -> TestClient:
    return TestClient(create_app(localizer, max_upload_bytes=2_000_000))


@pytest.fixture(scope="module")
def queries(scene) -> list[bytes]:
    seq = load_sequence(scene)
    return [seq.image_path(f).read_bytes() for f in seq.query_frames]


# ---------------------------------------------------------------- blank, 16-bit and oversized images


@pytest.mark.parametrize("level", [0, 128, 255])
def test_blank_image_is_not_localized_not_an_error(client, level):
    blank = png_bytes(np.full((240, 320, 3), level, np.uint8))
    response = client.post("/localize", content=blank)
    assert response.status_code == 200, response.text
    assert response.json() == {"success": False}


def test_blank_image_does_not_abort_a_localize_batch(map_dir, scene, tmp_path, capsys):
    from synthleak.cli import main

    blank = tmp_path / "blank.png"
    blank.write_bytes(png_bytes(np.zeros((240, 320, 3), np.uint8)))
    seq = load_sequence(scene)
    query = str(seq.image_path(seq.query_frames[0]))
    assert main(["localize", str(map_dir), str(blank), query]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [line["image"] for line in lines] == [str(blank), query]
    assert lines[0]["success"] is False and lines[1]["success"] is True


def test_refused_image_is_named_and_does_not_abort_a_localize_batch(map_dir, scene, tmp_path, capsys):
    from synthleak.cli import main

    huge = tmp_path / "huge.png"
    huge.write_bytes(png_bytes(np.zeros((6000, 6000), np.uint8)))
    seq = load_sequence(scene)
    query = str(seq.image_path(seq.query_frames[0]))
    assert main(["localize", str(map_dir), str(huge), query]) == 2
    captured = capsys.readouterr()
    lines = [json.loads(line) for line in captured.out.splitlines()]
    assert [line["image"] for line in lines] == [str(huge), query]
    assert lines[0]["success"] is False and "6000x6000" in lines[0]["error"] and lines[1]["success"] is True
    assert str(huge) in captured.err and "1 of 2 images refused" in captured.err


def test_16_bit_images_are_scaled_not_clipped(localizer, scene):
    seq = load_sequence(scene)
    frame = seq.query_frames[1]
    rgb = seq.rgb(frame)
    expected = localizer.localize(rgb)
    assert expected.success
    wide = rgb.astype(np.uint16) * 257  # the same image, 16 bits per sample
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    for array, as_rgb in ((wide, rgb), (grey.astype(np.uint16) * 257, np.repeat(grey[..., None], 3, 2))):
        ok, encoded = cv2.imencode(".png", array[..., ::-1] if array.ndim == 3 else array)
        assert ok
        decoded = decode_image(encoded.tobytes())
        assert decoded.dtype == np.uint8 and np.array_equal(decoded, as_rgb)
    result = localizer.localize(cv2.imencode(".png", wide[..., ::-1])[1].tobytes())
    assert result.success and np.array_equal(result.cam_from_world, expected.cam_from_world)
    # values that are not multiples of 257 round to the nearest 8-bit level (not truncated to the high byte)
    ramp = np.arange(0, 65536, 16, dtype=np.uint16).reshape(64, 64)
    expected = np.round(ramp / 257).astype(np.uint8)
    assert np.array_equal(decode_image(cv2.imencode(".png", ramp)[1].tobytes())[..., 0], expected)
    colour = np.stack([ramp, ramp[::-1], ramp[:, ::-1]], axis=-1)
    assert np.array_equal(decode_image(cv2.imencode(".png", colour[..., ::-1])[1].tobytes()),
                          np.stack([expected, expected[::-1], expected[:, ::-1]], axis=-1))


def test_decompression_bomb_is_refused_from_the_header(client):
    bomb = png_bytes(np.zeros((6000, 6000), np.uint8))  # ~100 KB that would decode to 108 MB of RGB
    assert len(bomb) < 200_000
    with pytest.raises(ImageTooLargeError, match="6000x6000"):
        read_size(bomb)
    with pytest.raises(ImageTooLargeError):
        decode_image(bomb)
    params = {"fx": 5000, "fy": 5000, "cx": 3000, "cy": 3000}
    started = time.perf_counter()
    response = client.post("/localize", content=bomb, params=params)
    assert response.status_code == 413 and f"{MAX_QUERY_PIXELS:,}" in response.json()["detail"]
    assert time.perf_counter() - started < 5.0  # a header read, not a 36 MP decode and extraction


def test_large_photo_is_downscaled_with_scaled_intrinsics(localizer, scene):
    """A 3x upscaled query with 3x intrinsics: extracted at the map's size, and the same camera pose."""
    seq = load_sequence(scene)
    frame = seq.query_frames[2]
    rgb = seq.rgb(frame)
    big = cv2.resize(rgb, (960, 720), interpolation=cv2.INTER_CUBIC)
    cam = localizer.camera
    big_camera = Camera(960, 720, cam.fx * 3, cam.fy * 3, cam.cx * 3, cam.cy * 3)
    seen = []
    extractor = localizer.extractor
    localizer.extractor = lambda image: seen.append(image.shape) or extractor(image)
    try:
        result = localizer.localize(png_bytes(big), big_camera)
    finally:
        localizer.extractor = extractor
    assert seen == [(240, 320, 3)]
    assert result.success
    gt = seq.cam_from_world[frame]
    centre = -result.cam_from_world[:3, :3].T @ result.cam_from_world[:3, 3]
    assert np.linalg.norm(centre - (-gt[:3, :3].T @ gt[:3, 3])) < 0.05


# ---------------------------------------------------------------- slow bodies and disconnects


class _Server:
    """uvicorn serving ``app`` on a free loopback port in a thread."""

    def __init__(self, app) -> None:
        import uvicorn

        with socket.socket() as sock:
            sock.bind(("127.0.0.1", 0))
            self.port = sock.getsockname()[1]
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port, log_level="info",
                                                    limit_concurrency=64))
        self.thread = threading.Thread(target=self.server.run, daemon=True)

    def __enter__(self) -> _Server:
        self.thread.start()
        deadline = time.monotonic() + 20
        while not self.server.started and time.monotonic() < deadline:
            time.sleep(0.05)
        assert self.server.started
        return self

    def __exit__(self, *exc) -> None:
        self.server.should_exit = True
        self.thread.join(timeout=10)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"


def _raw_request(port: int, declared: int, body: bytes) -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.sendall(f"POST /localize HTTP/1.1\r\nHost: x\r\nContent-Length: {declared}\r\n\r\n".encode() + body)
    return sock


def test_short_body_times_out_with_408_and_the_connection_closes(localizer):
    app = create_app(localizer, body_idle_timeout=0.5, body_timeout=2.0)
    with _Server(app) as server:
        socks = [_raw_request(server.port, 10_000, b"\x89PNG" * 10) for _ in range(5)]
        started = time.monotonic()
        for sock in socks:
            with sock:
                answer = b""
                while chunk := sock.recv(65536):  # the server closes the connection after its answer
                    answer += chunk
                assert answer.startswith(b"HTTP/1.1 408"), answer[:200]
                assert b"timed out after 40 bytes of 10000 declared" in answer
        assert time.monotonic() - started < 5.0
        assert httpx.get(f"{server.url}/health").json() == {"status": "ok"}


def test_slow_trickle_is_cut_at_the_total_deadline(localizer):
    app = create_app(localizer, body_idle_timeout=1.0, body_timeout=1.5)
    with _Server(app) as server, _raw_request(server.port, 1000, b"x") as sock:
        started, answer = time.monotonic(), b""
        sock.settimeout(0.3)
        while time.monotonic() - started < 8 and not answer:
            try:
                sock.sendall(b"x")  # a byte every 0.3 s: never idle for 1 s, never complete
                answer = sock.recv(65536)
            except TimeoutError:
                continue
        assert answer.startswith(b"HTTP/1.1 408"), answer[:200]


def test_client_disconnect_is_one_log_line(localizer, caplog):
    with caplog.at_level(logging.INFO), _Server(create_app(localizer)) as server:
        sock = _raw_request(server.port, 100_000, b"\x89PNG" * 100)
        time.sleep(0.3)
        sock.close()  # gone mid-upload
        deadline = time.monotonic() + 5
        while "disconnected" not in caplog.text and time.monotonic() < deadline:
            time.sleep(0.05)
        assert httpx.get(f"{server.url}/health").status_code == 200
    lines = [r.getMessage() for r in caplog.records if "disconnect" in r.getMessage().lower()]
    assert len(lines) == 1 and "disconnected during its upload" in lines[0], lines
    assert "Traceback" not in caplog.text and not any(r.exc_info for r in caplog.records)


# ---------------------------------------------------------------- the pool


def _answers(url: str, bodies: list[bytes], clients: int) -> list[bytes]:
    with httpx.Client(timeout=60) as http, ThreadPoolExecutor(clients) as threads:
        responses = list(threads.map(lambda body: http.post(f"{url}/localize", content=body), bodies))
    assert all(r.status_code == 200 for r in responses), [r.text for r in responses if r.status_code != 200]
    return [r.content for r in responses]


def test_pool_answers_are_byte_identical_across_worker_counts(map_dir, localizer, queries):
    bodies = queries * 2
    with TestClient(create_app(localizer)) as client:
        expected = [client.post("/localize", content=body).content for body in bodies]
    assert sum(json.loads(a)["success"] for a in expected) >= len(queries)
    for workers in (1, 2):
        with LocalizerPool(map_dir, workers, CONFIG) as pool, _Server(create_app(pool)) as server:
            assert _answers(server.url, bodies, clients=4) == expected, f"workers={workers}"


def test_health_answers_while_queries_run(map_dir, queries):
    with LocalizerPool(map_dir, 1, CONFIG) as pool, _Server(create_app(pool)) as server:
        done: list[float] = []

        def run() -> None:
            _answers(server.url, queries * 3, clients=len(queries) * 3)
            done.append(time.monotonic())

        thread = threading.Thread(target=run)
        thread.start()
        time.sleep(0.2)  # the queries are in (one worker: they queue behind each other)
        asked = time.monotonic()
        health = httpx.get(f"{server.url}/health", timeout=30)
        answered = time.monotonic()
        thread.join()
        assert health.json() == {"status": "ok"}
        assert answered < done[0]  # answered while queries were still running...
        assert answered - asked < 1.0  # ...without waiting for them (a liveness bound, not a benchmark)


def test_pool_reports_map_errors_at_start(tmp_path):
    from synthleak.localize.store import MapError

    with pytest.raises(MapError, match="map.json"):
        LocalizerPool(tmp_path / "nowhere", 2)


def test_a_killed_worker_costs_one_503_then_the_pool_is_restarted(map_dir, localizer, queries):
    import multiprocessing
    import os
    import signal

    expected = TestClient(create_app(localizer)).post("/localize", content=queries[0]).content
    with LocalizerPool(map_dir, 1, CONFIG) as pool, _Server(create_app(pool)) as server:
        (worker,) = multiprocessing.active_children()
        os.kill(worker.pid, signal.SIGKILL)  # as the kernel's OOM killer would
        worker.join(10)
        first = httpx.post(f"{server.url}/localize", content=queries[0], timeout=120)
        assert first.status_code == 503 and "restarted" in first.json()["detail"]
        assert httpx.post(f"{server.url}/localize", content=queries[0], timeout=120).content == expected
