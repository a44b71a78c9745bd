"""The HTTP service under load: requests/s and p95 latency at 1, 4 and 16 clients, and the server's memory and
``/health`` latency under oversized uploads.

    python benchmarks/server_load.py                       # synthetic box room, 320x240, sift; --workers 1 2
    python benchmarks/server_load.py --workers 0 --server-src OTHER/src   # another checkout's server, its
                                                                          # default workers (before/after)
    python benchmarks/server_load.py --docs docs/service.md   # also writes the figures into the page's block

Starts ``synthleak serve MAP [--workers N]`` as a subprocess for each worker count; clients are threads that
each POST pre-encoded query PNGs (the held-out frames of the room) in turn. Then uploads oversized images
(a 6000x6000 black PNG, a 6000x4500 and a 5000x4000 upscaled query; all with intrinsics) one at a time, sampling the
resident memory of the server and its worker processes every 10 ms and polling ``/health``. Every answer to
the same query must be the same bytes, whatever the worker count or the number of clients: the script says
whether they were.
"""

from __future__ import annotations

import argparse
import builtins
import contextlib
import io
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
from PIL import Image

from synthleak.config import load_config
from synthleak.core.dataset import load_sequence
from synthleak.core.types import Camera
from synthleak.localize import build_map
from synthleak.localize import testscene as ts


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _tree(pid: int) -> list[int]:
    """``pid`` and its descendants (Linux /proc)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        for task in Path(f"/proc/{p}/task").glob("*/children"):
            with contextlib.suppress(OSError):  # the process ended meanwhile
                todo += [int(c) for c in task.read_text().split()]
    return out


def _rss_mib(pid: int) -> float:
    total = 0
    for p in _tree(pid):
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024


class Server:
    """``synthleak serve`` in a subprocess."""

    def __init__(self, map_dir: Path, workers: int, src: Path | None, config: str) -> None:
        self.port = _free_port()
        cmd = [sys.executable, "-m", "synthleak.cli", "serve", str(map_dir), "--port", str(self.port),
               "--config", config]
        if workers:
            cmd += ["--workers", str(workers)]
        env = dict(os.environ)
        if src is not None:
            env["PYTHONPATH"] = str(src)
        self.proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        self.url = f"http://127.0.0.1:{self.port}"
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited: {self.proc.stderr.read()}")
            try:
                if httpx.get(f"{self.url}/health", timeout=1).status_code == 200:
                    return
            except httpx.HTTPError:
                time.sleep(0.2)
        raise RuntimeError("server did not start in 120 s")

    def close(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(30)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def load(url: str, bodies: list[bytes], clients: int, requests: int) -> tuple[float, float, dict[int, set[bytes]]]:
    """(requests/s, p95 latency s, answers per body index) for ``requests`` POSTs from ``clients`` threads."""
    order = [i % len(bodies) for i in range(requests)]
    latencies: list[float] = []
    answers: dict[int, set[bytes]] = {}
    lock = threading.Lock()
    local = threading.local()

    def one(i: int) -> None:
        if not hasattr(local, "http"):
            local.http = httpx.Client(timeout=300)
        t0 = time.perf_counter()
        response = local.http.post(f"{url}/localize", content=bodies[i])
        elapsed = time.perf_counter() - t0
        with lock:
            latencies.append(elapsed)
            answers.setdefault(i, set()).add(response.status_code.to_bytes(2, "big") + response.content)

    started = time.perf_counter()
    with ThreadPoolExecutor(clients) as pool:
        list(pool.map(one, order))
    wall = time.perf_counter() - started
    return requests / wall, float(np.percentile(latencies, 95)), answers


def png(image: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


def oversized(camera: Camera, query: np.ndarray) -> list[tuple[str, bytes, dict]]:
    """(label, body, query parameters) of the oversized uploads."""
    def intrinsics(w: int, h: int) -> dict:
        sx, sy = w / camera.width, h / camera.height
        return {"fx": camera.fx * sx, "fy": camera.fy * sy, "cx": camera.cx * sx, "cy": camera.cy * sy}

    rows = [("6000x6000 black", png(np.zeros((6000, 6000), np.uint8)), intrinsics(6000, 6000))]
    for w, h in ((6000, 4500), (5000, 4000)):
        big = np.asarray(Image.fromarray(query).resize((w, h), Image.Resampling.BILINEAR))
        rows.append((f"{w}x{h} query", png(big), intrinsics(w, h)))
    return rows


def upload_under_watch(server: Server, body: bytes, params: dict) -> dict:
    """One upload; the server tree's peak RSS, the worst /health latency while it ran, status, seconds."""
    peak, worst_health, stop = [_rss_mib(server.proc.pid)], [0.0], threading.Event()

    def sample() -> None:
        while not stop.is_set():
            peak.append(_rss_mib(server.proc.pid))
            time.sleep(0.01)

    def health() -> None:
        while not stop.is_set():
            t0 = time.perf_counter()
            with contextlib.suppress(httpx.HTTPError):  # a new connection each time; an error counts as its wait
                httpx.get(f"{server.url}/health", timeout=300)
            worst_health[0] = max(worst_health[0], time.perf_counter() - t0)
            time.sleep(0.05)

    threads = [threading.Thread(target=sample), threading.Thread(target=health)]
    for t in threads:
        t.start()
    t0 = time.perf_counter()
    try:
        response = httpx.post(f"{server.url}/localize", content=body, params=params, timeout=600)
        status = response.status_code
    except httpx.HTTPError as exc:
        status = type(exc).__name__
    seconds = time.perf_counter() - t0
    time.sleep(0.1)
    stop.set()
    for t in threads:
        t.join()
    return {"status": status, "seconds": seconds, "peak_mib": max(peak), "health_s": worst_health[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                        help="server worker counts to run (0: do not pass --workers)")
    parser.add_argument("--clients", type=int, nargs="+", default=[1, 4, 16])
    parser.add_argument("--requests", type=int, default=64, help="requests per client count")
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--width", type=int, default=320)
    parser.add_argument("--height", type=int, default=240)
    parser.add_argument("--server-src", type=Path, help="PYTHONPATH of the server (another checkout's src)")
    parser.add_argument("--no-oversized", action="store_true", help="skip the oversized uploads")
    parser.add_argument("--no-load", action="store_true", help="skip the client load (oversized uploads only)")
    parser.add_argument("--docs", metavar="PAGE", help="write the printed figures into PAGE's block 'server-load'")
    args = parser.parse_args()
    printed: list[str] = []

    def print(line: str) -> None:  # noqa: A001 (the figures also go to --docs)
        printed.append(line)
        builtins.print(line, flush=True)
    print(f"{os.cpu_count()} cores; server from {args.server_src or 'this checkout'}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        camera = Camera.from_hfov(args.width, args.height, 65.0)
        scene = ts.write_sequence(work / "room_000", ts.make_room(seed=0), camera,
                                  ts.walkthrough_poses(args.frames), query_every=5)
        config = "ci-tiny"  # its [localize]: sift, 2048 keypoints, 8 pairs per image
        map_dir = build_map(scene, "sift", work / "map", load_config(config).localize, progress=False)
        seq = load_sequence(scene)
        bodies = [seq.image_path(f).read_bytes() for f in seq.query_frames]
        print(f"map: {len(seq.map_frames)} images at {args.width}x{args.height}, sift; "
              f"{len(bodies)} distinct queries, {args.requests} requests per row")
        all_answers: dict[int, set[bytes]] = {}
        for workers in args.workers:
            server = Server(map_dir, workers, args.server_src, config)
            try:
                label = f"workers={workers}" if workers else "default workers"
                idle = _rss_mib(server.proc.pid)
                for clients in [] if args.no_load else args.clients:
                    rps, p95, answers = load(server.url, bodies, clients, args.requests)
                    for k, v in answers.items():
                        all_answers.setdefault(k, set()).update(v)
                    print(f"{label:>16}  clients={clients:<3} {rps:6.1f} requests/s  p95 {p95:6.3f} s")
                if not args.no_oversized:
                    print(f"{label:>16}  idle server tree RSS {idle:.0f} MiB")
                    for name, body, params in oversized(camera, seq.rgb(seq.query_frames[0])):
                        r = upload_under_watch(server, body, params)
                        print(f"{label:>16}  {name} ({len(body) / 1024:.0f} KB): HTTP {r['status']} in "
                              f"{r['seconds']:.2f} s, peak server tree RSS {r['peak_mib']:.0f} MiB, "
                              f"worst /health {r['health_s']:.3f} s")
            finally:
                server.close()
        distinct = {k: len(v) for k, v in all_answers.items()}
        localized = sum(json.loads(next(iter(v))[2:]).get("success", False) for v in all_answers.values())
        print(f"answers identical for every query across runs: {all(n == 1 for n in distinct.values())} "
              f"({localized}/{len(all_answers)} queries localized)")
    if args.docs:
        from synthleak.evaluate.doc_blocks import write_benchmark_block

        text = "\n".join(printed)
        write_benchmark_block(args.docs, "server-load", f"```\n{text}\n```")


if __name__ == "__main__":
    main()
