"""HTTP localization service (FastAPI, loopback by default).

``POST /localize``: the request body is the encoded image itself (PNG/JPEG/..., 8 or 16 bits per sample, any
Content-Type, e.g. ``image/png``), optional intrinsics as query parameters ``fx, fy, cx, cy`` (all four or
none) and ``width, height`` (must equal the image size if given), and with them, optionally, the lens
distortion ``k1, k2, p1, p2, k3`` (OpenCV / COLMAP ``OPENCV``; absent ones are 0, none: pinhole). Without
intrinsics the map's camera is used and the image must have the map's size. The response is exactly
``{"success": true, "cam_from_world": {"rotation": [qw, qx, qy, qz], "translation": [x, y, z]}}`` or
``{"success": false}`` (also for an image without features, such as a blank one). Bad input gets a 4xx with
``{"detail": "<message>"}``: 400 (empty, undecodable, too small, size mismatch), 408 (the body did not arrive
in time: nothing for ``body_idle_timeout`` seconds, or not all of it within ``body_timeout``), 413 (body over
``max_upload_bytes``, rejected from Content-Length or while streaming; or an image header declaring more than
``MAX_QUERY_PIXELS``, refused before decoding), 422 (bad intrinsics). ``GET /health`` -> ``{"status": "ok"}``.
With ``?labels=1`` the answer also holds the server-side labels a study's evaluation reads (``num_inliers``,
``inlier_instance_counts``, ``retrieved``). :func:`create_maps_app` serves several maps, each under
``/<server>/<room>/``, listed at ``GET /maps``. The protocol: docs/service-protocol.md.

Work per query is bounded (see :mod:`synthleak.localize.images`): images larger than the map's are
downscaled to its pixel count with scaled intrinsics. :func:`serve` runs queries in a
:class:`~synthleak.localize.pool.LocalizerPool` of ``workers`` processes, so they run in parallel and the
event loop (``/health``, uploads) never waits for one. A client that disconnects mid-upload is logged as one
line.
"""

from __future__ import annotations

import asyncio
import logging
import math
import os
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Protocol

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from synthleak.config import LocalizeConfig
from synthleak.core.dataset import OpenCVCamera
from synthleak.core.types import Camera
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.images import MAX_QUERY_PIXELS, ImageTooLargeError, InvalidImageError, read_size
from synthleak.localize.localizer import LocalizationResult, Localizer
from synthleak.localize.pool import LocalizerPool, WorkerCrashedError
from synthleak.localize.wire_pose import encode_pose

MAX_UPLOAD_BYTES = 32 * 1024 * 1024
MIN_IMAGE_SIDE = 16
BODY_IDLE_TIMEOUT_S = 10.0
"""Seconds an upload may send nothing before it is answered 408 (a Content-Length larger than the body)."""
BODY_TIMEOUT_S = 60.0
"""Seconds the whole body may take."""
MAX_CONNECTIONS = 64
"""uvicorn's ``limit_concurrency``: more connections at once are answered 503, so upload buffers stay below
``MAX_CONNECTIONS * max_upload_bytes``."""

logger = logging.getLogger("synthleak.server")


class Backend(Protocol):
    """What the app needs: the map camera and ``await localize(data, camera)``."""

    camera: Camera
    max_query_pixels: int

    async def localize(self, data: bytes, camera: Camera | None) -> LocalizationResult: ...


class InProcessBackend:
    """One :class:`Localizer` in this process, calls serialised in a thread (tests, embedding). pycolmap's SIFT
    holds the GIL, so the event loop stalls while it runs: :func:`serve` uses a :class:`LocalizerPool`."""

    def __init__(self, localizer: Localizer) -> None:
        self.localizer = localizer
        self.camera = localizer.camera
        self.max_query_pixels = localizer.max_query_pixels
        self._lock = threading.Lock()

    def _run(self, data: bytes, camera: Camera | None) -> LocalizationResult:
        with self._lock:
            return self.localizer.localize(data, camera)

    async def localize(self, data: bytes, camera: Camera | None) -> LocalizationResult:
        return await run_in_threadpool(self._run, data, camera)


def _check_size(data: bytes, max_pixels: int) -> tuple[int, int]:
    """(width, height) from the image header (nothing decoded); 400 if unreadable or too small, 413 if too many
    pixels."""
    try:
        width, height = read_size(data, max_pixels)
    except ImageTooLargeError as exc:
        raise HTTPException(413, str(exc)) from exc
    except InvalidImageError as exc:
        raise HTTPException(400, "request body is not a decodable image (PNG, JPEG, ...)") from exc
    if min(width, height) < MIN_IMAGE_SIDE:
        raise HTTPException(400, f"image is {width}x{height}; both sides must be >= {MIN_IMAGE_SIDE} px")
    return width, height


def _camera_from_query(params, width: int, height: int) -> Camera | None:
    """Intrinsics from the query string, validated against the image size (422 on bad values)."""
    names = ("fx", "fy", "cx", "cy")
    given = {k: params[k] for k in (*names, "width", "height") if k in params}
    if not any(k in given for k in names):
        if any(k in params for k in DISTORTION_PARAMS):
            raise HTTPException(422, "distortion: give the intrinsics fx, fy, cx, cy with it")
        return None
    if not all(k in given for k in names):
        raise HTTPException(422, "intrinsics: give all of fx, fy, cx, cy or none")
    values = {}
    for key, text in given.items():
        try:
            values[key] = float(text)
        except ValueError:
            raise HTTPException(422, f"intrinsics: {key}={text!r} is not a number") from None
        if not math.isfinite(values[key]):
            raise HTTPException(422, f"intrinsics: {key} must be finite")
    for key in ("width", "height"):
        if key in values and values[key] != (width if key == "width" else height):
            raise HTTPException(
                422, f"intrinsics: {key}={given[key]} does not match the image ({width}x{height})"
            )
    if values["fx"] <= 0 or values["fy"] <= 0:
        raise HTTPException(422, "intrinsics: fx and fy must be > 0")
    if not (0 < values["cx"] < width and 0 < values["cy"] < height):
        raise HTTPException(422, f"intrinsics: principal point ({values['cx']}, {values['cy']}) lies outside "
                                 f"the {width}x{height} image")
    camera = Camera(width, height, values["fx"], values["fy"], values["cx"], values["cy"])
    return _with_distortion(params, camera)


DISTORTION_PARAMS = ("k1", "k2", "p1", "p2", "k3")
"""Optional query parameters: the query camera's OpenCV lens distortion (COLMAP ``OPENCV``; absent: 0)."""


def _with_distortion(params, camera: Camera) -> Camera:
    """``camera`` with the lens distortion of the query string, if any (422 on bad values)."""
    given = {k: params[k] for k in DISTORTION_PARAMS if k in params}
    if not given:
        return camera
    values = {}
    for key, text in given.items():
        try:
            values[key] = float(text)
        except ValueError:
            raise HTTPException(422, f"distortion: {key}={text!r} is not a number") from None
        if not (math.isfinite(values[key]) and abs(values[key]) <= 1.0):
            raise HTTPException(422, f"distortion: {key} must be finite and in [-1, 1]")
    return OpenCVCamera(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy,
                        *(values.get(k, 0.0) for k in DISTORTION_PARAMS))


class _Closing(HTTPException):
    """An error answered before the whole body was read: the connection is closed after the answer."""

    def __init__(self, status_code: int, detail: str) -> None:
        super().__init__(status_code, detail, headers={"Connection": "close"})


async def _read_body(request: Request, limit: int, idle_timeout: float, timeout: float) -> bytes:
    """The whole body: 413 over ``limit``, 408 when nothing arrives for ``idle_timeout`` s or the body takes
    longer than ``timeout`` s (a Content-Length larger than the body waits for bytes that never come)."""
    length = request.headers.get("content-length")
    if length is not None:
        try:
            declared = int(length)
        except ValueError:
            raise HTTPException(400, "invalid Content-Length header") from None
        if declared > limit:
            raise _Closing(413, f"upload of {declared} bytes exceeds the limit of {limit} bytes")
    chunks, size = [], 0
    deadline = time.monotonic() + timeout
    stream = request.stream().__aiter__()
    while True:
        wait = min(idle_timeout, deadline - time.monotonic())
        try:
            async with asyncio.timeout(max(wait, 0.0)):
                chunk = await anext(stream)
        except StopAsyncIteration:
            break
        except TimeoutError:
            what = f"of {length} declared " if length is not None else ""
            raise _Closing(408, f"upload timed out after {size} bytes {what}(no data for {idle_timeout:g} s or "
                                f"not complete within {timeout:g} s)") from None
        size += len(chunk)
        if size > limit:
            raise _Closing(413, f"upload exceeds the limit of {limit} bytes")
        chunks.append(chunk)
    data = b"".join(chunks)
    if not data:
        raise HTTPException(400, "empty request body: send the encoded image as the body")
    return data


def create_app(
    backend: Localizer | Backend,
    max_upload_bytes: int = MAX_UPLOAD_BYTES,
    body_idle_timeout: float = BODY_IDLE_TIMEOUT_S,
    body_timeout: float = BODY_TIMEOUT_S,
) -> FastAPI:
    """The FastAPI app around a :class:`LocalizerPool` or an in-process :class:`Localizer`."""
    if isinstance(backend, Localizer):
        backend = InProcessBackend(backend)
    app = FastAPI(title="synthleak localization", docs_url=None, redoc_url=None, openapi_url=None)

    @app.get("/health")
    async def health() -> dict:
        return {"status": "ok"}

    @app.post("/localize", response_model=None)
    async def localize(request: Request) -> dict | Response:
        return await _answer(request, backend, max_upload_bytes, body_idle_timeout, body_timeout)

    return app


async def _answer(request: Request, backend: Backend, max_upload_bytes: int, body_idle_timeout: float,
                  body_timeout: float) -> dict | Response:
    """One ``POST .../localize``: read, check and localize the uploaded image; the JSON answer."""
    try:
        data = await _read_body(request, max_upload_bytes, body_idle_timeout, body_timeout)
    except ClientDisconnect:
        client = f"{request.client.host}:{request.client.port}" if request.client else "client"
        logger.info("%s disconnected during its upload to %s", client, request.url.path)
        return Response(status_code=400)  # nobody reads it
    labels = _labels_from_query(request.query_params)
    width, height = _check_size(data, backend.max_query_pixels)
    camera = _camera_from_query(request.query_params, width, height)
    if camera is None and (width, height) != (backend.camera.width, backend.camera.height):
        raise HTTPException(400, f"image is {width}x{height} but the map camera is "
                                 f"{backend.camera.width}x{backend.camera.height}: pass intrinsics")
    try:
        result = await backend.localize(data, camera)
    except ImageTooLargeError as exc:
        raise HTTPException(413, str(exc)) from exc
    except InvalidImageError as exc:
        raise HTTPException(400, str(exc)) from exc
    except WorkerCrashedError as exc:
        raise HTTPException(503, str(exc)) from exc
    return response_from_result(result, labels)


def _labels_from_query(params) -> bool:
    """The optional ``labels`` query parameter (``1``/``true`` or ``0``/``false``; 422 otherwise)."""
    text = params.get("labels", "0").lower()
    if text not in ("0", "1", "true", "false"):
        raise HTTPException(422, f"labels={params.get('labels')!r}: give 1/true or 0/false")
    return text in ("1", "true")


def response_from_result(result: LocalizationResult, labels: bool = False) -> dict:
    """The service's whole answer: the pose (quaternion [qw, qx, qy, qz] + translation) or failure; with
    ``labels`` (a study's evaluation asks ``?labels=1``) also the server-side labels the in-process query log
    holds: ``num_inliers``, ``inlier_instance_counts`` (instance id as a string -> inliers) and ``retrieved``
    (the map images matched against), docs/service-protocol.md."""
    extra = {} if not labels else {
        "num_inliers": int(result.num_inliers),
        "inlier_instance_counts": {str(k): int(v) for k, v in sorted(result.inlier_instance_counts.items())},
        "retrieved": [str(name) for name in result.retrieved]}
    if not result.success or result.cam_from_world is None:
        return {"success": False, **extra}
    return {"success": True, "cam_from_world": encode_pose(result.cam_from_world), **extra}


def find_maps(root: Path) -> dict[tuple[str, str], Path]:
    """The maps under a study's ``maps/`` folder, ``root/<server>/<room>/map.json``, by (server, room), sorted;
    a ValueError naming ``root`` when it holds none."""
    root = Path(root)
    maps = {(path.parent.parent.name, path.parent.name): path.parent for path in sorted(root.glob("*/*/map.json"))}
    if not maps:
        raise ValueError(f"{root}: neither a map (no map.json) nor a folder of maps (<server>/<room>/map.json)")
    return maps


def create_maps_app(
    backends: Mapping[tuple[str, str], Localizer | Backend],
    max_upload_bytes: int = MAX_UPLOAD_BYTES,
    body_idle_timeout: float = BODY_IDLE_TIMEOUT_S,
    body_timeout: float = BODY_TIMEOUT_S,
) -> FastAPI:
    """The app serving several maps by (server, room): ``POST /<server>/<room>/localize`` (as ``/localize`` of
    :func:`create_app`), ``GET /<server>/<room>/health``, ``GET /maps`` (the JSON list of ``{"server", "room",
    "path"}``) and ``GET /health``; an unknown (server, room) is answered 404."""
    served = {name: InProcessBackend(b) if isinstance(b, Localizer) else b for name, b in backends.items()}
    app = FastAPI(title="synthleak localization", docs_url=None, redoc_url=None, openapi_url=None)

    def backend_of(server: str, room: str) -> Backend:
        if (server, room) not in served:
            known = ", ".join(f"{s}/{r}" for s, r in served)
            raise HTTPException(404, f"no map {server}/{room} on this service (maps: {known})")
        return served[(server, room)]

    @app.get("/health")
    async def health() -> dict:
        return {"status": "ok"}

    @app.get("/maps")
    async def maps() -> list[dict]:
        return [{"server": server, "room": room, "path": f"/{server}/{room}"} for server, room in served]

    @app.get("/{server}/{room}/health")
    async def map_health(server: str, room: str) -> dict:
        backend_of(server, room)
        return {"status": "ok"}

    @app.post("/{server}/{room}/localize", response_model=None)
    async def localize(server: str, room: str, request: Request) -> dict | Response:
        backend = backend_of(server, room)
        return await _answer(request, backend, max_upload_bytes, body_idle_timeout, body_timeout)

    return app


def default_workers() -> int:
    """Localizer processes by default: one per core, at most 8 (each holds the map in memory)."""
    return max(1, min(8, os.cpu_count() or 1))


LOG_CONFIG_LOGGERS = {"synthleak.server": {"handlers": ["default"], "level": "INFO", "propagate": False}}


def serve(
    map_dir: Path,
    host: str = "127.0.0.1",
    port: int = 8000,
    config: LocalizeConfig | None = None,
    defense: DefensePolicy | None = None,
    decision_log: Path | None = None,
    weights_dir: Path | None = None,
    max_upload_bytes: int = MAX_UPLOAD_BYTES,
    workers: int | None = None,
    max_query_pixels: int = MAX_QUERY_PIXELS,
) -> None:
    """Start ``workers`` localizer processes (:func:`default_workers` if None) on the map and serve it with
    uvicorn until interrupted. ``map_dir`` may also be a folder of maps (a study's ``maps/``,
    ``<server>/<room>/map.json``): each is served under ``/<server>/<room>/`` by its own pool of ``workers``
    processes (1 if None), listed at ``GET /maps`` (:func:`create_maps_app`)."""
    import contextlib
    import copy

    import uvicorn
    from uvicorn.config import LOGGING_CONFIG

    log_config = copy.deepcopy(LOGGING_CONFIG)
    log_config["loggers"].update(LOG_CONFIG_LOGGERS)
    map_dir = Path(map_dir)
    with contextlib.ExitStack() as stack:
        if (map_dir / "map.json").is_file():
            pool = stack.enter_context(LocalizerPool(map_dir, workers or default_workers(), config, defense,
                                                     weights_dir, decision_log, max_query_pixels))
            app = create_app(pool, max_upload_bytes)
        else:
            if decision_log is not None:
                raise ValueError(f"{map_dir}: --decision-log needs a single map, not a folder of maps")
            app = create_maps_app({name: stack.enter_context(LocalizerPool(
                path, workers or 1, config, defense, weights_dir, None, max_query_pixels))
                for name, path in find_maps(map_dir).items()}, max_upload_bytes)
        uvicorn.run(app, host=host, port=port, log_level="info", log_config=log_config,
                    limit_concurrency=MAX_CONNECTIONS)
