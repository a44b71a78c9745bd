"""Named cameras for :func:`synthleak.render.capture.capture`: nominal :class:`CaptureParams` per profile and
:func:`draw_device`, which samples one photo's parameters within the profile's ranges.

Profiles: ``ideal`` (every effect off: the pipeline's plain 8-bit encoding), ``phone`` (a phone's main
camera in a normally lit room), ``phone-low-light`` (the same phone, a dim room at night), ``web-photo``
(somebody else's photo found online: unknown device and light, re-compressed and resized by the service).

Sources are those of ``../shared/capture-references.md``: Brooks et al. 2019, "Unprocessing Images for
Learned Raw Denoising" (noise fit, white-balance gains, camera matrices, tone curve), Foi et al. 2008
(Poisson-Gaussian model), Infinigen (lamp colour temperatures), plus standard photographic relations
(exposure value, thin lens). Values marked *assumed* are engineering choices, not measurements.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from synthleak.errors import ConfigError
from synthleak.render.capture import (
    XYZ_TO_CAM_BROOKS,
    CaptureParams,
    ColorMatrix,
    Defocus,
    Distortion,
    Exposure,
    Jpeg,
    NoiseReduction,
    Resize,
    Sensor,
    ToneCurve,
    Vignetting,
    WhiteBalance,
)
from synthleak.render.motion_blur import MotionBlur, hand_shake


def _ev100_shutter(lux: float, f_number: float, iso: float) -> float:
    """Shutter time (s) that exposes a scene of illuminance ``lux`` correctly: incident-light metering with
    C = 250 gives ``EV100 = log2(lux / 2.5)``; then ``t = N^2 / 2^(EV100 + log2(ISO / 100))``."""
    ev100 = math.log2(lux / 2.5)
    return f_number**2 / 2.0 ** (ev100 + math.log2(iso / 100.0))


MEAN_CCM = ColorMatrix(tuple(tuple(row) for row in np.mean(np.array(XYZ_TO_CAM_BROOKS), axis=0).round(4).tolist()))
"""The mean of Brooks et al.'s four camera matrices (no phone matrix is among the references)."""

PHONE_F_NUMBER = 1.8
"""A 2020s phone main camera: f/1.5-f/1.9."""
PHONE_LENS = Defocus(
    f_number=PHONE_F_NUMBER,
    focal_length_mm=5.7,  # 26-27 mm equivalent on the sensor below (36 / 7.6 * 5.7 = 27)
    sensor_width_mm=7.6,  # a 1/1.7"-type sensor, 7.6 x 5.7 mm
    focus_distance_m=None,  # autofocus on the frame centre
)
PHONE_SENSOR = Sensor(
    shot_noise=1.7e-4,  # a = 1 / full well at base ISO: ~6000 e- for 1.0-1.4 um pixels (assumed); Brooks: >= 1e-4
    read_noise_log_offset=0.0,  # on Brooks et al.'s fit; draw_device adds their N(0, 0.26)
    wb_gain_red=2.15,  # midpoints of Brooks et al.'s U(1.9, 2.4) and U(1.5, 1.9)
    wb_gain_blue=1.7,
    bit_depth=10,  # phone raw is 10-bit
    black_level=64 / 1023,  # black level 64 of 1023, usual for 10-bit sensors
)
PHONE_BASE_ISO = 50.0
"""Phone main cameras start at ISO 32-50."""

IDEAL = CaptureParams(name="ideal")
"""Every effect off: ``capture`` returns the pipeline's current 8-bit encoding of the render."""

PHONE = CaptureParams(
    name="phone",
    base_iso=PHONE_BASE_ISO,
    defocus=PHONE_LENS,
    vignetting=Vignetting(corner_stops=0.5),  # residual after lens-shading correction (assumed 0.3-0.7)
    exposure=Exposure(
        # a 150 lux living room (EV100 ~ 5.9): at f/1.8, ISO 50 that needs ~1/9 s, so AE picks 1/30 s, ISO ~170
        reference_shutter_s=_ev100_shutter(150.0, PHONE_F_NUMBER, PHONE_BASE_ISO),
        target=0.18,
        max_shutter_s=1.0 / 30.0,  # phones raise ISO rather than go below ~1/30 s hand-held (assumed)
        iso_min=PHONE_BASE_ISO,
        iso_max=3200.0,
    ),
    # residual hand shake after OIS, RMS pitch / yaw rate (assumed; unstabilised ~1.7 deg/s, motion_blur.py)
    motion_blur=MotionBlur(angular_velocity_deg_s=hand_shake(0.6, np.ones(3))),
    sensor=PHONE_SENSOR,
    color_matrix=MEAN_CCM,
    white_balance=WhiteBalance(illuminant_k=4700.0, error_mired=0.0),  # Infinigen's mean lamp CCT
    tone_curve=ToneCurve(strength=1.0),  # Brooks et al.'s smoothstep
    # the ISP: a burst merge as HDR+ does by default (Hasinoff et al. 2016: 2-8 frames; assumed 6) and chroma NR
    noise_reduction=NoiseReduction(merge_frames=6, chroma_sigma_px=1.5),
    jpeg=Jpeg(quality=95, subsampling="4:2:0"),  # high in-camera quality (assumed), 4:2:0 as cameras write
    # the residual after the ISP's distortion correction of a phone main camera: mild barrel (assumed); each
    # device draws its own (PHONE_VARIATION)
    distortion=Distortion(k1=-0.02, k2=0.005),
)

PHONE_LOW_LIGHT = replace(
    PHONE,
    name="phone-low-light",
    # a 5 lux room (one dim lamp at night, EV100 = 1): ~3.2 s at f/1.8, ISO 50 -> AE: 1/15 s, ISO ~2400,
    # where a = 1.7e-4 * 2400 / 50 = 8e-3 is near the top of Brooks et al.'s range (0.012)
    exposure=replace(
        PHONE.exposure, reference_shutter_s=_ev100_shutter(5.0, PHONE_F_NUMBER, PHONE_BASE_ISO), max_shutter_s=1 / 15
    ),
    vignetting=Vignetting(corner_stops=0.8),  # ISPs correct less shading at high gain, to spare noise (assumed)
    motion_blur=MotionBlur(angular_velocity_deg_s=hand_shake(1.0, np.ones(3))),  # and twice the shutter time
    white_balance=WhiteBalance(illuminant_k=2700.0, error_mired=-15.0),  # 2700 K warm-white bulb; AWB keeps it warm
    noise_reduction=NoiseReduction(merge_frames=8, chroma_sigma_px=2.0),  # HDR+'s longest default burst (assumed)
)

WEB_PHOTO = CaptureParams(
    name="web-photo",
    base_iso=100.0,
    defocus=replace(PHONE_LENS, f_number=2.0),
    motion_blur=MotionBlur(angular_velocity_deg_s=hand_shake(1.0, np.ones(3))),
    vignetting=Vignetting(corner_stops=0.5),
    exposure=Exposure(
        reference_shutter_s=_ev100_shutter(150.0, 2.0, 100.0),
        target=0.18,
        max_shutter_s=1 / 30,
        iso_min=100.0,
        iso_max=6400.0,
    ),  # fmt: skip
    sensor=replace(PHONE_SENSOR, shot_noise=2e-4, bit_depth=12, black_level=256 / 4095),
    color_matrix=MEAN_CCM,
    white_balance=WhiteBalance(illuminant_k=4700.0),
    tone_curve=ToneCurve(strength=0.8),
    # web photos come from phones (burst merge, chroma NR) and cameras (in-camera NR): a middle value (assumed)
    noise_reduction=NoiseReduction(merge_frames=4, chroma_sigma_px=1.5),
    jpeg=Jpeg(quality=92),
    distortion=Distortion(k1=-0.05, k2=0.01),  # any camera, uncorrected or not (assumed); drawn per photo
    resize=Resize(longest_px=1536),  # services serve 1024-2048 px; never enlarged
    recompress=Jpeg(quality=80),  # services re-encode at q 70-90
)


@dataclass(frozen=True)
class Variation:
    """Per-photo ranges of a profile (``None``: keep the nominal value). Units as in the capture fields."""

    ev_bias_sigma_stops: float | None = None
    """Metering error: ev_bias ~ N(0, sigma) stops, clipped at 2.5 sigma."""
    wb_error_sigma_mired: float | None = None
    """White-balance error ~ N(nominal, sigma) mired, clipped at 2.5 sigma."""
    illuminant_k: tuple[float, float, float, float] | None = None
    """(mean, sd, lo, hi) K: clip-Gaussian light colour temperature."""
    read_noise_log_sigma: float | None = None
    """ln(read noise) deviation from Brooks et al.'s fit ~ N(0, sigma); they use 0.26."""
    wb_gain_red: tuple[float, float] | None = None
    """U(lo, hi) sensor red gain (Brooks et al.: 1.9-2.4)."""
    wb_gain_blue: tuple[float, float] | None = None
    """U(lo, hi) sensor blue gain (Brooks et al.: 1.5-1.9)."""
    shot_noise: tuple[float, float] | None = None
    """log-U(lo, hi) shot-noise factor at base ISO (device to device)."""
    scene_lux: tuple[float, float] | None = None
    """log-U(lo, hi) room illuminance in lux, which sets ``exposure.reference_shutter_s``."""
    random_ccm: bool = False
    """A random convex combination of Brooks et al.'s four camera matrices (as their unprocessing draws)."""
    vignetting_stops: tuple[float, float] | None = None
    tone_strength: tuple[float, float] | None = None
    jpeg_quality: tuple[int, int] | None = None
    resize_longest_px: tuple[int, int] | None = None
    recompress_quality: tuple[int, int] | None = None
    shake_deg_s: tuple[float, float] | None = None
    """log-U(lo, hi) RMS hand-shake pitch / yaw rate in deg/s; the photo's axis and rate from 3 normals
    (:func:`synthleak.render.motion_blur.hand_shake`)."""
    distortion_k1: tuple[float, float] | None = None
    """U(lo, hi) radial k1 (the profile's ``distortion`` must be on)."""
    distortion_k2: tuple[float, float] | None = None
    """U(lo, hi) radial k2."""
    distortion_tangential_sigma: float | None = None
    """p1, p2 ~ N(0, sigma), clipped at 2.5 sigma (a decentred lens element)."""


@dataclass(frozen=True)
class DeviceProfile:
    """A named camera: nominal parameters and per-photo variation."""

    nominal: CaptureParams
    variation: Variation


PHONE_VARIATION = Variation(
    ev_bias_sigma_stops=0.2,  # assumed: AE lands within ~1/3 stop of mid grey
    wb_error_sigma_mired=15.0,  # assumed: ~ +-350 K at 4700 K
    illuminant_k=(4700.0, 700.0, 3500.0, 6500.0),  # Infinigen's lamp colour temperature
    read_noise_log_sigma=0.26,  # Brooks et al.
    scene_lux=(80.0, 300.0),  # assumed: lit living rooms and offices
    shake_deg_s=(0.3, 1.2),  # assumed: residual shake with OIS (unstabilised ~1.7 deg/s, motion_blur.py)
    distortion_k1=(-0.05, 0.01),  # assumed: residual after the ISP's correction, mostly barrel
    distortion_k2=(-0.005, 0.02),  # assumed
    distortion_tangential_sigma=2e-4,  # assumed
)
PROFILES: dict[str, DeviceProfile] = {
    "ideal": DeviceProfile(IDEAL, Variation()),
    "phone": DeviceProfile(PHONE, PHONE_VARIATION),
    "phone-low-light": DeviceProfile(
        PHONE_LOW_LIGHT,
        replace(
            PHONE_VARIATION,
            illuminant_k=(2700.0, 300.0, 2200.0, 3500.0),
            wb_error_sigma_mired=20.0,
            scene_lux=(2.0, 10.0),
            shake_deg_s=(0.5, 2.0),  # assumed: a tired hand at night, 1/15 s; OIS at its limit
        ),  # fmt: skip
    ),
    "web-photo": DeviceProfile(
        WEB_PHOTO,
        Variation(
            ev_bias_sigma_stops=0.5,  # assumed: any camera, any user
            wb_error_sigma_mired=25.0,  # assumed
            illuminant_k=(4700.0, 700.0, 3500.0, 6500.0),  # Infinigen
            read_noise_log_sigma=0.26,  # Brooks et al.
            wb_gain_red=(1.9, 2.4),  # Brooks et al.
            wb_gain_blue=(1.5, 1.9),  # Brooks et al.
            shot_noise=(1e-4, 4e-4),  # full wells of ~2500-10000 e- at base ISO (assumed); Brooks: a >= 1e-4
            scene_lux=(30.0, 500.0),  # assumed
            random_ccm=True,
            vignetting_stops=(0.0, 1.0),  # assumed
            tone_strength=(0.5, 1.0),  # assumed
            jpeg_quality=(85, 95),  # assumed in-camera quality
            resize_longest_px=(1024, 2048),  # as services serve photos
            recompress_quality=(70, 90),  # as services re-encode
            shake_deg_s=(0.2, 4.0),  # assumed: tripods to unstabilised hands
            distortion_k1=(-0.15, 0.05),  # assumed: phones, compacts, action cameras short of fisheye
            distortion_k2=(-0.02, 0.06),  # assumed
            distortion_tangential_sigma=5e-4,  # assumed
        ),
    ),
}
PROFILE_NAMES = tuple(PROFILES)


def _profile(name: str) -> DeviceProfile:
    if name not in PROFILES:
        raise ConfigError(f"capture profile {name!r}: unknown; known profiles: {', '.join(PROFILE_NAMES)}")
    return PROFILES[name]


def profile(name: str) -> CaptureParams:
    """The nominal parameters of profile ``name`` (:class:`ConfigError` naming it when unknown)."""
    return _profile(name).nominal


def draw_device(profile_name: str, seed: int) -> CaptureParams:
    """One photo's parameters: profile ``profile_name`` with its :class:`Variation` drawn from
    ``numpy.random.default_rng(seed)``. Always the same draws in the same order (4 normals, 10 uniforms,
    4 CCM weights, then 3 hand-shake normals and 1 uniform, then 2 uniforms and 2 normals for the lens
    distortion), used or not, so every profile reads the stream the
    same way."""
    prof = _profile(profile_name)
    p, v = prof.nominal, prof.variation
    rng = np.random.default_rng(int(seed))
    z = rng.standard_normal(4)  # ev bias, wb error, illuminant, read noise
    u = rng.random(10)  # red gain, blue gain, shot noise, lux, vignetting, tone, jpeg, resize, recompress, spare
    weights = rng.uniform(1e-8, 1.0, size=4)  # Brooks et al.: uniform convex weights of the 4 matrices
    shake_z, shake_u = rng.standard_normal(3), rng.random()  # drawn after the others: earlier draws unchanged
    lens_u, lens_z = rng.random(2), rng.standard_normal(2)  # k1, k2; p1, p2 (after the others, too)

    def clip_normal(mean: float, sigma: float, k: float) -> float:
        return float(np.clip(mean + sigma * k, mean - 2.5 * sigma, mean + 2.5 * sigma))

    def uniform(rng_: tuple[float, float], t: float) -> float:
        return float(rng_[0] + (rng_[1] - rng_[0]) * t)

    def log_uniform(rng_: tuple[float, float], t: float) -> float:
        return float(math.exp(uniform((math.log(rng_[0]), math.log(rng_[1])), t)))

    def integer(rng_: tuple[int, int], t: float) -> int:
        return int(min(rng_[0] + math.floor(t * (rng_[1] - rng_[0] + 1)), rng_[1]))

    out = p
    if p.exposure is not None:
        exposure = p.exposure
        if v.ev_bias_sigma_stops is not None:
            exposure = replace(exposure, ev_bias_stops=clip_normal(exposure.ev_bias_stops, v.ev_bias_sigma_stops, z[0]))
        if v.scene_lux is not None:
            f_number = p.defocus.f_number if p.defocus is not None else PHONE_F_NUMBER
            lux = log_uniform(v.scene_lux, u[3])
            exposure = replace(exposure, reference_shutter_s=_ev100_shutter(lux, f_number, p.base_iso))
        out = replace(out, exposure=exposure)
    if p.white_balance is not None:
        wb = p.white_balance
        if v.illuminant_k is not None:
            mean, sd, lo, hi = v.illuminant_k
            wb = replace(wb, illuminant_k=float(np.clip(mean + sd * z[2], lo, hi)))
        if v.wb_error_sigma_mired is not None:
            wb = replace(wb, error_mired=clip_normal(wb.error_mired, v.wb_error_sigma_mired, z[1]))
        out = replace(out, white_balance=wb)
    if p.sensor is not None:
        s = p.sensor
        if v.read_noise_log_sigma is not None:
            s = replace(s, read_noise_log_offset=float(v.read_noise_log_sigma * z[3]))
        if v.wb_gain_red is not None:
            s = replace(s, wb_gain_red=uniform(v.wb_gain_red, u[0]))
        if v.wb_gain_blue is not None:
            s = replace(s, wb_gain_blue=uniform(v.wb_gain_blue, u[1]))
        if v.shot_noise is not None:
            s = replace(s, shot_noise=log_uniform(v.shot_noise, u[2]))
        out = replace(out, sensor=s)
    if v.random_ccm:
        w = weights / weights.sum()  # the convex combination term by term (tensordot is a BLAS product)
        terms = [w[k] * np.array(XYZ_TO_CAM_BROOKS[k]) for k in range(4)]
        xyz_to_cam = ((terms[0] + terms[1]) + terms[2]) + terms[3]
        out = replace(out, color_matrix=ColorMatrix(tuple(tuple(r) for r in xyz_to_cam.tolist())))
    if v.vignetting_stops is not None:
        out = replace(out, vignetting=Vignetting(corner_stops=uniform(v.vignetting_stops, u[4])))
    if v.tone_strength is not None:
        strength = round(uniform(v.tone_strength, u[5]), 2)  # 2 decimals: a handful of cached encoder tables
        out = replace(out, tone_curve=ToneCurve(strength=strength))
    if v.jpeg_quality is not None and p.jpeg is not None:
        out = replace(out, jpeg=replace(p.jpeg, quality=integer(v.jpeg_quality, u[6])))
    if v.resize_longest_px is not None and p.resize is not None:
        out = replace(out, resize=replace(p.resize, longest_px=integer(v.resize_longest_px, u[7])))
    if v.recompress_quality is not None and p.recompress is not None:
        out = replace(out, recompress=replace(p.recompress, quality=integer(v.recompress_quality, u[8])))
    if v.shake_deg_s is not None and p.motion_blur is not None:
        shake = hand_shake(log_uniform(v.shake_deg_s, shake_u), shake_z)
        out = replace(out, motion_blur=replace(p.motion_blur, angular_velocity_deg_s=shake))
    if p.distortion is not None:
        lens = p.distortion
        if v.distortion_k1 is not None:
            lens = replace(lens, k1=round(uniform(v.distortion_k1, lens_u[0]), 6))
        if v.distortion_k2 is not None:
            lens = replace(lens, k2=round(uniform(v.distortion_k2, lens_u[1]), 6))
        if v.distortion_tangential_sigma is not None:
            sigma = v.distortion_tangential_sigma
            lens = replace(lens, p1=round(clip_normal(0.0, sigma, lens_z[0]), 8),
                           p2=round(clip_normal(0.0, sigma, lens_z[1]), 8))
        out = replace(out, distortion=lens)
    return out
