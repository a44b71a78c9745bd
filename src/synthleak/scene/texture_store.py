"""Content-addressed PNG textures next to a stage: ``textures/<sha256-prefix>.png``.

The file name is the SHA-256 of the pixel content (shape + raw bytes), so it does not depend on the zlib
version; the PNG itself is written with fixed settings (no metadata, zlib level 1: noisy procedural textures
gain little from higher levels, which cost 4x the time), so the bytes are stable for a given Pillow/zlib
build. Identical textures are written once.
"""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

import numpy as np
from PIL import Image

TEXTURE_DIR = "textures"
_PREFIX = 16


def texture_key(texture: np.ndarray) -> str:
    """Content hash (16 hex digits) of an (H, W, 3) uint8 texture."""
    arr = np.ascontiguousarray(texture, dtype=np.uint8)
    if arr.ndim != 3 or arr.shape[2] not in (3, 4):
        raise ValueError(f"texture: expected an (H, W, 3) uint8 array, got shape {arr.shape}")
    digest = hashlib.sha256(f"{arr.shape}".encode() + arr.tobytes()).hexdigest()
    return digest[:_PREFIX]


def encode_png(texture: np.ndarray) -> bytes:
    """PNG bytes with fixed settings (compression level 1, no optimisation, no text chunks)."""
    arr = np.ascontiguousarray(texture, dtype=np.uint8)
    mode = "RGB" if arr.shape[2] == 3 else "RGBA"
    buf = io.BytesIO()
    Image.fromarray(arr, mode=mode).save(buf, format="PNG", compress_level=1, optimize=False)
    return buf.getvalue()


def store_texture(texture: np.ndarray, stage_dir: Path) -> str:
    """Write ``texture`` under ``stage_dir/textures/`` (once) and return its stage-relative asset path."""
    key = texture_key(texture)
    rel = f"./{TEXTURE_DIR}/{key}.png"
    path = stage_dir / TEXTURE_DIR / f"{key}.png"
    if not path.is_file():
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".png.tmp")
        tmp.write_bytes(encode_png(texture))
        tmp.replace(path)
    return rel

