"""A camera capture model: a renderer's linear radiance in, a photograph (uint8 sRGB) out.

Renders are too clean for the attack's matchers (see ``../shared/capture-references.md``): real photos are
exposed by a meter, white-balanced by a guess, noisy in raw space, demosaicked, tone-mapped, vignetted, out
of focus away from the focus plane, JPEG-compressed and resized. :func:`capture` applies these effects, in
physical order, to one frame; every effect is a dataclass field of :class:`CaptureParams` with physical
units and is off when ``None``. Everything is vectorised numpy/OpenCV; every random draw comes from
``numpy.random.default_rng(seed)`` in a fixed order, so the same seed gives the same bytes.

Input: ``linear_rgb`` float (H, W, 3), linear radiance in the renderer's linear sRGB (Rec. 709 primaries,
D65 white) where 1.0 is the white that today's 8-bit encoding clips at
(:func:`synthleak.render.mitsuba_backend.linear_to_srgb_uint8`, also used by the Blender backend).
mitsuba and Blender compute this linear image before they encode it. pyrender does not: its shader writes
``clamp(pow(c, 1/2.2))`` and OpenGL rounds that to 8 bits, so its frames are linearised with
:func:`gamma22_to_linear` (``(v / 255) ** 2.2``). Highlights above 1.0 are already clipped there, and the
shadows carry 8-bit banding that the noise model then treats as signal.

Order (:func:`capture`): optics (defocus, motion blur, lens distortion,
vignetting) -> auto-exposure (meters the irradiance the sensor sees, chooses shutter and ISO) -> sensor
(colour filter response, RGGB Bayer mosaic, Poisson-Gaussian noise, black level, ADC) -> ISP (demosaic,
white balance with the camera's illuminant estimate, colour correction matrix, tone curve, sRGB encoding)
-> in-camera JPEG -> resize (as an uploader does) -> re-compression. Motion blur
(:mod:`synthleak.render.motion_blur`) warps the frame along the camera's motion over the shutter time the
auto-exposure chooses, from the GT depth; the ground truth is the mid-exposure pose. Lens distortion and
resize change the geometry: the photo's camera is :func:`output_camera` (an ``OPENCV`` camera after distortion,
scaled after resize; geometry in :mod:`synthleak.render.distortion`), and the pipeline ray casts the ground
truth for it.

With every effect off (``devices.IDEAL``) the output is exactly ``linear_to_srgb_uint8(linear_rgb)``,
the pipeline's current encoding, byte for byte.
"""

from __future__ import annotations

import functools
import io
import math
import time
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import cv2
import numpy as np
from PIL import Image

from synthleak.core.types import Camera
from synthleak.errors import ConfigError
from synthleak.portable import apply_matrix3, inv3, matmul, snap
from synthleak.render.motion_blur import MotionBlur

CAPTURE_FORMAT = 2
"""Version of the photographs for the same seed and profile: part of a study's render key when a capture is not
``ideal`` (2: CPU-independent arithmetic and the ISP's noise reduction, 38edff6)."""

# --------------------------------------------------------------------------------------------- colour science

RGB_TO_XYZ = np.array(
    [[0.4124564, 0.3575761, 0.1804375], [0.2126729, 0.7151522, 0.0721750], [0.0193339, 0.1191920, 0.9503041]]
)
"""Linear sRGB (D65) -> CIE XYZ (IEC 61966-2-1)."""
XYZ_TO_RGB = inv3(RGB_TO_XYZ)
LUMA = np.array([0.2126729, 0.7151522, 0.0721750], dtype=np.float32)
"""Relative luminance Y of linear sRGB (row 2 of :data:`RGB_TO_XYZ`)."""

XYZ_TO_CAM_BROOKS = (
    ((1.0234, -0.2969, -0.2266), (-0.5625, 1.6328, -0.0469), (-0.0703, 0.2188, 0.6406)),
    ((0.4913, -0.0541, -0.0202), (-0.6130, 1.3513, 0.2906), (-0.1564, 0.2151, 0.7183)),
    ((0.8380, -0.2630, -0.0639), (-0.2887, 1.0725, 0.2496), (-0.0627, 0.1427, 0.5438)),
    ((0.6596, -0.2079, -0.0562), (-0.4782, 1.3016, 0.1933), (-0.0970, 0.1581, 0.5181)),
)
"""The four XYZ -> camera-RGB matrices (DSLRs of the Darmstadt Noise Dataset) of Brooks et al. 2019,
"Unprocessing Images for Learned Raw Denoising" (CVPR), whose unprocessing samples a random convex
combination of them (:func:`synthleak.render.devices.draw_device` does the same)."""

PLANCKIAN_RANGE_K = (1667.0, 25000.0)
"""Validity range of :func:`planckian_xy` (Kim et al. 2002)."""


def planckian_xy(temperature_k: float) -> tuple[float, float]:
    """CIE 1931 (x, y) of a black body at ``temperature_k`` from the cubic-spline approximation of the
    Planckian locus by Kim et al. 2002, "Design of advanced color temperature control system for HDTV
    applications", J. Korean Physical Society 41(6) 865-871 (valid 1667-25000 K)."""
    t = float(temperature_k)
    lo, hi = PLANCKIAN_RANGE_K
    if not lo <= t <= hi:
        raise ConfigError(f"capture: colour temperature {t} K is outside the Planckian fit's {lo:g}-{hi:g} K")
    if t <= 4000.0:
        x = -0.2661239e9 / t**3 - 0.2343589e6 / t**2 + 0.8776956e3 / t + 0.179910
    else:
        x = -3.0258469e9 / t**3 + 2.1070379e6 / t**2 + 0.2226347e3 / t + 0.240390
    if t <= 2222.0:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif t <= 4000.0:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


def planckian_rgb(temperature_k: float) -> np.ndarray:
    """Linear sRGB of a black body's white at ``temperature_k`` (Y = 1 in XYZ, then scaled to G = 1)."""
    x, y = planckian_xy(temperature_k)
    rgb = matmul(XYZ_TO_RGB, np.array([x / y, 1.0, (1.0 - x - y) / y]))
    return rgb / rgb[1]


def rgb_to_cam_matrix(xyz_to_cam: np.ndarray) -> np.ndarray:
    """linear sRGB -> camera RGB for an XYZ -> camera matrix, rows normalised so that sRGB white maps to
    camera white (Brooks et al. 2019, ``random_ccm``)."""
    m = matmul(np.asarray(xyz_to_cam, dtype=np.float64), RGB_TO_XYZ)
    return m / m.sum(axis=1, keepdims=True)


def mired(temperature_k: float) -> float:
    """Micro reciprocal degrees: 1e6 / T. Equal steps in mired are roughly equal perceived colour shifts."""
    return 1e6 / float(temperature_k)


# ------------------------------------------------------------------------------------------------ parameters


def _fail(section: str, name: str, rule: str, value: object) -> None:
    raise ConfigError(f"capture parameter {section}.{name}: {rule}, got {value!r}")


def _positive(section: str, **values: float | None) -> None:
    for name, value in values.items():
        if value is not None and not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
            _fail(section, name, "must be a finite number > 0", value)


def _in_range(section: str, name: str, value: float, lo: float, hi: float) -> None:
    if not (isinstance(value, int | float) and math.isfinite(value) and lo <= value <= hi):
        _fail(section, name, f"must be in [{lo:g}, {hi:g}]", value)


@dataclass(frozen=True)
class Defocus:
    """Thin-lens defocus from the z-depth map: circle of confusion (diameter on the sensor)
    ``c = (f / N) * f * |z - s| / (z * (s - f))`` for focal length f, f-number N, focus distance s and
    depth z (e.g. Potmesil & Chakravarty 1981, "A lens and aperture camera model for synthetic image
    generation"), blurred with a disc of that diameter in pixels (layered: see :func:`apply_defocus`)."""

    f_number: float
    """Aperture f-number N (dimensionless; the entrance pupil is f / N wide)."""
    focal_length_mm: float
    """Real (not 35 mm-equivalent) focal length in mm."""
    sensor_width_mm: float
    """Sensor width in mm: the pixel pitch is ``sensor_width_mm / image width``. Keep it consistent with the
    camera intrinsics: ``fx = focal_length_mm / sensor_width_mm * W``."""
    focus_distance_m: float | None = None
    """Focus distance in m (z-depth of the sharp plane); ``None``: autofocus on the median finite z-depth of
    the central fifth of the frame."""
    max_blur_px: float = 32.0
    """Largest disc diameter in px (a cap on the layer stack)."""
    SECTION: ClassVar[str] = "defocus"

    def __post_init__(self) -> None:
        _positive(self.SECTION, f_number=self.f_number, focal_length_mm=self.focal_length_mm,
                  sensor_width_mm=self.sensor_width_mm, focus_distance_m=self.focus_distance_m,
                  max_blur_px=self.max_blur_px)  # fmt: skip
        if self.focus_distance_m is not None and self.focus_distance_m * 1000.0 <= self.focal_length_mm:
            _fail(self.SECTION, "focus_distance_m", "must be beyond the focal length", self.focus_distance_m)


@dataclass(frozen=True)
class Distortion:
    """Lens distortion, OpenCV's radial-tangential (Brown-Conrady) model = COLMAP's ``OPENCV`` camera
    (``FULL_OPENCV`` with k3): normalised camera coordinates (x, y) -> ``x (1 + k1 r^2 + k2 r^4 + k3 r^6) +
    2 p1 x y + p2 (r^2 + 2 x^2)`` and y alike (Brown 1966, "Decentering distortion of lenses"). Plain
    coefficients on normalised coordinates (independent of resolution). The render is resampled into the
    distorted photo (:func:`synthleak.render.distortion.distorted_camera`); a radial map that folds inside the
    frame is refused once the camera is known (:func:`output_camera`)."""

    k1: float = 0.0
    """r^2 radial coefficient (< 0: barrel, > 0: pincushion)."""
    k2: float = 0.0
    """r^4 radial coefficient."""
    p1: float = 0.0
    """Tangential (decentering) coefficient."""
    p2: float = 0.0
    """Tangential (decentering) coefficient."""
    k3: float = 0.0
    """r^6 radial coefficient (not 0: written as COLMAP ``FULL_OPENCV``)."""
    SECTION: ClassVar[str] = "distortion"

    def __post_init__(self) -> None:
        for name, bound in (("k1", 1.0), ("k2", 1.0), ("p1", 0.05), ("p2", 0.05), ("k3", 1.0)):
            _in_range(self.SECTION, name, getattr(self, name), -bound, bound)

    @property
    def coeffs(self) -> np.ndarray:
        """OpenCV ``distCoeffs`` ``[k1, k2, p1, p2, k3]``."""
        return np.array([self.k1, self.k2, self.p1, self.p2, self.k3], dtype=np.float64)


@dataclass(frozen=True)
class Vignetting:
    """Residual radial falloff of irradiance (after the ISP's lens-shading correction):
    ``2 ** (-corner_stops * (r / r_corner) ** 2)``, r measured from the image centre to a pixel centre
    (r_corner: to a corner pixel's centre). An r^2 law in stops is
    the small-angle form of the cos^4 law (``-4 log2 cos(theta) ~ 2.9 tan^2(theta)``)."""

    corner_stops: float
    """Darkening at the image corner in stops (EV); 0 is none."""
    SECTION: ClassVar[str] = "vignetting"

    def __post_init__(self) -> None:
        _in_range(self.SECTION, "corner_stops", self.corner_stops, 0.0, 8.0)


@dataclass(frozen=True)
class Exposure:
    """Auto-exposure: meter the median luminance of the irradiance the sensor sees, then choose shutter time
    first (up to ``max_shutter_s``), then ISO, to bring it to ``target * 2 ** ev_bias_stops``. What the
    limits do not allow is left as under- (or over-)exposure (``record["exposure_shortfall_stops"]``).

    The render has no photometric scale: ``reference_shutter_s`` states how bright the scene is, as the
    shutter time at ``CaptureParams.base_iso`` (and this device's aperture) that records the render's linear
    values 1:1 in the raw file. A brighter scene has a shorter reference time."""

    reference_shutter_s: float
    """Shutter time (s) at base ISO at which a raw value equals the render's linear value."""
    target: float = 0.18
    """Metered median luminance to aim for, as a fraction of white (0.18: mid grey)."""
    ev_bias_stops: float = 0.0
    """Exposure compensation in stops (the meter's error or the user's choice)."""
    min_shutter_s: float = 1.0 / 8000.0
    """Shortest shutter time (s)."""
    max_shutter_s: float = 1.0 / 30.0
    """Longest shutter time (s) the camera allows hand-held before it raises ISO instead."""
    iso_min: float = 50.0
    """Lowest ISO the camera uses."""
    iso_max: float = 3200.0
    """Highest ISO (analog gain) the camera uses."""
    manual_shutter_s: float | None = None
    """Fixed shutter time (s); ``None``: automatic."""
    manual_iso: float | None = None
    """Fixed ISO; ``None``: automatic."""
    SECTION: ClassVar[str] = "exposure"

    def __post_init__(self) -> None:
        _positive(self.SECTION, reference_shutter_s=self.reference_shutter_s, target=self.target,
                  min_shutter_s=self.min_shutter_s, max_shutter_s=self.max_shutter_s, iso_min=self.iso_min,
                  iso_max=self.iso_max, manual_shutter_s=self.manual_shutter_s,
                  manual_iso=self.manual_iso)  # fmt: skip
        _in_range(self.SECTION, "ev_bias_stops", self.ev_bias_stops, -10.0, 10.0)
        _in_range(self.SECTION, "target", self.target, 1e-4, 1.0)
        if self.max_shutter_s < self.min_shutter_s:
            _fail(self.SECTION, "max_shutter_s", f"must be >= min_shutter_s ({self.min_shutter_s})", self.max_shutter_s)
        if self.iso_max < self.iso_min:
            _fail(self.SECTION, "iso_max", f"must be >= iso_min ({self.iso_min})", self.iso_max)


@dataclass(frozen=True)
class Sensor:
    """The raw sensor: colour-filter response, RGGB Bayer mosaic, Poisson-Gaussian noise, black level and
    ADC. Noise in raw units (white level = 1) follows Foi et al. 2008, "Practical Poissonian-Gaussian noise
    modeling and fitting for single-image raw-data" (IEEE TIP): ``y = a * Poisson(x / a) + N(0, b)``, so
    ``var(y) = a x + b``. The shot term scales with analog gain, ``a = shot_noise * ISO / base_iso``, and the
    read term follows the log-linear fit of Brooks et al. 2019 (CVPR):
    ``ln b = 2.18 ln a + 1.20 + read_noise_log_offset``; their sampled range of a is 1e-4 to 0.012."""

    shot_noise: float = 1e-4
    """Shot-noise factor a at base ISO (variance per unit signal, white level = 1), i.e. 1 / full-well
    electrons at unity gain; Brooks et al.'s range starts at 1e-4."""
    read_noise_log_offset: float = 0.0
    """This device's deviation (natural log) from Brooks et al.'s read-noise fit; they draw it N(0, 0.26)."""
    wb_gain_red: float = 2.15
    """Gain that makes this sensor's red raw channel neutral under the capture light (red pixels see
    1 / gain of green); Brooks et al.: U(1.9, 2.4)."""
    wb_gain_blue: float = 1.7
    """Blue counterpart of ``wb_gain_red``; Brooks et al.: U(1.5, 1.9)."""
    bayer: bool = True
    """RGGB colour filter mosaic, demosaicked by the ISP; ``False``: three full colour planes."""
    demosaic: str = "bilinear"
    """``"bilinear"`` (OpenCV ``COLOR_BayerRGGB2RGB``) or ``"edge-aware"`` (``..._EA``), on 16-bit data."""
    noise: bool = True
    """Poisson-Gaussian noise on; ``False``: a noiseless sensor (mosaic and ADC still apply)."""
    bit_depth: int = 12
    """ADC bits: raw values are integers 0 .. 2**bit_depth - 1."""
    black_level: float = 0.0625
    """Black level as a fraction of the ADC range (256 / 4096 on many 12-bit sensors, 64 / 1024 on 10-bit
    phone sensors): noise below black is not clipped away before the ISP subtracts it."""
    SECTION: ClassVar[str] = "sensor"
    DEMOSAIC: ClassVar[dict[str, int]] = {
        "bilinear": cv2.COLOR_BayerRGGB2RGB,  # == COLOR_BayerBG2RGB; OpenCV's "BayerRG" names mean BGGR
        "edge-aware": cv2.COLOR_BayerRGGB2RGB_EA,
    }

    def __post_init__(self) -> None:
        _in_range(self.SECTION, "shot_noise", self.shot_noise, 1e-7, 0.1)
        _in_range(self.SECTION, "read_noise_log_offset", self.read_noise_log_offset, -5.0, 5.0)
        _in_range(self.SECTION, "wb_gain_red", self.wb_gain_red, 0.2, 8.0)
        _in_range(self.SECTION, "wb_gain_blue", self.wb_gain_blue, 0.2, 8.0)
        if self.demosaic not in self.DEMOSAIC:
            _fail(self.SECTION, "demosaic", f"must be one of {sorted(self.DEMOSAIC)}", self.demosaic)
        if not isinstance(self.bit_depth, int) or not 8 <= self.bit_depth <= 16:
            _fail(self.SECTION, "bit_depth", "must be an integer in [8, 16]", self.bit_depth)
        _in_range(self.SECTION, "black_level", self.black_level, 0.0, 0.5)


@dataclass(frozen=True)
class ColorMatrix:
    """The camera's colour space: its XYZ -> camera-RGB matrix (as in DNG ``ColorMatrix`` / dcraw). The scene
    is taken into camera RGB with it and the ISP's colour correction matrix (its inverse) brings it back: no
    colour change when nothing else happens, but noise is mixed and amplified across channels and camera-RGB
    channels clip on their own, as in a real camera."""

    xyz_to_cam: tuple[tuple[float, float, float], ...]
    """3x3 XYZ -> camera RGB (rows: camera R, G, B)."""
    SECTION: ClassVar[str] = "color_matrix"

    def __post_init__(self) -> None:
        m = np.asarray(self.xyz_to_cam, dtype=np.float64)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            _fail(self.SECTION, "xyz_to_cam", "must be a finite 3x3 matrix", self.xyz_to_cam)
        rgb_to_cam = m @ RGB_TO_XYZ
        if np.any(np.abs(rgb_to_cam.sum(axis=1)) < 1e-3) or abs(np.linalg.det(rgb_to_cam_matrix(m))) < 1e-6:
            _fail(self.SECTION, "xyz_to_cam", "must be invertible and map white to a non-zero colour", self.xyz_to_cam)


@dataclass(frozen=True)
class WhiteBalance:
    """White-balance error: the camera estimates the illuminant's colour temperature with an error and
    divides by its estimate (a von Kries diagonal gain in camera RGB). The render is taken as correctly
    balanced for the true illuminant, so only the error shows: camera-RGB gains
    ``w(T_true) / w(T_est)``, with w(T) the camera-RGB colour of a black body (:func:`planckian_rgb`)."""

    illuminant_k: float = 4700.0
    """Correlated colour temperature (K) of the capture light (Infinigen's lamps: clip-N(4700, 700,
    3500-6500) K)."""
    error_mired: float = 0.0
    """Camera estimate minus truth in mired (1e6 / T). Positive: the camera assumes warmer light than there
    is and the photo comes out cooler (bluer); negative: warmer (more orange)."""
    SECTION: ClassVar[str] = "white_balance"

    def __post_init__(self) -> None:
        lo, hi = PLANCKIAN_RANGE_K
        _in_range(self.SECTION, "illuminant_k", self.illuminant_k, lo, hi)
        _in_range(self.SECTION, "error_mired", self.error_mired, -300.0, 300.0)
        estimate = mired(self.illuminant_k) + self.error_mired
        if not mired(hi) <= estimate <= mired(lo):
            _fail(self.SECTION, "error_mired", f"puts the estimate outside {lo:g}-{hi:g} K", self.error_mired)

    @property
    def estimated_k(self) -> float:
        """The camera's estimate of the illuminant's colour temperature (K)."""
        return 1e6 / (mired(self.illuminant_k) + self.error_mired)


@dataclass(frozen=True)
class ToneCurve:
    """Global tone curve in display (sRGB-encoded) space: ``(1 - s) v + s (3 v^2 - 2 v^3)``, the smoothstep
    S-curve Brooks et al. 2019 use as the generic camera tone curve, blended with identity by strength s."""

    strength: float = 1.0
    """Blend s in [0, 1] (dimensionless): 0 is no tone curve, 1 is the full smoothstep."""
    SECTION: ClassVar[str] = "tone_curve"

    def __post_init__(self) -> None:
        _in_range(self.SECTION, "strength", self.strength, 0.0, 1.0)


@dataclass(frozen=True)
class NoiseReduction:
    """The ISP's noise reduction, as phone cameras apply it before the JPEG. First a burst merge: HDR+ (Hasinoff
    et al. 2016, "Burst photography for high dynamic range and low-light imaging on mobile cameras", SIGGRAPH
    Asia) aligns and merges 2-8 raw frames, so the merged raw has ``1 / merge_frames`` the noise variance of one
    frame (modelled as an ideal merge of frames of the chosen exposure: the AE's shutter and ISO are per frame;
    motion within the burst is not modelled). Then chroma noise reduction: the colour-difference planes (each
    linear channel minus the luminance) blurred by a Gaussian of ``chroma_sigma_px`` (scipy.ndimage: the same
    bits on every CPU), leaving luminance detail to the merge. Without it a photo at ISO 2000 carries the raw
    sensor's full colour noise, which no phone JPEG shows."""

    merge_frames: int = 1
    """Raw frames merged (1: a single frame)."""
    chroma_sigma_px: float = 0.0
    """Gaussian sigma (px) of the chroma blur; 0: none."""
    SECTION: ClassVar[str] = "noise_reduction"

    def __post_init__(self) -> None:
        frames = self.merge_frames
        if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= 16:
            _fail(self.SECTION, "merge_frames", "must be an integer in [1, 16]", self.merge_frames)
        _in_range(self.SECTION, "chroma_sigma_px", self.chroma_sigma_px, 0.0, 10.0)


@dataclass(frozen=True)
class Jpeg:
    """JPEG compression with Pillow (libjpeg baseline: no ``optimize``, not progressive, fixed chroma
    subsampling, so the bytes depend on the pixels and the libjpeg build only)."""

    quality: int = 95
    """libjpeg quality 1-95 (IJG scale; above 95 is disabled by libjpeg's own advice)."""
    subsampling: str = "4:2:0"
    """Chroma subsampling: ``"4:4:4"``, ``"4:2:2"`` or ``"4:2:0"`` (what cameras and web services write)."""
    SECTION: ClassVar[str] = "jpeg"
    SUBSAMPLING: ClassVar[dict[str, int]] = {"4:4:4": 0, "4:2:2": 1, "4:2:0": 2}

    def __post_init__(self) -> None:
        if not isinstance(self.quality, int) or not 1 <= self.quality <= 95:
            _fail(self.SECTION, "quality", "must be an integer in [1, 95]", self.quality)
        if self.subsampling not in self.SUBSAMPLING:
            _fail(self.SECTION, "subsampling", f"must be one of {sorted(self.SUBSAMPLING)}", self.subsampling)


@dataclass(frozen=True)
class Resize:
    """Resizing as a photo is resized when shared online: Pillow LANCZOS to a longest side in pixels.
    Pillow maps the box [0, W] onto [0, W'], so intrinsics scale as ``fx, cx *= W' / W`` (pixel-corner
    convention of ``render.base``); ``record["resize_scale"]`` gives the factors."""

    longest_px: int
    """Target longest side (px); the other side keeps the aspect ratio (rounded)."""
    upscale: bool = False
    """Also enlarge images smaller than ``longest_px`` (web services do not)."""
    SECTION: ClassVar[str] = "resize"

    def __post_init__(self) -> None:
        if not isinstance(self.longest_px, int) or not 8 <= self.longest_px <= 16384:
            _fail(self.SECTION, "longest_px", "must be an integer in [8, 16384]", self.longest_px)


@dataclass(frozen=True)
class CaptureParams:
    """A camera: one optional parameter set per effect (``None``: the effect is off), applied in the order of
    the fields. ``base_iso`` is the ISO of unity analog gain (shared by the exposure and noise models)."""

    base_iso: float = 100.0
    """ISO at unity analog gain: the ISO the sensor's noise is specified at."""
    defocus: Defocus | None = None
    motion_blur: MotionBlur | None = None
    """Camera motion during the exposure (:mod:`synthleak.render.motion_blur`; GT is the mid-exposure pose)."""
    distortion: Distortion | None = None
    """Lens distortion: needs the render's camera (``capture(camera=...)``); changes the photo's camera."""
    vignetting: Vignetting | None = None
    exposure: Exposure | None = None
    sensor: Sensor | None = None
    color_matrix: ColorMatrix | None = None
    white_balance: WhiteBalance | None = None
    noise_reduction: NoiseReduction | None = None
    """The ISP's burst merge (noise variance / frames, at the noise step) and chroma noise reduction (after the
    colour correction)."""
    tone_curve: ToneCurve | None = None
    jpeg: Jpeg | None = None
    """In-camera JPEG."""
    resize: Resize | None = None
    recompress: Jpeg | None = None
    """The uploader's re-compression after ``resize`` (web services re-encode)."""
    name: str = field(default="custom", compare=False)
    """Profile name (for records only)."""
    SECTION: ClassVar[str] = "capture"

    def __post_init__(self) -> None:
        _positive(self.SECTION, base_iso=self.base_iso)
        kinds = {
            "defocus": Defocus, "motion_blur": MotionBlur, "distortion": Distortion,
            "vignetting": Vignetting, "exposure": Exposure,
            "sensor": Sensor, "color_matrix": ColorMatrix, "white_balance": WhiteBalance,
            "noise_reduction": NoiseReduction, "tone_curve": ToneCurve, "jpeg": Jpeg, "resize": Resize,
            "recompress": Jpeg,
        }  # fmt: skip
        for name, kind in kinds.items():
            value = getattr(self, name)
            if value is not None and not isinstance(value, kind):
                _fail(self.SECTION, name, f"must be a {kind.__name__} or None", value)

    @property
    def is_geometric(self) -> bool:
        """True when the photo's camera differs from the render's (distortion, or a resize)."""
        return self.distortion is not None or self.resize is not None

    @property
    def is_ideal(self) -> bool:
        """True when every effect is off (the output is then the pipeline's plain 8-bit encoding)."""
        return all(getattr(self, n) is None for n in EFFECT_FIELDS)


EFFECT_FIELDS = (
    "defocus", "motion_blur", "distortion", "vignetting", "exposure", "sensor", "color_matrix", "white_balance",
    "noise_reduction", "tone_curve", "jpeg", "resize", "recompress",
)  # fmt: skip
"""The effect fields of :class:`CaptureParams`, in the order they are applied."""


# ------------------------------------------------------------------------------------------ 8-bit encoding


def pipeline_encoding(linear_rgb: np.ndarray) -> np.ndarray:
    """The render pipeline's current linear -> 8-bit sRGB encoding (clip to [0, 1], sRGB OETF, round),
    imported lazily: the backends will import this module when capture is wired in."""
    from synthleak.render.mitsuba_backend import linear_to_srgb_uint8

    return linear_to_srgb_uint8(linear_rgb)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """sRGB OETF (IEC 61966-2-1) on linear values in [0, 1]."""
    x = np.clip(x, 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """Inverse sRGB OETF on encoded values in [0, 1]."""
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4))


def srgb8_to_linear(rgb: np.ndarray) -> np.ndarray:
    """uint8 sRGB (mitsuba / Blender frames) -> linear float32."""
    return srgb_decode(np.asarray(rgb, dtype=np.float64) / 255.0).astype(np.float32)


def gamma22_to_linear(rgb: np.ndarray) -> np.ndarray:
    """pyrender's 8-bit output (``pow(c, 1/2.2)`` in its shader, rounded by OpenGL) -> linear float32."""
    return np.power(np.asarray(rgb, dtype=np.float32) / np.float32(255.0), np.float32(2.2))


_LUT_SHIFT = 12
"""float32 bit patterns share a LUT bucket when they agree above this bit (4096 neighbouring floats)."""


@functools.lru_cache(maxsize=8)
def _encoder_tables(tone_strength: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Tables of :func:`encode_8bit`: for the monotone map ``f = pipeline_encoding o tone`` the 255 smallest
    float32 inputs where f steps up, bucketed by their top bits (at most one step per bucket)."""
    s = float(tone_strength)

    def f(bits: np.ndarray) -> np.ndarray:
        y = np.repeat(bits.view(np.float64)[:, None, None], 3, axis=2)  # (N, 1, 3): an image, as the pipeline's
        if s > 0.0:
            v = srgb_encode(y)
            y = srgb_decode((1.0 - s) * v + s * v * v * (3.0 - 2.0 * v))
        return pipeline_encoding(y)[:, 0, 0].astype(np.int64)

    levels = np.arange(1, 256)
    lo = np.zeros(255, dtype=np.int64)  # invariant f(lo) < level <= f(hi); bisection on float64 bit patterns
    hi = np.full(255, np.float64(2.0).view(np.int64))
    while np.any(hi - lo > 1):
        mid = lo + (hi - lo) // 2
        up = f(mid) >= levels
        hi, lo = np.where(up, mid, hi), np.where(up, lo, mid)
    step = hi.view(np.float64)
    step32 = step.astype(np.float32)
    step32 = np.where(step32.astype(np.float64) < step, np.nextafter(step32, np.float32(np.inf)), step32)
    bits = step32.view(np.int32).astype(np.int64)
    n_buckets = (int(np.float32(2.0).view(np.int32)) >> _LUT_SHIFT) + 1
    starts = np.arange(n_buckets, dtype=np.int64) << _LUT_SHIFT
    base = np.searchsorted(bits, starts, side="right").astype(np.uint8)  # f at each bucket's first float
    inner = np.full(n_buckets, np.iinfo(np.int32).max, dtype=np.int32)
    strictly = bits & ((1 << _LUT_SHIFT) - 1) != 0
    buckets = bits[strictly] >> _LUT_SHIFT
    if len(np.unique(buckets)) != len(buckets):
        raise RuntimeError("encode_8bit: two steps in one LUT bucket; lower _LUT_SHIFT")
    inner[buckets] = bits[strictly]
    return base, inner, n_buckets - 1


def encode_8bit(linear: np.ndarray, tone_strength: float = 0.0) -> np.ndarray:
    """``pipeline_encoding(tone(linear))`` for float32 input, bit-exact and ~10x faster: the map is monotone,
    so a LUT on the float32 bit pattern plus one comparison per pixel reproduces it
    (``tests/test_capture.py`` checks it at every step). NaN maps to 255 here (0 in the pipeline's)."""
    base, inner, top = _encoder_tables(float(tone_strength))
    x = np.ascontiguousarray(linear, dtype=np.float32)
    bits = x.view(np.int32)
    idx = np.clip(bits >> _LUT_SHIFT, 0, top)  # negative floats (sign bit) -> bucket 0 -> 0
    return base[idx] + (bits >= inner[idx]).astype(np.uint8)


# --------------------------------------------------------------------------------------------- the effects


def circle_of_confusion_px(depth: np.ndarray, params: Defocus, focus_m: float, width_px: int) -> np.ndarray:
    """Thin-lens circle-of-confusion diameter in pixels for z-depth ``depth`` (m; +inf allowed) and focus
    distance ``focus_m`` (m; +inf: focused at infinity, ``c = (f / N) f / z``)."""
    f = params.focal_length_mm
    z = np.maximum(np.asarray(depth, dtype=np.float64) * 1000.0, f * 1.001)
    aperture = f / params.f_number
    if math.isinf(focus_m):
        c_mm = aperture * f / z
    else:
        s = focus_m * 1000.0
        with np.errstate(invalid="ignore"):
            ratio = np.where(np.isinf(z), 1.0, np.abs(z - s) / z)
        c_mm = aperture * f * ratio / (s - f)
    return (c_mm * width_px / params.sensor_width_mm).astype(np.float32)


def autofocus_distance(depth: np.ndarray) -> float:
    """Median finite z-depth (m) in the central fifth (by side) of the frame; +inf when none is finite."""
    h, w = depth.shape
    centre = depth[2 * h // 5 : max(3 * h // 5, 2 * h // 5 + 1), 2 * w // 5 : max(3 * w // 5, 2 * w // 5 + 1)]
    finite = centre[np.isfinite(centre) & (centre > 0)]
    return float(np.median(finite)) if finite.size else math.inf


@functools.lru_cache(maxsize=32)
def _disc(diameter: float) -> np.ndarray:
    """Anti-aliased disc kernel of ``diameter`` px (coverage sampled 8x8 per pixel), summing to 1."""
    r = diameter / 2.0
    n = int(math.ceil(r - 0.5)) * 2 + 1
    sub = (np.arange(n * 8) + 0.5) / 8.0 - n / 2.0
    inside = (sub[:, None] ** 2 + sub[None, :] ** 2 <= r * r).astype(np.float32)
    k = inside.reshape(n, 8, n, 8).mean(axis=(1, 3))
    return k / k.sum()


def _correlate(x: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """``x`` (H, W, C) correlated with ``kernel``, mirrored borders (OpenCV's ``BORDER_REFLECT``), by
    scipy.ndimage (compiled without run-time SIMD dispatch, float64 sums: the same bits on every CPU, unlike
    ``cv2.filter2D``)."""
    from scipy.ndimage import correlate

    k = np.asarray(kernel, dtype=np.float64)
    out = np.empty_like(x)
    for c in range(x.shape[2]):
        correlate(x[..., c], k, output=out[..., c], mode="reflect")
    return out


VIGNETTING_STEP = 1e-9
"""Grid of the vignetting factors (exact on every CPU, far below a float32 ulp of the image)."""

DEFOCUS_LAYERS = (0.0, 1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0)
"""Disc diameters (px) of the layer stack; a pixel interpolates linearly between its two neighbours."""


def apply_defocus(x: np.ndarray, coc_px: np.ndarray, max_blur_px: float) -> np.ndarray:
    """Depth-varying disc blur: the image is blurred once per layer diameter (OpenCV ``filter2D``) and each
    pixel takes the linear interpolation of the two layers around its own circle of confusion (a gather
    approximation: a blurred background can take colour from a sharp foreground at occlusion edges)."""
    c = np.minimum(coc_px, np.float32(max_blur_px))
    c_max = float(c.max()) if c.size else 0.0
    layers = [d for d in DEFOCUS_LAYERS if d <= max_blur_px]
    if c_max > layers[-1]:
        layers.append(float(max_blur_px))
    out = np.zeros_like(x)
    for k, d in enumerate(layers):
        lo = layers[k - 1] if k else None
        hi = layers[k + 1] if k + 1 < len(layers) else None
        if lo is not None and lo >= c_max:
            break
        weight = np.zeros_like(c)  # the hat function of layer k over the CoC diameter
        if lo is not None:
            rising = (c >= lo) & (c <= d)
            weight[rising] = (c[rising] - lo) / (d - lo)
        else:
            weight[c <= d] = 1.0
        if hi is not None:
            falling = (c > d) & (c < hi)
            weight[falling] = (hi - c[falling]) / (hi - d)
        if not weight.any():
            continue
        blurred = x if d <= 1.0 else _correlate(x, _disc(d))
        out += blurred * weight[..., None]
    return out


def vignetting_map(height: int, width: int, corner_stops: float) -> np.ndarray:
    """(H, W, 1) float32 irradiance factor ``2 ** (-corner_stops * (r / r_corner) ** 2)`` at pixel centres;
    r_corner is the radius of the corner pixels' centres, so they are exactly ``corner_stops`` darker."""
    v = (np.arange(height, dtype=np.float32) + 0.5 - height / 2.0) ** 2
    u = (np.arange(width, dtype=np.float32) + 0.5 - width / 2.0) ** 2
    # 2^(-s r2) = 2^(-s v / R) 2^(-s u / R): two 1-D factors on a grid (numpy's exp2 picks SIMD kernels by
    # CPU; snapped, the last-bit differences vanish), multiplied elementwise
    scale = np.float32(((height - 1) / 2.0) ** 2 + ((width - 1) / 2.0) ** 2 or 1.0)
    fv = snap(np.exp2(-float(corner_stops) * (v / scale).astype(np.float64)), VIGNETTING_STEP).astype(np.float32)
    fu = snap(np.exp2(-float(corner_stops) * (u / scale).astype(np.float64)), VIGNETTING_STEP).astype(np.float32)
    return (fv[:, None] * fu[None, :])[..., None]


def meter(x: np.ndarray) -> float:
    """The auto-exposure meter: median relative luminance on a 4x-subsampled grid (AE statistics are low
    resolution)."""
    return float(np.median(luminance(np.asarray(x[::4, ::4], dtype=np.float64))))


def luminance(x: np.ndarray) -> np.ndarray:
    """Relative luminance Y of linear RGB ``x`` (H, W, 3) in ``x``'s float type, as elementwise products and sums
    in a fixed order: the same bits on every CPU (``x @ LUMA`` is a BLAS product)."""
    luma = LUMA.astype(x.dtype)
    return x[..., 0] * luma[0] + x[..., 1] * luma[1] + x[..., 2] * luma[2]


def choose_exposure(metered: float, params: Exposure, base_iso: float) -> dict[str, float]:
    """Program auto-exposure: shutter first, then ISO, within the limits. Returns shutter_s, iso, the linear
    gain over the render (``(t / t_ref) * (ISO / base_iso)``) and the shortfall in stops (> 0: darker than
    the target)."""
    want = params.target * 2.0**params.ev_bias_stops / max(metered, 1e-12)
    t_lo, t_hi = (
        (params.manual_shutter_s,) * 2 if params.manual_shutter_s else (params.min_shutter_s, params.max_shutter_s)
    )
    i_lo, i_hi = (params.manual_iso,) * 2 if params.manual_iso else (params.iso_min, params.iso_max)
    t_ideal = params.reference_shutter_s * want  # at base ISO
    shutter = min(max(t_ideal, t_lo), t_hi)
    iso = min(max(base_iso * t_ideal / shutter, i_lo), i_hi)
    gain = (shutter / params.reference_shutter_s) * (iso / base_iso)
    return {"shutter_s": shutter, "iso": iso, "gain": gain, "shortfall_stops": math.log2(want / gain)}


def noise_params(sensor: Sensor, iso: float, base_iso: float) -> tuple[float, float]:
    """Poisson-Gaussian (a, b) in raw units at ``iso``: ``var = a x + b`` (Foi et al. 2008), a proportional
    to analog gain, ``ln b = 2.18 ln a + 1.20 + offset`` (Brooks et al. 2019)."""
    a = sensor.shot_noise * iso / base_iso
    b = math.exp(2.18 * math.log(a) + 1.20 + sensor.read_noise_log_offset)
    return a, b


def add_sensor_noise(raw: np.ndarray, a: float, b: float, rng: np.random.Generator) -> np.ndarray:
    """Poisson-Gaussian noise on raw values (white = 1): ``a * Poisson(raw / a) + sqrt(b) * N(0, 1)``. Draws,
    in this order: the Poisson field, then the Gaussian field (both of ``raw``'s shape)."""
    photons = rng.poisson(np.maximum(raw, 0.0) / a)
    read = rng.standard_normal(raw.shape, dtype=np.float32)
    return (photons.astype(np.float32) * np.float32(a) + read * np.float32(math.sqrt(b))).astype(np.float32)


def chroma_denoise(x: np.ndarray, sigma_px: float) -> np.ndarray:
    """Linear RGB ``x`` with its colour-difference planes (``channel - Y``) blurred by a Gaussian of ``sigma_px``
    and its luminance Y kept (:class:`NoiseReduction`); mirrored borders, float64 sums (scipy.ndimage)."""
    from scipy.ndimage import gaussian_filter

    y = luminance(x)
    out = np.empty_like(x)
    for c in range(3):
        out[..., c] = y + gaussian_filter((x[..., c] - y).astype(np.float64), sigma_px, mode="reflect").astype(
            np.float32)
    return out


def mosaic(cam: np.ndarray) -> np.ndarray:
    """RGGB Bayer mosaic (H, W) of a camera-RGB image (H, W, 3): R at (even, even), B at (odd, odd)."""
    raw = np.empty(cam.shape[:2], dtype=cam.dtype)
    raw[0::2, 0::2] = cam[0::2, 0::2, 0]
    raw[0::2, 1::2] = cam[0::2, 1::2, 1]
    raw[1::2, 0::2] = cam[1::2, 0::2, 1]
    raw[1::2, 1::2] = cam[1::2, 1::2, 2]
    return raw


def _adc(signal: np.ndarray, sensor: Sensor) -> tuple[np.ndarray, float, float]:
    """Signal (white = 1, may be negative from read noise) -> integer raw DN with black level, clipped at
    white; returned as uint16 with the black and white DN."""
    white = float(2**sensor.bit_depth - 1)
    black = round(sensor.black_level * white)
    dn = np.rint(signal * np.float32(white - black) + np.float32(black))
    return np.clip(dn, 0.0, white).astype(np.uint16), float(black), white


def _from_dn(dn: np.ndarray, black: float, white: float) -> np.ndarray:
    return (dn.astype(np.float32) - np.float32(black)) * np.float32(1.0 / (white - black))


def encode_jpeg(rgb: np.ndarray, params: Jpeg) -> bytes:
    """JPEG bytes of a uint8 (H, W, 3) image from Pillow's libjpeg at ``params``: baseline, no ``optimize``,
    not progressive, fixed subsampling, no metadata (the same pixels give the same bytes)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb), "RGB").save(
        buf,
        format="JPEG",
        quality=params.quality,
        subsampling=Jpeg.SUBSAMPLING[params.subsampling],
        optimize=False,
        progressive=False,
    )
    return buf.getvalue()


def decode_jpeg(data: bytes) -> np.ndarray:
    """uint8 (H, W, 3) pixels of JPEG ``data`` (Pillow)."""
    with Image.open(io.BytesIO(data)) as im:
        return np.asarray(im.convert("RGB"))


def jpeg_roundtrip(rgb: np.ndarray, params: Jpeg) -> tuple[np.ndarray, int]:
    """Encode (:func:`encode_jpeg`) and decode; returns the decoded image and the JPEG's size in bytes."""
    data = encode_jpeg(rgb, params)
    return decode_jpeg(data), len(data)


def resized_size(width: int, height: int, params: Resize) -> tuple[int, int]:
    """(W', H') of :func:`resize_longest` for a ``width`` x ``height`` image."""
    longest = max(height, width)
    if longest == params.longest_px or (longest < params.longest_px and not params.upscale):
        return width, height
    scale = params.longest_px / longest
    return max(1, round(width * scale)), max(1, round(height * scale))


def resize_longest(rgb: np.ndarray, params: Resize) -> np.ndarray:
    """Pillow LANCZOS resize so that the longest side is ``params.longest_px`` (unchanged when smaller and
    ``upscale`` is off)."""
    h, w = rgb.shape[:2]
    size = resized_size(w, h, params)
    if size == (w, h):
        return rgb
    return np.asarray(Image.fromarray(rgb, "RGB").resize(size, Image.Resampling.LANCZOS))


def lens_camera(params: CaptureParams, width: int, height: int) -> Camera:
    """The pinhole camera of the profile's own lens (``defocus``: ``f = focal_length_mm / sensor_width_mm * W``,
    centred), for a :func:`capture` of a distorting profile without ``camera``; a ConfigError without a lens."""
    if params.defocus is None:
        raise ConfigError("capture parameter distortion: needs the render's camera (camera=None given and no "
                          "defocus lens to derive it from)")
    f = params.defocus.focal_length_mm / params.defocus.sensor_width_mm * width
    return Camera(int(width), int(height), f, f, width / 2.0, height / 2.0)


def output_camera(render_camera: Camera, params: CaptureParams) -> Camera:
    """The camera of the photo :func:`capture` makes of a render by the pinhole ``render_camera``: an
    ``OPENCV`` camera after ``distortion`` (:func:`synthleak.render.distortion.distorted_camera`), scaled to
    the resized size after ``resize`` (:func:`synthleak.core.dataset.scaled_camera`); ``render_camera``
    itself when neither is on. A distortion that folds inside the frame is a ConfigError naming the profile
    and the field."""
    from synthleak.core.dataset import scaled_camera
    from synthleak.render.distortion import distorted_camera

    camera = render_camera
    if params.distortion is not None:
        camera = distorted_camera(render_camera, params.distortion.coeffs,
                                  f"capture profile {params.name}: {Distortion.SECTION}")
    if params.resize is not None:
        size = resized_size(camera.width, camera.height, params.resize)
        if size != (camera.width, camera.height):
            camera = scaled_camera(camera, *size)
    return camera


# ------------------------------------------------------------------------------------------------- capture


class Photo(NamedTuple):
    """:func:`capture`'s result: the photograph and a JSON-serialisable record of what was applied."""

    rgb: np.ndarray
    record: dict[str, Any]


def _check_input(linear_rgb: np.ndarray, depth: np.ndarray | None, params: CaptureParams) -> None:
    if not isinstance(params, CaptureParams):
        raise ConfigError(f"capture: params must be CaptureParams, got {type(params).__name__}")
    arr = np.asarray(linear_rgb)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.dtype.kind != "f":
        raise ValueError(f"capture: linear_rgb must be float (H, W, 3), got {arr.dtype} {arr.shape}")
    if params.defocus is not None:
        if depth is None:
            raise ConfigError("capture parameter defocus: needs the frame's depth map (depth=None given)")
        if np.shape(depth) != arr.shape[:2]:
            raise ValueError(f"capture: depth must be (H, W) = {arr.shape[:2]}, got {np.shape(depth)}")


def capture(
    linear_rgb: np.ndarray,
    params: CaptureParams,
    seed: int,
    depth: np.ndarray | None = None,
    *,
    timings: dict[str, float] | None = None,
    camera: Camera | None = None,
) -> Photo:
    """Photograph a render: ``linear_rgb`` float (H, W, 3) linear radiance (see the module docstring),
    ``depth`` z-depth (H, W) in m (needed by ``defocus`` only). Returns :class:`Photo` ``(rgb, record)``:
    uint8 (H', W', 3) and what was applied (chosen shutter / ISO / gain, noise a and b, white-balance
    estimate and gains, focus distance, JPEG sizes, resize factors; ``record["effects"]`` lists the effects
    in order). Random draws, all from ``numpy.random.default_rng(seed)``: the sensor's Poisson field, then
    its Gaussian field; nothing else is random (per-photo parameters come from ``devices.draw_device``).
    ``timings``, when given, receives seconds per stage; ``camera``: the frame's intrinsics (motion blur), the
    render's pinhole camera, needed by ``distortion``: the photo's camera is then :func:`output_camera`
    (``record["camera"]``: its COLMAP model and params)."""
    _check_input(linear_rgb, depth, params)
    if params.distortion is not None and camera is None:
        camera = lens_camera(params, np.shape(linear_rgb)[1], np.shape(linear_rgb)[0])
    rng = np.random.default_rng(int(seed))
    record: dict[str, Any] = {"profile": params.name, "seed": int(seed), "effects": []}
    clock = [time.perf_counter()]

    def done(stage: str, **values: Any) -> None:
        record["effects"].append(stage)
        record.update(values)
        if timings is not None:
            now = time.perf_counter()
            timings[stage] = timings.get(stage, 0.0) + now - clock[0]
            clock[0] = now

    if params.is_ideal:  # the pipeline's own encoding, untouched input: byte-identical by construction
        rgb = pipeline_encoding(linear_rgb)
        done("encode")
        return Photo(rgb, record)

    x = np.nan_to_num(np.asarray(linear_rgb, dtype=np.float32), nan=0.0, posinf=65504.0, neginf=0.0)
    x = np.maximum(x, np.float32(0.0))
    h, w = x.shape[:2]
    if timings is not None:
        clock[0] = time.perf_counter()  # input conversion is not an effect

    # ---- optics: what reaches the sensor
    if params.defocus is not None:
        z = np.asarray(depth, dtype=np.float32)
        focus = params.defocus.focus_distance_m or autofocus_distance(z)
        focus = max(focus, 2e-3 * params.defocus.focal_length_mm)  # autofocus stops at 1:1 macro (2 f)
        coc = circle_of_confusion_px(z, params.defocus, focus, w)
        x = apply_defocus(x, coc, params.defocus.max_blur_px)
        done("defocus", focus_distance_m=float(focus), max_coc_px=float(coc.max()))
    if params.motion_blur is not None:  # its shutter time: the AE's choice on the unblurred irradiance
        from synthleak.render.motion_blur import motion_blur_stage

        x, blurred = motion_blur_stage(x, depth, params, camera)
        done("motion_blur", **blurred)
    if params.distortion is not None:
        from synthleak.render.distortion import distorted_camera, sample_positions

        assert camera is not None
        if (camera.width, camera.height) != (w, h):
            raise ValueError(f"capture: camera is {camera.width}x{camera.height}, the render {w}x{h}")
        out_cam = distorted_camera(camera, params.distortion.coeffs, f"capture profile {params.name}: distortion")
        map_x, map_y = sample_positions(out_cam, camera)
        x = cv2.remap(x, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        done("distortion", distortion=params.distortion.coeffs.tolist(), distortion_focal_scale=out_cam.fx / camera.fx)
    if params.vignetting is not None:
        x = x * vignetting_map(h, w, params.vignetting.corner_stops)
        done("vignetting", vignetting_corner_stops=params.vignetting.corner_stops)

    # ---- exposure
    iso, gain = params.base_iso, 1.0
    if params.exposure is not None:
        metered = meter(x)
        chosen = choose_exposure(metered, params.exposure, params.base_iso)
        iso, gain = chosen["iso"], chosen["gain"]
        done("exposure", metered_luminance=metered, shutter_s=chosen["shutter_s"], iso=iso, exposure_gain=gain,
             exposure_shortfall_stops=chosen["shortfall_stops"])  # fmt: skip

    # ---- into camera RGB and onto the sensor: exposure gain, camera matrix and colour-filter response as one
    # 3x3 (the render's linear sRGB -> raw camera RGB, white = 1 at the sensor's saturation)
    sensor = params.sensor
    cm = params.color_matrix
    rgb_to_cam = np.eye(3) if cm is None else rgb_to_cam_matrix(np.array(cm.xyz_to_cam))
    response = np.ones(3) if sensor is None else np.array([1.0 / sensor.wb_gain_red, 1.0, 1.0 / sensor.wb_gain_blue])
    to_raw = (response[:, None] * rgb_to_cam) * gain
    if not np.array_equal(to_raw, np.eye(3)):
        x = apply_matrix3(x, to_raw)
        done("to_camera_rgb", rgb_to_cam=rgb_to_cam.round(6).tolist(), filter_response=response.round(6).tolist())
    if sensor is not None:
        raw = mosaic(x) if sensor.bayer else x
        if sensor.bayer:
            done("mosaic")
        if sensor.noise:
            a, b = noise_params(sensor, iso, params.base_iso)
            frames = params.noise_reduction.merge_frames if params.noise_reduction is not None else 1
            raw = add_sensor_noise(raw, a / frames, b / frames, rng)  # the merged burst: variance / frames
            done("noise", noise_a=a, noise_b=b, **({"merge_frames": frames} if frames > 1 else {}))
        dn, black, white = _adc(raw, sensor)
        done("adc", black_dn=black, white_dn=white)
        if sensor.bayer:
            dn = cv2.cvtColor(dn, Sensor.DEMOSAIC[sensor.demosaic])
        x = _from_dn(dn, black, white)
        if sensor.bayer:
            done("demosaic")

    # ---- ISP: white balance (the camera's estimate, von Kries in camera RGB), colour correction to sRGB
    wb = 1.0 / response  # the gains that are right for the true illuminant
    if params.white_balance is not None:
        true_w = matmul(rgb_to_cam, planckian_rgb(params.white_balance.illuminant_k))
        est_w = matmul(rgb_to_cam, planckian_rgb(params.white_balance.estimated_k))
        error = (true_w / true_w[1]) / (est_w / est_w[1])
        wb = wb * error
        record["effects"].append("white_balance")
        record.update(
            illuminant_k=params.white_balance.illuminant_k,
            estimated_k=params.white_balance.estimated_k,
            wb_error_mired=params.white_balance.error_mired,
            wb_error_gains=error.round(6).tolist(),
        )
    to_rgb = matmul(inv3(rgb_to_cam), np.diag(wb))
    if not np.array_equal(to_rgb, np.eye(3)):
        x = apply_matrix3(x, to_rgb)
        done("white_balance_ccm")
    if params.noise_reduction is not None and params.noise_reduction.chroma_sigma_px > 0:
        x = chroma_denoise(x, params.noise_reduction.chroma_sigma_px)
        done("chroma_denoise", chroma_sigma_px=params.noise_reduction.chroma_sigma_px)

    # ---- tone curve and sRGB encoding: one exact LUT pass (see encode_8bit)
    strength = 0.0 if params.tone_curve is None else params.tone_curve.strength
    rgb = encode_8bit(x, strength)
    if params.tone_curve is not None:
        record["effects"].append("tone_curve")
        record["tone_strength"] = strength
    done("encode")

    # ---- out of the camera and onto the Internet
    if params.jpeg is not None:
        rgb, size = jpeg_roundtrip(rgb, params.jpeg)
        done("jpeg", jpeg_quality=params.jpeg.quality, jpeg_bytes=size)
    if params.resize is not None:
        rgb = resize_longest(rgb, params.resize)
        done("resize", resize_scale=[rgb.shape[1] / w, rgb.shape[0] / h])
    if params.recompress is not None:
        rgb, size = jpeg_roundtrip(rgb, params.recompress)
        done("recompress", recompress_quality=params.recompress.quality, recompress_bytes=size)
    record["output_size"] = [int(rgb.shape[1]), int(rgb.shape[0])]
    if camera is not None and params.is_geometric:
        from synthleak.core.dataset import colmap_camera_model

        out = output_camera(camera, params)
        if (out.width, out.height) != (rgb.shape[1], rgb.shape[0]):
            raise RuntimeError(f"capture: photo is {rgb.shape[1]}x{rgb.shape[0]}, its camera {out.width}x{out.height}")
        model, values = colmap_camera_model(out)
        record["camera"] = {"model": model, "width": out.width, "height": out.height, "params": values}
    return Photo(np.ascontiguousarray(rgb), record)
