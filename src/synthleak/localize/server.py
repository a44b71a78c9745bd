"""HTTP localization service (FastAPI, loopback by default).

``POST /localize``: the request body is the encoded image itself (PNG/JPEG/..., 8 or 16 bits per sample, any
Content-Type, e.g. ``image/png``), optional intrinsics as query parameters ``fx, fy, cx, cy`` (all four or
none) and ``width, height`` (must equal the image size if given). Without intrinsics the map's camera is used
and the image must have the map's size. The response is exactly
``{"success": true, "cam_from_world": {"rotation": [qw, qx, qy, qz], "translation": [x, y, z]}}`` or
``{"success": false}`` (also for an image without features, such as a blank one). Bad input gets a 4xx with
``{"detail": "<message>"}``: 400 (empty, undecodable, too small, size mismatch), 408 (the body did not arrive
in time: nothing for ``body_idle_timeout`` seconds, or not all of it within ``body_timeout``), 413 (body over
``max_upload_bytes``, rejected from Content-Length or while streaming; or an image header declaring more than
``MAX_QUERY_PIXELS``, refused before decoding), 422 (bad intrinsics). ``GET /health`` -> ``{"status": "ok"}``.

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
from pathlib import Path
from typing import Protocol

from fastapi import FastAPI, HTTPException, Request
from fastapi.responses import Response
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect

from synthleak.config import LocalizeConfig
from synthleak.core.types import Camera
from synthleak.geometry.poses import quat_wxyz_from_matrix
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.images import MAX_QUERY_PIXELS, ImageTooLargeError, InvalidImageError, read_size
from synthleak.localize.localizer import LocalizationResult, Localizer
from synthleak.localize.pool import LocalizerPool, WorkerCrashedError

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
    return Camera(width, height, values["fx"], values["fy"], values["cx"], values["cy"])


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
        try:
            data = await _read_body(request, max_upload_bytes, body_idle_timeout, body_timeout)
        except ClientDisconnect:
            client = f"{request.client.host}:{request.client.port}" if request.client else "client"
            logger.info("%s disconnected during its upload to /localize", client)
            return Response(status_code=400)  # nobody reads it
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
        return response_from_result(result)

    return app


def response_from_result(result: LocalizationResult) -> dict:
    """The service's whole answer: the pose (quaternion [qw, qx, qy, qz] + translation) or failure."""
    if not result.success or result.cam_from_world is None:
        return {"success": False}
    pose = result.cam_from_world
    return {"success": True, "cam_from_world": {
        "rotation": [float(x) for x in quat_wxyz_from_matrix(pose[:3, :3])],
        "translation": [float(x) for x in pose[:3, 3]]}}


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
    uvicorn until interrupted."""
    import copy

    import uvicorn
    from uvicorn.config import LOGGING_CONFIG

    log_config = copy.deepcopy(LOGGING_CONFIG)
    log_config["loggers"].update(LOG_CONFIG_LOGGERS)
    with LocalizerPool(Path(map_dir), workers or default_workers(), config, defense, weights_dir, decision_log,
                       max_query_pixels) as pool:
        uvicorn.run(create_app(pool, max_upload_bytes), host=host, port=port, log_level="info",
                    log_config=log_config, limit_concurrency=MAX_CONNECTIONS)
