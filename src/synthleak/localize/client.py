"""HTTP client with the in-process :class:`~synthleak.localize.localizer.Localizer` interface."""

from __future__ import annotations

import string
import time
from collections.abc import Sequence
from dataclasses import dataclass

import httpx
import numpy as np

from synthleak.core.dataset import camera_dist_coeffs, encode_png
from synthleak.core.types import Camera
from synthleak.errors import ServiceUnreachableError
from synthleak.localize.localizer import LocalizationResult
from synthleak.localize.servers import base_tier
from synthleak.localize.wire_pose import decode_pose


class LocalizationServiceError(RuntimeError):
    """The service rejected a request (4xx/5xx); carries its status code and message."""

    def __init__(self, status_code: int, message: str) -> None:
        super().__init__(f"HTTP {status_code}: {message}")
        self.status_code = status_code


@dataclass
class HttpLocalizationResult(LocalizationResult):
    """An HTTP answer; ``labelled``: it held the server-side labels (``?labels=1``), so ``num_inliers``,
    ``inlier_instance_counts`` and ``retrieved`` are the server's, not unknown."""

    labelled: bool = False


class HttpLocalizer:
    """``localize(image, camera=None)`` against a running service; success and pose come back, and with
    ``labels`` the server-side labels (docs/service-protocol.md) when the service gives them."""

    def __init__(self, url: str, timeout: float = 60.0, labels: bool = False) -> None:
        self.url = url.rstrip("/")
        self.labels = labels
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
        params: dict = {"labels": 1} if self.labels else {}
        if camera is not None:
            params |= {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy,
                      "width": camera.width, "height": camera.height}
            dist = camera_dist_coeffs(camera)  # a distorting lens: its OpenCV k1 k2 p1 p2 k3 (optional)
            if dist is not None:
                params |= dict(zip(("k1", "k2", "p1", "p2", "k3"), dist.tolist(), strict=True))
        try:
            response = self._client.post(f"{self.url}/localize", content=body, params=params,
                                         headers={"Content-Type": "application/octet-stream"})
        except httpx.TransportError as exc:
            raise ServiceUnreachableError(f"POST {self.url}/localize: no answer ({_reason(exc)})") from exc
        if response.status_code != 200:
            try:
                message = response.json().get("detail", response.text)
            except ValueError:
                message = response.text
            raise LocalizationServiceError(response.status_code, str(message))
        data = response.json()
        timings = {"total": time.perf_counter() - t0}
        labels = {}
        if self.labels and "num_inliers" in data:
            labels = {"labelled": True, "num_inliers": int(data["num_inliers"]),
                      "inlier_instance_counts": {int(k): int(v) for k, v in
                                                 data.get("inlier_instance_counts", {}).items()},
                      "retrieved": [str(name) for name in data.get("retrieved", [])]}
        if not data.get("success"):
            return HttpLocalizationResult(False, timings=timings, **labels)
        return HttpLocalizationResult(True, decode_pose(data["cam_from_world"]), timings=timings, **labels)


URL_FIELDS = ("server", "tier", "room", "room_index")
"""The placeholders of a ``--server`` URL template (docs/service-protocol.md)."""


def is_url_template(url: str) -> bool:
    """True when ``url`` holds a ``{...}`` placeholder."""
    return any(field is not None for _, field, _, _ in string.Formatter().parse(url))


def server_urls(url: str, pairs: Sequence[tuple[str, str]], rooms: Sequence[str],
                maps: Sequence[dict] | None = None) -> dict[tuple[str, str], str]:
    """The URL of each (server, room) pair of a study (docs/service-protocol.md): ``url`` as a template
    (``{server}``, ``{tier}``, ``{room}``, ``{room_index}``, format specs allowed, e.g. ``{room_index:02d}``),
    or, without placeholders, the entry of ``maps`` (a service's ``GET /maps``, paths relative to ``url``) or,
    without ``maps``, ``url`` itself for every pair. ``rooms``: the study's rooms in index order. A ValueError
    names a bad template, two pairs sent to one URL by a template, or a pair ``maps`` does not list."""
    base = url.rstrip("/")
    if not is_url_template(url):
        if maps is None:
            return {pair: base for pair in pairs}
        listed = {(str(m["server"]), str(m["room"])): str(m.get("url") or base + "/" + str(m["path"]).strip("/"))
                  for m in maps}
        missing = [f"{s}/{r}" for s, r in pairs if (s, r) not in listed]
        if missing:
            raise ValueError(f"{base}/maps: the service has no map for {', '.join(missing)} "
                             f"(it lists {', '.join(f'{s}/{r}' for s, r in listed) or 'none'})")
        return {pair: listed[pair] for pair in pairs}
    out = {}
    for server, room in pairs:
        fields = {"server": server, "tier": base_tier(server), "room": room, "room_index": list(rooms).index(room)}
        try:
            out[(server, room)] = url.format(**fields).rstrip("/")
        except (KeyError, IndexError, ValueError) as exc:
            raise ValueError(f"--server {url!r}: bad URL template ({exc!r}); placeholders: "
                             f"{', '.join('{' + f + '}' for f in URL_FIELDS)}") from None
    seen: dict[str, tuple[str, str]] = {}
    for pair, target in out.items():
        if target in seen:
            raise ValueError(f"--server {url!r} sends {seen[target][0]}/{seen[target][1]} and {pair[0]}/{pair[1]} "
                             f"to the same URL {target}: add {{server}} or {{room}} to the template")
        seen[target] = pair
    return out


def check_reachable(url: str, timeout: float = 10.0) -> None:
    """Fail early, before a study renders, when nothing answers at ``url`` (a ``--server`` URL or template): a
    :class:`~synthleak.errors.ServiceUnreachableError` naming it. Any HTTP answer to ``GET /health`` passes (a
    foreign service need not serve it); a template is checked at its host, unless the host is a placeholder."""
    if not url.startswith(("http://", "https://")):
        raise ValueError(f"--server {url}: not an http:// or https:// URL")
    probe = f"{url.rstrip('/')}/health"
    if is_url_template(url):
        scheme, rest = url.split("//", 1)
        host = rest.split("/", 1)[0]
        if is_url_template(host):
            return
        probe = f"{scheme}//{host}/health"
    try:
        httpx.get(probe, timeout=timeout)
    except httpx.TransportError as exc:
        raise ServiceUnreachableError(f"--server {url}: no service answers at {probe} ({_reason(exc)}); start it "
                                      "first, e.g. synthleak serve STUDY/maps (docs/service-protocol.md)") from exc
    except httpx.InvalidURL as exc:
        raise ValueError(f"--server {url}: not a URL ({exc})") from exc


def _reason(exc: Exception) -> str:
    return f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__


def list_maps(url: str, timeout: float = 10.0) -> list[dict] | None:
    """A service's ``GET <url>/maps`` (the maps it serves), or None when it answers 404 (a single-map service)."""
    response = httpx.get(f"{url.rstrip('/')}/maps", timeout=timeout)
    if response.status_code == 404:
        return None
    if response.status_code != 200:
        raise LocalizationServiceError(response.status_code, f"GET {url.rstrip('/')}/maps: {response.text}")
    maps = response.json()
    if not isinstance(maps, list) or not all(isinstance(m, dict) and {"server", "room"} <= m.keys()
                                             and ("path" in m or "url" in m) for m in maps):
        raise ValueError(f"GET {url.rstrip('/')}/maps: expected a JSON list of {{server, room, path or url}}")
    return maps
