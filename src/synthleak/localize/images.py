"""Query images: decoding (8- and 16-bit), a pixel limit checked from the header before decoding, and
downscaling with scaled intrinsics.

A query's cost is bounded in two steps. The header gives the size before any pixel is decoded: more than
``max_pixels`` (:data:`MAX_QUERY_PIXELS`, 25 MP: a 24 MP camera's 6000x4000 photo passes) is refused, so a
small file that declares a huge image (a 105 KB PNG of 6000x6000 black pixels) costs a header read. A
decoded image with more pixels than the map's images is downscaled to their pixel count, with its
intrinsics scaled to match (:func:`fit_to_pixels`): feature extraction, the expensive step, then costs what a
map image costs, and a high-resolution photo still localizes (its pose is that of the same camera).
"""

from __future__ import annotations

import io
import math
import struct

import cv2
import numpy as np
from PIL import Image

from synthleak.core.dataset import scaled_camera
from synthleak.core.types import Camera
from synthleak.errors import SynthleakError

MAX_QUERY_PIXELS = 25_000_000
"""Largest query image (width x height) that is decoded at all."""

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


class InvalidImageError(SynthleakError, ValueError):
    """Query image bytes/array that cannot be used."""


class ImageTooLargeError(InvalidImageError):
    """The image header declares more pixels than the limit (nothing was decoded)."""


def read_size(data: bytes, max_pixels: int = MAX_QUERY_PIXELS) -> tuple[int, int]:
    """(width, height) from the encoded image's header, without decoding pixels.

    Raises :class:`InvalidImageError` for bytes that are not an image and :class:`ImageTooLargeError` for
    more than ``max_pixels``."""
    with _open(data) as im:
        return _check_pixels(im.size, max_pixels)


def _open(data: bytes) -> Image.Image:
    if not len(data):
        raise InvalidImageError("empty image")
    try:
        return Image.open(io.BytesIO(bytes(data)))  # lazy: reads the header only
    except Image.DecompressionBombError as exc:
        raise ImageTooLargeError(f"image has too many pixels ({exc})") from exc
    except (OSError, ValueError) as exc:
        raise InvalidImageError(f"not a decodable image ({exc.__class__.__name__})") from exc


def _check_pixels(size: tuple[int, int], max_pixels: int) -> tuple[int, int]:
    width, height = (int(v) for v in size)
    if width * height > max_pixels:
        raise ImageTooLargeError(f"image is {width}x{height} ({width * height:,} pixels); "
                                 f"at most {max_pixels:,} pixels are accepted")
    return width, height


def _png_bit_depth(data: bytes) -> int | None:
    """Bits per sample from a PNG's IHDR chunk (None for other formats)."""
    if len(data) < 25 or data[:8] != _PNG_SIGNATURE or data[12:16] != b"IHDR":
        return None
    return struct.unpack("B", data[24:25])[0]


def scale_16_to_8(values: np.ndarray) -> np.ndarray:
    """uint8 from 16-bit samples: 0..65535 onto 0..255, rounded to nearest (``v / 257``; no sample lies
    within 0.002 of a rounding tie, so float arithmetic rounds exactly). No wide temporary copy."""
    values = np.asarray(values)
    if values.dtype != np.uint16:  # Pillow's 32-bit integer grey
        values = np.clip(values, 0, 65535).astype(np.uint16)
    return cv2.convertScaleAbs(values, alpha=1.0 / 257.0)


def _rgb_from_array(arr: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 from grey (H, W) or (H, W, 1|2|3|4) uint8 channels (alpha dropped)."""
    if arr.ndim == 2:
        arr = arr[..., None]
    if arr.ndim != 3 or arr.shape[2] not in (1, 2, 3, 4):
        raise InvalidImageError(f"image array must be (H, W[, 1|2|3|4]), got shape {arr.shape}")
    if arr.shape[2] <= 2:  # grey or grey + alpha
        arr = np.repeat(arr[..., :1], 3, axis=2)
    return np.ascontiguousarray(arr[..., :3])


def _decode_16bit_png(data: bytes) -> np.ndarray:
    """A 16-bit PNG at full precision (OpenCV keeps 16 bits; Pillow reads 16-bit RGB as 8-bit truncated and
    16-bit grey as 32-bit integers that ``convert("RGB")`` clips to white), scaled to 8 bits."""
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None:
        raise InvalidImageError("not a decodable image (16-bit PNG)")
    if arr.ndim == 3 and arr.shape[2] >= 3:  # OpenCV's BGR(A) -> RGB(A)
        arr = arr[..., [2, 1, 0, *range(3, arr.shape[2])]]
    return _rgb_from_array(scale_16_to_8(arr) if arr.dtype == np.uint16 else arr.astype(np.uint8))


def decode_image(image: np.ndarray | bytes, max_pixels: int = MAX_QUERY_PIXELS) -> np.ndarray:
    """(H, W, 3) uint8 RGB from an array (grey, RGB or RGBA, uint8 or uint16) or encoded bytes (PNG, JPEG,
    ...; 8 or 16 bits per sample, 16-bit samples scaled to 8 bits). Encoded images are checked against
    ``max_pixels`` from their header before decoding."""
    if isinstance(image, bytes | bytearray | memoryview):
        data = bytes(image)
        with _open(data) as im:
            _check_pixels(im.size, max_pixels)
            if _png_bit_depth(data) == 16:
                return _decode_16bit_png(data)
            try:
                im.load()
                if im.mode == "I" or im.mode.startswith("I;16"):  # 16-bit grey (TIFF, PGM, ...)
                    return _rgb_from_array(scale_16_to_8(np.asarray(im)))
                return np.asarray(im if im.mode == "RGB" else im.convert("RGB"))
            except (OSError, ValueError, Image.DecompressionBombError) as exc:
                raise InvalidImageError(f"not a decodable image ({exc.__class__.__name__})") from exc
    arr = np.asarray(image)
    if arr.dtype == np.uint16:
        arr = scale_16_to_8(arr)
    if arr.dtype != np.uint8:
        raise InvalidImageError(f"image array must be uint8 or uint16, got {arr.dtype}")
    if arr.ndim == 3 and arr.shape[2] not in (3, 4):
        raise InvalidImageError(f"image array must be (H, W[, 3|4]), got shape {arr.shape}")
    return _rgb_from_array(arr)


def fit_to_pixels(rgb: np.ndarray, camera: Camera, max_pixels: int) -> tuple[np.ndarray, Camera]:
    """``rgb`` and ``camera`` unchanged if the image has at most ``max_pixels``; otherwise the image
    downscaled (area averaging) to about ``max_pixels`` with the same aspect ratio, and the camera's
    intrinsics scaled by the same per-axis factors (corners map to corners: ``u' = u * W' / W`` in the
    pixel-corner convention of :class:`Camera`, so ``fx``, ``cx`` scale by ``W' / W``)."""
    height, width = rgb.shape[:2]
    if width * height <= max_pixels:
        return rgb, camera
    factor = math.sqrt(max_pixels / (width * height))
    new_w, new_h = max(1, int(width * factor)), max(1, int(height * factor))
    small = cv2.resize(rgb, (new_w, new_h), interpolation=cv2.INTER_AREA)
    return small, scaled_camera(camera, new_w, new_h)  # a lens distortion (normalised coordinates) is kept
