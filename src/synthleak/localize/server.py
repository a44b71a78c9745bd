"""HTTP localization service (FastAPI, loopback by default).

``POST /localize``: the request body is the encoded image itself (PNG/JPEG/..., any Content-Type, e.g.
``image/png``), optional intrinsics as query parameters ``fx, fy, cx, cy`` (all four or none) and
``width, height`` (must equal the image size if given). Without intrinsics the map's camera is used and
the image must have the map's size. The response is exactly
``{"success": true, "cam_from_world": {"rotation": [qw, qx, qy, qz], "translation": [x, y, z]}}`` or
``{"success": false}``. Bad input gets a 4xx with ``{"detail": "<message>"}``: 400 (empty, undecodable,
too small, size mismatch), 413 (body over ``max_upload_bytes``, rejected from Content-Length or while
streaming), 422 (bad intrinsics). ``GET /health`` -> ``{"status": "ok"}``.
"""

from __future__ import annotations

import io
import math
import threading
from pathlib import Path

from fastapi import FastAPI, HTTPException, Request
from PIL import Image
from starlette.concurrency import run_in_threadpool

from synthleak.config import LocalizeConfig
from synthleak.geometry.poses import quat_wxyz_from_matrix
from synthleak.localize.defense import DefensePolicy
from synthleak.localize.localizer import InvalidImageError, LocalizationResult, Localizer
from synthleak.render.base import Camera

MAX_UPLOAD_BYTES = 100 * 1024 * 1024
MIN_IMAGE_SIDE = 16
MAX_IMAGE_PIXELS = 40_000_000


def _check_size(data: bytes) -> tuple[int, int]:
    """(width, height) from the image header; 400 if unreadable or out of bounds."""
    try:
        with Image.open(io.BytesIO(data)) as im:
            width, height = im.size
    except Image.DecompressionBombError as exc:
        raise HTTPException(413, f"image has too many pixels ({exc})") from exc
    except (OSError, ValueError) as exc:
        raise HTTPException(400, "request body is not a decodable image (PNG, JPEG, ...)") from exc
    if min(width, height) < MIN_IMAGE_SIDE:
        raise HTTPException(400, f"image is {width}x{height}; both sides must be >= {MIN_IMAGE_SIDE} px")
    if width * height > MAX_IMAGE_PIXELS:
        raise HTTPException(413, f"image is {width}x{height}; at most {MAX_IMAGE_PIXELS} pixels")
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


async def _read_body(request: Request, limit: int) -> bytes:
    length = request.headers.get("content-length")
    if length is not None:
        try:
            declared = int(length)
        except ValueError:
            raise HTTPException(400, "invalid Content-Length header") from None
        if declared > limit:
            raise HTTPException(413, f"upload of {declared} bytes exceeds the limit of {limit} bytes")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise HTTPException(413, f"upload exceeds the limit of {limit} bytes")
        chunks.append(chunk)
    data = b"".join(chunks)
    if not data:
        raise HTTPException(400, "empty request body: send the encoded image as the body")
    return data


def create_app(localizer: Localizer, max_upload_bytes: int = MAX_UPLOAD_BYTES) -> FastAPI:
    """The FastAPI app around one :class:`Localizer` (calls are serialised with a lock)."""
    app = FastAPI(title="synthleak localization", docs_url=None, redoc_url=None, openapi_url=None)
    lock = threading.Lock()

    def run(data: bytes, camera: Camera | None):
        with lock:
            return localizer.localize(data, camera)

    @app.get("/health")
    async def health() -> dict:
        return {"status": "ok"}

    @app.post("/localize")
    async def localize(request: Request) -> dict:
        data = await _read_body(request, max_upload_bytes)
        width, height = _check_size(data)
        camera = _camera_from_query(request.query_params, width, height)
        if camera is None and (width, height) != (localizer.camera.width, localizer.camera.height):
            raise HTTPException(400, f"image is {width}x{height} but the map camera is "
                                     f"{localizer.camera.width}x{localizer.camera.height}: pass intrinsics")
        try:
            result = await run_in_threadpool(run, data, camera)
        except InvalidImageError as exc:
            raise HTTPException(400, str(exc)) from exc
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


def serve(
    map_dir: Path,
    host: str = "127.0.0.1",
    port: int = 8000,
    config: LocalizeConfig | None = None,
    defense: DefensePolicy | None = None,
    decision_log: Path | None = None,
    weights_dir: Path | None = None,
    max_upload_bytes: int = MAX_UPLOAD_BYTES,
) -> None:
    """Load the map and run the service with uvicorn until interrupted."""
    import uvicorn

    localizer = Localizer.load(Path(map_dir), config, defense, weights_dir, decision_log)
    uvicorn.run(create_app(localizer, max_upload_bytes), host=host, port=port, log_level="info")
