"""HTTP client with the in-process :class:`~synthleak.localize.localizer.Localizer` interface."""

from __future__ import annotations

import time

import httpx
import numpy as np

from synthleak.core.dataset import encode_png
from synthleak.core.types import Camera
from synthleak.geometry.poses import make_pose, matrix_from_quat_wxyz
from synthleak.localize.localizer import LocalizationResult


class LocalizationServiceError(RuntimeError):
    """The service rejected a request (4xx/5xx); carries its status code and message."""

    def __init__(self, status_code: int, message: str) -> None:
        super().__init__(f"HTTP {status_code}: {message}")
        self.status_code = status_code


class HttpLocalizer:
    """``localize(image, camera=None)`` against a running service; only success and pose come back."""

    def __init__(self, url: str, timeout: float = 60.0) -> None:
        self.url = url.rstrip("/")
        self._client = httpx.Client(timeout=timeout)

    def close(self) -> None:
        self._client.close()

    def __enter__(self) -> HttpLocalizer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def health(self) -> bool:
        return self._client.get(f"{self.url}/health").status_code == 200

    def localize(self, image: np.ndarray | bytes, camera: Camera | None = None) -> LocalizationResult:
        t0 = time.perf_counter()
        body = bytes(image) if isinstance(image, bytes | bytearray) else encode_png(np.asarray(image, dtype=np.uint8))
        params = {}
        if camera is not None:
            params = {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
                      "width": camera.width, "height": camera.height}
        response = self._client.post(f"{self.url}/localize", content=body, params=params,
                                     headers={"Content-Type": "application/octet-stream"})
        if response.status_code != 200:
            try:
                message = response.json().get("detail", response.text)
            except ValueError:
                message = response.text
            raise LocalizationServiceError(response.status_code, str(message))
        data = response.json()
        timings = {"total": time.perf_counter() - t0}
        if not data.get("success"):
            return LocalizationResult(False, timings=timings)
        pose = data["cam_from_world"]
        matrix = make_pose(matrix_from_quat_wxyz(pose["rotation"]), pose["translation"])
        return LocalizationResult(True, matrix, timings=timings)
