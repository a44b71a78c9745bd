"""Contact sheet of a rendered sequence: one row per sampled frame, four panels.

``RGB | depth (turbo colour map, near = blue, + a scale bar in metres) | instance mask (fixed palette) |
RGB with each object's projected 3D box and id``. Boxes come from the BOP ground truth alone
(``bop/scene_gt.json`` cam_R_m2c / cam_t_m2c in mm, ``bop/scene_camera.json`` cam_K) and the extents of
``objects.json`` in the canonical frame (x in [-ex/2, ex/2], y in [-ey/2, ey/2], z in [0, ez]), so a box that
misses its object in the mask panel means the ground truth is wrong. Room-shell pieces get no box.
A photographed sequence (``[render] capture_*`` other than ``ideal``) keeps the render of the first photo of each
capture profile (``capture_render/``): the sheet ends with one row per such frame, ``render | photo (its profile)
| |photo - render| x 4 | photo with boxes``. Boxes of a distorted frame are drawn through its lens.
The sheet is ``rows * H`` pixels high and ``4 * W + BAR_W`` wide; drawing is OpenCV only (deterministic).
"""

from __future__ import annotations

import colorsys
from pathlib import Path

import cv2
import numpy as np

from synthleak.atomic_io import atomic_write_bytes
from synthleak.core.dataset import (
    RENDER_TWINS,
    DatasetError,
    Sequence,
    camera_dist_coeffs,
    encode_png,
    load_sequence,
    read_json,
    read_rgb,
)
from synthleak.geometry.poses import make_pose, transform_points
from synthleak.render.dataset import read_capture_records

BAR_W = 44
"""Width in pixels of the depth scale bar appended to the depth panel."""
NEAR = 1e-3
CLIP_NEAR = 0.05
"""Box edges are clipped to the part at least this far (metres) in front of the camera."""
_EDGES = ((0, 1), (1, 3), (3, 2), (2, 0), (4, 5), (5, 7), (7, 6), (6, 4), (0, 4), (1, 5), (2, 6), (3, 7))
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def id_colour(instance_id: int) -> tuple[int, int, int]:
    """Fixed palette colour (RGB uint8) of an instance id; 0 (background) is black."""
    iid = int(instance_id)
    if iid == 0:
        return (0, 0, 0)
    hue = (iid * 0.6180339887498949) % 1.0
    sat = 0.55 + 0.45 * ((iid * 0.3819660112501051) % 1.0)
    val = 0.75 + 0.25 * ((iid * 0.7548776662466927) % 1.0)
    r, g, b = colorsys.hsv_to_rgb(hue, sat, val)
    return (round(r * 255), round(g * 255), round(b * 255))


def instance_image(instance: np.ndarray) -> np.ndarray:
    """RGB rendering of a uint16 instance mask with :func:`id_colour`."""
    ids, inverse = np.unique(instance, return_inverse=True)
    lut = np.array([id_colour(int(i)) for i in ids], dtype=np.uint8)
    return lut[inverse.reshape(instance.shape)]


def find_sequence(path: Path, sequence: str | None = None) -> Path:
    """The sequence folder: ``path`` itself, or ``path/scenes/<s>`` / ``path/attackers/<s>`` of a dataset, or of a
    study folder's ``dataset/`` (``sequence`` by name or relative path; default: the first scene, else the first
    attacker sequence)."""
    path = Path(path)
    if not path.is_dir():
        raise DatasetError(f"{path}: no such folder (a dataset or a sequence folder, e.g. DATASET/scenes/room_000)")
    if (path / "dataset").is_dir() and not any((path / g).is_dir() for g in ("scenes", "attackers")):
        path = path / "dataset"  # a study folder: its dataset
    if (path / "colmap" / "images.txt").is_file() and sequence is None:
        return path
    if sequence is not None and (path / sequence / "colmap" / "images.txt").is_file():
        return path / sequence
    found = [
        p
        for group in ("scenes", "attackers")
        for p in sorted((path / group).glob("*"))
        if (p / "colmap" / "images.txt").is_file()
    ]
    if sequence is not None:
        found = [p for p in found if p.name == sequence]
    if not found:
        what = f"sequence {sequence!r}" if sequence else "rendered sequence (scenes/*, attackers/*)"
        names = sorted(p.name for g in ("scenes", "attackers") for p in (path / g).glob("*") if p.is_dir())
        raise DatasetError(f"{path}: no {what}; available: {names or 'none'}")
    return found[0]


def sample_frames(frames: list[str], n: int) -> list[str]:
    """``n`` frames evenly spread over the sequence (first and last included), in order."""
    if n < 1:
        raise ValueError(f"frames must be >= 1, got {n}")
    if len(frames) <= n:
        return list(frames)
    idx = np.unique(np.round(np.linspace(0, len(frames) - 1, n)).astype(int))
    return [frames[i] for i in idx]


def _bop(seq: Sequence) -> tuple[dict, dict]:
    return read_json(seq.root / "bop" / "scene_gt.json"), read_json(seq.root / "bop" / "scene_camera.json")


def box_corners(extents: np.ndarray) -> np.ndarray:
    """(8, 3) corners of the canonical box; index bits: x (1), y (2), z (4)."""
    ex, ey, ez = (float(e) for e in extents)
    bits = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
    return np.stack([(bits[:, 0] - 0.5) * ex, (bits[:, 1] - 0.5) * ey, bits[:, 2] * ez], axis=1)


def camera_boxes(seq: Sequence, frame: str | int, include_shell: bool = False) -> tuple[np.ndarray, dict]:
    """(K, ``{obj_id: (8, 3) box corners in the camera frame, metres}``) of ``frame`` from the BOP files."""
    scene_gt, scene_camera = _bop(seq)
    key = str(int(str(frame).removesuffix(".png"))) if not isinstance(frame, int) else str(frame)
    if key not in scene_gt or key not in scene_camera:
        raise DatasetError(f"{seq.root / 'bop'}: frame {key} not in scene_gt.json / scene_camera.json")
    k = np.asarray(scene_camera[key]["cam_K"], dtype=np.float64).reshape(3, 3)
    objects = {o.instance_id: o for o in seq.objects}
    boxes = {}
    for entry in scene_gt[key]:
        obj = objects.get(int(entry["obj_id"]))
        if obj is None or (obj.role == "shell" and not include_shell):
            continue
        pose = make_pose(
            np.asarray(entry["cam_R_m2c"], dtype=np.float64).reshape(3, 3),
            np.asarray(entry["cam_t_m2c"], dtype=np.float64) / 1000.0,
        )
        boxes[int(entry["obj_id"])] = transform_points(pose, box_corners(obj.extents))
    return k, boxes


def projected_boxes(seq: Sequence | Path, frame: str | int, include_shell: bool = False) -> dict[int, np.ndarray]:
    """``{obj_id: (8, 2) pixel coordinates}`` of each object's canonical 3D box in ``frame`` from the BOP
    ground truth; boxes with a corner behind the camera are left out. Pixel (u, v) has its centre at
    (u + 0.5, v + 0.5), so a box edge at x = 10.0 runs between pixel columns 9 and 10."""
    seq = seq if isinstance(seq, Sequence) else load_sequence(Path(seq))
    k, boxes = camera_boxes(seq, frame, include_shell)
    out = {}
    for obj_id, pts in boxes.items():
        if np.all(pts[:, 2] > NEAR):
            uvw = pts @ k.T
            out[obj_id] = uvw[:, :2] / uvw[:, 2:]
    return out


def box_segments(k: np.ndarray, corners: np.ndarray, near: float = CLIP_NEAR) -> list[np.ndarray]:
    """The box's 12 edges as (2, 2) pixel segments, each clipped to the part in front of ``near`` metres."""
    segments = []
    for a, b in _EDGES:
        p, q = corners[a].copy(), corners[b].copy()
        if p[2] < near and q[2] < near:
            continue
        if p[2] < near or q[2] < near:
            t = (near - p[2]) / (q[2] - p[2])
            cut = p + t * (q - p)
            p, q = (cut, q) if p[2] < near else (p, cut)
        uvw = np.stack([p, q]) @ k.T
        segments.append(uvw[:, :2] / uvw[:, 2:])
    return segments


def _text(image: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
    cv2.putText(image, text, org, _FONT, 0.32, (0, 0, 0), 2, cv2.LINE_AA)
    cv2.putText(image, text, org, _FONT, 0.32, colour, 1, cv2.LINE_AA)


def depth_image(depth: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """RGB turbo colour map of a z-depth over [lo, hi] metres; no hit (+inf) is black."""
    finite = np.isfinite(depth)
    t = np.zeros(depth.shape, dtype=np.uint8)
    t[finite] = np.round(255 * np.clip((depth[finite] - lo) / max(hi - lo, 1e-9), 0, 1)).astype(np.uint8)
    rgb = cv2.applyColorMap(t, cv2.COLORMAP_TURBO)[..., ::-1]
    rgb[~finite] = 0
    return np.ascontiguousarray(rgb)


def scale_bar(height: int, lo: float, hi: float) -> np.ndarray:
    """(height, BAR_W, 3) vertical colour bar (near at the top) with tick labels in metres."""
    bar = np.full((height, BAR_W, 3), 255, dtype=np.uint8)
    ramp = np.round(np.linspace(0, 255, height)).astype(np.uint8)[:, None]
    colours = cv2.applyColorMap(np.repeat(ramp, 10, axis=1), cv2.COLORMAP_TURBO)[..., ::-1]
    bar[:, 2:12] = colours
    for frac in (0.0, 0.5, 1.0):
        y = int(round(frac * (height - 1)))
        cv2.line(bar, (12, y), (15, y), (0, 0, 0), 1)
        ty = min(max(y + 4, 8), height - 2)
        cv2.putText(bar, f"{lo + frac * (hi - lo):.1f}m", (16, ty), _FONT, 0.28, (0, 0, 0), 1, cv2.LINE_AA)
    return bar


LENS_STEPS = 16
"""Pieces each box edge is drawn in through a distorting lens (a straight edge images as a curve)."""


def lens_segments(k: np.ndarray, dist: np.ndarray, corners: np.ndarray, near: float = CLIP_NEAR) -> list[np.ndarray]:
    """:func:`box_segments` through a lens with OpenCV ``dist`` coefficients: each clipped edge as
    :data:`LENS_STEPS` pieces, every point projected with ``cv2.projectPoints``."""
    pinhole = np.eye(3)
    out = []
    for seg in box_segments(pinhole, corners, near):
        ends = np.concatenate([seg, np.ones((2, 1))], axis=1)  # normalised image points of the clipped edge
        t = np.linspace(0.0, 1.0, LENS_STEPS + 1)[:, None]
        points = (1 - t) * ends[0] + t * ends[1]
        uv, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), k, dist)
        uv = uv.reshape(-1, 2)
        out.extend(uv[i:i + 2] for i in range(LENS_STEPS))
    return out


def box_overlay(rgb: np.ndarray, k: np.ndarray, boxes: dict[int, np.ndarray], dist: np.ndarray | None = None
                ) -> np.ndarray:
    """``rgb`` with each box (camera-frame corners) drawn as its 12 edges and its id, in the id's colour
    (``dist``: the frame's OpenCV distortion, the edges then drawn through the lens)."""
    out = np.ascontiguousarray(rgb.copy())
    shift = 4  # sub-pixel precision of cv2 drawing: coordinates * 16
    h, w = out.shape[:2]
    for obj_id in sorted(boxes):
        colour = id_colour(obj_id)
        segments = box_segments(k, boxes[obj_id]) if dist is None else lens_segments(k, dist, boxes[obj_id])
        for seg in segments:
            pts = np.round((np.clip(seg, -8 * max(h, w), 8 * max(h, w)) - 0.5) * (1 << shift)).astype(np.int64)
            cv2.line(
                out, (int(pts[0, 0]), int(pts[0, 1])), (int(pts[1, 0]), int(pts[1, 1])), colour, 1, cv2.LINE_8, shift
            )
        if not segments:
            continue
        ends = np.concatenate(segments)
        inside = ends[(ends[:, 0] >= 0) & (ends[:, 0] < w) & (ends[:, 1] >= 0) & (ends[:, 1] < h)]
        if len(inside):
            top = inside[np.argmin(inside[:, 1])]
            _text(out, str(obj_id), (int(np.clip(top[0], 0, w - 20)), int(np.clip(top[1] - 2, 8, h - 2))), colour)
    return out


def sheet_rows(seq: Sequence, frames: list[str]) -> list[np.ndarray]:
    """One (H, 4W + BAR_W, 3) row per frame."""
    depths = {f: seq.depth(f) for f in frames}
    finite = np.concatenate([d[np.isfinite(d)] for d in depths.values()] + [np.zeros(0, np.float32)])
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    rows = []
    for f in frames:
        rgb = seq.rgb(f)
        depth_panel = np.concatenate([depth_image(depths[f], lo, hi), scale_bar(rgb.shape[0], lo, hi)], axis=1)
        labelled = np.ascontiguousarray(rgb.copy())
        _text(labelled, f.removesuffix(".png"), (2, 10), (255, 255, 255))
        boxes = box_overlay(rgb, *camera_boxes(seq, f), camera_dist_coeffs(seq.camera_of(f)))
        rows.append(np.concatenate([labelled, depth_panel, instance_image(seq.instance(f)), boxes], axis=1))
    return rows


def twin_rows(seq: Sequence) -> list[np.ndarray]:
    """One row per kept render (``capture_render/<frame>.png``): render, photo, their difference x 4 and the photo
    with its boxes, padded to the width of a :func:`sheet_rows` row."""
    records = read_capture_records(seq.root)
    rows = []
    for path in sorted((seq.root / RENDER_TWINS).glob("*.png")):
        f = path.name
        photo = seq.rgb(f)
        h, w = photo.shape[:2]
        render = read_rgb(path)
        if render.shape[:2] != (h, w):  # a resized photo: the render shown at the photo's size
            render = cv2.resize(render, (w, h), interpolation=cv2.INTER_AREA)
        diff = np.clip(4 * np.abs(photo.astype(np.int16) - render.astype(np.int16)), 0, 255).astype(np.uint8)
        render, labelled = np.ascontiguousarray(render.copy()), np.ascontiguousarray(photo.copy())
        _text(render, f"{path.stem} render", (2, 10), (255, 255, 255))
        _text(labelled, f"{path.stem} {records.get(f, {}).get('profile', 'photo')}", (2, 10), (255, 255, 255))
        _text(diff, "|photo - render| x 4", (2, 10), (255, 255, 255))
        boxes = box_overlay(photo, *camera_boxes(seq, f), camera_dist_coeffs(seq.camera_of(f)))
        pad = np.full((h, BAR_W, 3), 255, dtype=np.uint8)
        rows.append(np.concatenate([render, labelled, diff, boxes, pad], axis=1))
    return rows


def contact_sheet(dataset_or_sequence_dir: Path, out: Path, sequence: str | None = None, frames: int = 4) -> Path:
    """Write the contact sheet PNG of one sequence (see the module docstring) to ``out``; returns ``out``."""
    seq = load_sequence(find_sequence(Path(dataset_or_sequence_dir), sequence))
    if not seq.frames:
        raise DatasetError(f"{seq.root}: the sequence has no frames")
    sheet = np.concatenate(sheet_rows(seq, sample_frames(seq.frames, frames)) + twin_rows(seq), axis=0)
    out = Path(out)
    atomic_write_bytes(out, encode_png(sheet))
    return out
