"""Camera motion blur without re-rendering: a depth-aware reprojection blur over the shutter time.

A photo integrates the image over its exposure ``[-T/2, T/2]`` (T: the shutter time the auto-exposure chose)
while the camera turns (hand shake, angular velocity in deg/s) and moves (the trajectory's velocity, where the
pipeline knows it). :func:`apply_motion_blur` averages N sub-exposure images, each the frame warped to the pose
at time t: for every output pixel q its ray in the camera at t is taken back to the mid-exposure camera,
``p = K (R(t) K^-1 q + v t / z(q))`` (R(t) = exp([omega t]x), v the velocity, z the ground-truth z-depth
at q; a point at infinity moves by the rotation only), and the frame is sampled there (``cv2.remap``, bilinear,
border replicated). The rotation part is exact (a homography, depth-independent); the translation part uses
the mid-exposure depth at q for the depth at q in the camera at t (first order in the motion; parallax at
occlusion edges is not modelled: an occluded surface cannot be sampled from one frame). With no translation
the remap maps are the homographies ``K R(t) K^-1`` (``cv2.warpPerspective``, same result, faster).

The pose ground truth is the **mid-exposure** pose (t = 0): the rendered frame, its depth, instance ids and
every pose file are those of the camera halfway through the exposure, and the blur is symmetric around it.
Depth and masks are not blurred.

Hand-shake speeds: the photographers' reciprocal rule (a hand-held shutter of 1 / f s, f the 35 mm-equivalent
focal length in mm, keeps blur under the 0.03 mm circle of confusion of a 36 mm frame) implies an angular
speed of ``0.03 mm / f * f rad/s = 0.03 rad/s ~ 1.7 deg/s`` for an unstabilised hand; optical image
stabilisation removes most of it (2-4 stops is what makers claim). The profiles' ranges in
:mod:`synthleak.render.devices` are *assumed* around these figures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import cv2
import numpy as np

from synthleak.errors import ConfigError
from synthleak.portable import inv3, matmul

if TYPE_CHECKING:
    from synthleak.core.types import Camera
    from synthleak.render.capture import CaptureParams

ROLL_SHARE = 0.5
"""Hand shake turns a camera about its optical axis (roll) about half as fast as in pitch and yaw (assumed)."""


def _check_vector(name: str, value: object) -> None:
    ok = isinstance(value, tuple | list) and len(value) == 3 and all(
        isinstance(v, int | float) and math.isfinite(v) for v in value
    )
    if not ok:
        raise ConfigError(f"capture parameter motion_blur.{name}: must be 3 finite numbers, got {value!r}")


@dataclass(frozen=True)
class MotionBlur:
    """The camera's motion during one exposure (camera frame: +x right, +y down, +z forward) and how finely it
    is sampled. The blur length follows the shutter time: the exposure stage's choice (``record["shutter_s"]``)
    or ``shutter_s`` when the capture has no exposure stage. The GT pose is the mid-exposure pose."""

    angular_velocity_deg_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Angular velocity (deg/s) about the camera's x (pitch), y (yaw), z (roll) axes: hand shake (drawn per
    photo by ``devices.draw_device``) plus the trajectory's turning rate where known."""
    velocity_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Translational velocity (m/s) of the camera in its own frame (the trajectory's, where known)."""
    shutter_s: float = 1.0 / 30.0
    """Shutter time (s) used when the capture has no exposure stage to choose one."""
    max_samples: int = 16
    """Most sub-exposure samples N (the cost is about 2 ms per sample at 640x480)."""
    sample_spacing_px: float = 1.0
    """Samples are spaced at most this far (px) along the longest flow, within ``max_samples``."""
    min_blur_px: float = 0.05
    """Blur extents below this (px) leave the frame untouched."""
    SECTION: ClassVar[str] = "motion_blur"

    def __post_init__(self) -> None:
        _check_vector("angular_velocity_deg_s", self.angular_velocity_deg_s)
        _check_vector("velocity_m_s", self.velocity_m_s)
        for name in ("shutter_s", "sample_spacing_px", "min_blur_px"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ConfigError(f"capture parameter motion_blur.{name}: must be a finite number > 0, got {value!r}")
        if not isinstance(self.max_samples, int) or not 2 <= self.max_samples <= 256:
            raise ConfigError(f"capture parameter motion_blur.max_samples: must be an integer in [2, 256], "
                              f"got {self.max_samples!r}")

    @property
    def has_translation(self) -> bool:
        return any(v != 0.0 for v in self.velocity_m_s)


def hand_shake(speed_deg_s: float, normals: np.ndarray) -> tuple[float, float, float]:
    """One photo's hand-shake angular velocity (deg/s): ``speed * (z0, z1, ROLL_SHARE * z2)`` for standard
    normals z clipped at 2.5 (``speed`` is the RMS pitch / yaw rate)."""
    z = np.clip(np.asarray(normals, dtype=np.float64)[:3], -2.5, 2.5)
    return (float(speed_deg_s * z[0]), float(speed_deg_s * z[1]), float(speed_deg_s * ROLL_SHARE * z[2]))


def _intrinsics(camera: Camera | None, params: CaptureParams, width: int, height: int
                ) -> tuple[float, float, float, float]:
    if camera is not None:
        if (int(camera.width), int(camera.height)) != (width, height):
            raise ValueError(f"capture: camera is {camera.width}x{camera.height}, the frame {width}x{height}")
        return float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)
    if params.defocus is not None:  # the lens's own field of view (Defocus asks for consistent intrinsics)
        f = params.defocus.focal_length_mm / params.defocus.sensor_width_mm * width
        return f, f, width / 2.0, height / 2.0
    raise ConfigError("capture parameter motion_blur: needs the camera intrinsics (camera=None given and no "
                      "defocus lens to derive them from)")


class _Flow:
    """Sub-exposure sampling maps of one frame: pixel-centre rays, inverse depth, intrinsics."""

    def __init__(self, shape: tuple[int, int], fx: float, fy: float, cx: float, cy: float,
                 depth: np.ndarray | None, blur: MotionBlur, step: int = 1) -> None:
        h, w = shape
        self.shape, self.step, self.blur = (h, w), step, blur
        self.K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        self.omega = np.radians(np.asarray(blur.angular_velocity_deg_s, dtype=np.float64))
        self.v = np.asarray(blur.velocity_m_s, dtype=np.float64)
        u = (np.arange(0, w, step, dtype=np.float32) + 0.5 - np.float32(cx)) / np.float32(fx)
        vv = (np.arange(0, h, step, dtype=np.float32) + 0.5 - np.float32(cy)) / np.float32(fy)
        self.rx, self.ry = np.meshgrid(u, vv)
        self.invz = None
        if blur.has_translation:
            if depth is None:
                raise ConfigError("capture parameter motion_blur: a moving camera (velocity_m_s) needs the frame's "
                                  "depth map (depth=None given)")
            z = np.asarray(depth, dtype=np.float32)[::step, ::step]
            with np.errstate(divide="ignore", invalid="ignore"):
                invz = np.where(np.isfinite(z) & (z > 0), np.float32(1.0) / z, np.float32(0.0))
            self.invz = invz.astype(np.float32)

    def rotation(self, t: float) -> np.ndarray:
        """R(t): cam_mid_from_cam_t rotation, ``exp([omega t]x)`` (Rodrigues)."""
        return cv2.Rodrigues((self.omega * t).reshape(3, 1))[0]

    def homography(self, t: float) -> np.ndarray:
        """Index-coordinate homography taking an output pixel at time t to its mid-exposure source."""
        to_centre = np.array([[1.0, 0.0, 0.5], [0.0, 1.0, 0.5], [0.0, 0.0, 1.0]])
        h = matmul(matmul(self.K, self.rotation(t)), inv3(self.K))  # Python floats: the same bits on every CPU
        return matmul(matmul(inv3(to_centre), h), to_centre)

    def maps(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(map_x, map_y) float32 source index coordinates of every (sub-sampled) output pixel at time t."""
        r = self.rotation(t).astype(np.float32)
        px = r[0, 0] * self.rx + r[0, 1] * self.ry + r[0, 2]
        py = r[1, 0] * self.rx + r[1, 1] * self.ry + r[1, 2]
        pz = r[2, 0] * self.rx + r[2, 1] * self.ry + r[2, 2]
        if self.invz is not None:
            vt = (self.v * t).astype(np.float32)
            px, py, pz = px + vt[0] * self.invz, py + vt[1] * self.invz, pz + vt[2] * self.invz
        pz = np.maximum(pz, np.float32(1e-6))  # behind the camera: never for the small motions here
        k = self.K.astype(np.float32)
        map_x = k[0, 0] * px / pz + k[0, 2] - np.float32(0.5)
        map_y = k[1, 1] * py / pz + k[1, 2] - np.float32(0.5)
        return map_x, map_y

    def extent_px(self, shutter_s: float) -> float:
        """Longest path (px) any (sub-sampled) pixel's source travels over the exposure: the blur length."""
        ax, ay = self.maps(-shutter_s / 2.0)
        bx, by = self.maps(shutter_s / 2.0)
        return float(np.sqrt((bx - ax) ** 2 + (by - ay) ** 2).max()) if ax.size else 0.0


def apply_motion_blur(x: np.ndarray, blur: MotionBlur, shutter_s: float, intrinsics: tuple[float, float, float, float],
                      depth: np.ndarray | None = None) -> tuple[np.ndarray, dict[str, Any]]:
    """Average of N sub-exposure warps of linear image ``x`` (H, W, 3) over ``[-shutter_s/2, shutter_s/2]``
    around the mid-exposure pose (module docstring). ``intrinsics`` = (fx, fy, cx, cy), pixel-centre convention.
    Returns the image (``x`` itself when the blur is under ``min_blur_px``) and a record: blur length in px, N,
    shutter. Deterministic (no random draws)."""
    h, w = x.shape[:2]
    if not (math.isfinite(shutter_s) and shutter_s >= 0):
        raise ValueError(f"motion blur: shutter time must be finite and >= 0, got {shutter_s}")
    if depth is not None and np.shape(depth) != (h, w):
        raise ValueError(f"capture: depth must be (H, W) = {(h, w)}, got {np.shape(depth)}")
    fx, fy, cx, cy = intrinsics
    coarse = _Flow((h, w), fx, fy, cx, cy, depth, blur, step=8)
    length = coarse.extent_px(shutter_s)
    record: dict[str, Any] = {
        "motion_blur_px": length, "motion_blur_shutter_s": float(shutter_s),
        "motion_blur_angular_velocity_deg_s": [float(v) for v in blur.angular_velocity_deg_s],
        "motion_blur_velocity_m_s": [float(v) for v in blur.velocity_m_s],
    }  # fmt: skip
    if length < blur.min_blur_px:
        record["motion_blur_samples"] = 1
        return x, record
    n = int(min(max(math.ceil(length / blur.sample_spacing_px) + 1, 2), blur.max_samples))
    record["motion_blur_samples"] = n
    src = np.ascontiguousarray(x, dtype=np.float32)
    acc = np.zeros_like(src)
    flow = _Flow((h, w), fx, fy, cx, cy, depth, blur) if blur.has_translation else coarse
    for k in range(n):
        t = ((k + 0.5) / n - 0.5) * shutter_s
        if blur.has_translation:
            map_x, map_y = flow.maps(t)
            acc += cv2.remap(src, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        else:  # pure rotation: the maps are a homography
            acc += cv2.warpPerspective(src, flow.homography(t), (w, h), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                                       borderMode=cv2.BORDER_REPLICATE)
    return acc * np.float32(1.0 / n), record


def motion_blur_stage(x: np.ndarray, depth: np.ndarray | None, params: CaptureParams, camera: Camera | None
                      ) -> tuple[np.ndarray, dict[str, Any]]:
    """The capture stage: the shutter time the auto-exposure chooses on the unblurred irradiance (with the
    profile's vignetting; as a camera meters its preview), then :func:`apply_motion_blur`. The exposure stage
    meters the blurred image again; a mean-preserving blur of a few pixels leaves its median, and so its
    shutter time, the same but for rounding, and a shutter at the hand-held limit (the common indoor case)
    exactly. Returns the image and the record (``motion_blur_shutter_s``: the time blurred over)."""
    from synthleak.render.capture import choose_exposure, meter, vignetting_map

    blur = params.motion_blur
    assert blur is not None
    h, w = x.shape[:2]
    shutter = blur.shutter_s
    if params.exposure is not None:
        seen = x if params.vignetting is None else x * vignetting_map(h, w, params.vignetting.corner_stops)
        shutter = choose_exposure(meter(seen), params.exposure, params.base_iso)["shutter_s"]
    return apply_motion_blur(x, blur, shutter, _intrinsics(camera, params, w, h), depth)
