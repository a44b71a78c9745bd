"""The camera capture model (synthleak.render.capture) and its device profiles: tiny images, real computation."""

from __future__ import annotations

import io
import math
from dataclasses import replace

import numpy as np
import pytest
from PIL import Image, JpegImagePlugin

from synthleak.errors import ConfigError
from synthleak.render import capture as cap
from synthleak.render import devices
from synthleak.render.blender_backend import linear_to_srgb_uint8 as blender_encoding
from synthleak.render.capture import (
    CaptureParams,
    Defocus,
    Exposure,
    Jpeg,
    NoiseReduction,
    Resize,
    Sensor,
    ToneCurve,
    Vignetting,
    WhiteBalance,
    capture,
)
from synthleak.render.mitsuba_backend import linear_to_srgb_uint8

NOISELESS = Sensor(noise=False, bit_depth=16, black_level=0.0)
"""A sensor with mosaic, filter response and ADC but no noise."""


def linear(u8: np.ndarray) -> np.ndarray:
    """Decode a capture (sRGB uint8) back to linear float64."""
    return cap.srgb_decode(np.asarray(u8, dtype=np.float64) / 255.0)


def flat(value: float | tuple[float, float, float], h: int = 48, w: int = 64) -> np.ndarray:
    return np.broadcast_to(np.asarray(value, dtype=np.float32), (h, w, 3)).copy()


def test_ideal_is_the_pipelines_encoding_byte_for_byte() -> None:
    rng = np.random.default_rng(0)
    x = (rng.random((31, 47, 3), dtype=np.float32) * 1.4 - 0.1).astype(np.float32)
    x[0, 0] = [np.nan, np.inf, -np.inf]
    x[1, :, :] = rng.random((47, 3), dtype=np.float32) * 0.004  # the linear toe of sRGB
    photo = capture(x, devices.IDEAL, seed=7)
    assert photo.rgb.dtype == np.uint8 and photo.rgb.shape == x.shape
    assert photo.rgb.tobytes() == linear_to_srgb_uint8(x).tobytes() == blender_encoding(x).tobytes()
    assert photo.record["effects"] == ["encode"]
    assert devices.draw_device("ideal", 123) == devices.IDEAL and devices.profile("ideal").is_ideal
    x64 = x.astype(np.float64) + 1e-9  # float64 input goes through untouched too
    assert capture(x64, devices.IDEAL, seed=7).rgb.tobytes() == linear_to_srgb_uint8(x64).tobytes()


@pytest.mark.parametrize("strength", [0.0, 0.6, 1.0])
def test_fast_encoder_is_exact_at_every_step(strength: float) -> None:
    """encode_8bit (the non-ideal path's LUT encoder) == pipeline encoding of the tone-mapped value, on both
    sides of each of the 255 steps and on random values."""

    def reference(x32: np.ndarray) -> np.ndarray:
        y = x32.astype(np.float64)
        if strength:
            v = cap.srgb_encode(y)
            y = cap.srgb_decode((1 - strength) * v + strength * v * v * (3 - 2 * v))
        return linear_to_srgb_uint8(y)

    base, inner, _ = cap._encoder_tables(strength)
    sentinel = np.iinfo(np.int32).max
    has_inner = inner != sentinel
    at_start = np.nonzero(np.diff(base.astype(np.int64)) - has_inner[:-1])[0] + 1  # steps on a bucket's first float
    bits = np.concatenate([inner[has_inner].astype(np.int64), at_start.astype(np.int64) << cap._LUT_SHIFT])
    steps = bits.astype(np.int32).view(np.float32)
    assert len(steps) == 255
    below = np.nextafter(steps, np.float32(0.0))
    rng = np.random.default_rng(1)
    samples = np.concatenate([steps, below, rng.random(30000, dtype=np.float32) * 1.3 - 0.1,
                              np.float32([0.0, -0.0, 1.0, 2.0, 3e38, -5.0])])  # fmt: skip
    samples = np.ascontiguousarray(np.repeat(samples[:, None, None], 3, axis=2), dtype=np.float32)
    assert np.array_equal(cap.encode_8bit(samples, strength), reference(samples))
    ref = reference(np.ascontiguousarray(np.repeat(np.stack([below, steps], 1)[:, :, None], 3, axis=2)))
    assert np.all(ref[:, 1, 0].astype(int) - ref[:, 0, 0] == 1)  # they are the steps: one level up each


def test_same_seed_same_bytes_other_seed_other_bytes() -> None:
    rng = np.random.default_rng(2)
    x = (0.05 + 0.3 * rng.random((32, 40, 3), dtype=np.float32)).astype(np.float32)
    depth = np.linspace(0.5, 6.0, 32 * 40, dtype=np.float32).reshape(32, 40)
    for name in ("phone", "phone-low-light", "web-photo"):
        params = devices.draw_device(name, 11)
        assert params == devices.draw_device(name, 11)
        first = capture(x, params, seed=5, depth=depth)
        again = capture(x, params, seed=5, depth=depth)
        other = capture(x, params, seed=6, depth=depth)
        assert first.rgb.tobytes() == again.rgb.tobytes() and first.record == again.record
        assert first.rgb.tobytes() != other.rgb.tobytes()
        assert first.rgb.tobytes() != capture(x, devices.draw_device(name, 12), seed=5, depth=depth).rgb.tobytes()


def test_raw_noise_variance_is_poisson_gaussian_in_iso() -> None:
    """var = a x + b with a proportional to ISO and b = exp(1.20) a^2.18 (Brooks et al. 2019)."""
    sensor = Sensor(shot_noise=1e-4)
    rng = np.random.default_rng(3)
    a_of = {}
    for iso in (100.0, 800.0, 3200.0):
        a, b = cap.noise_params(sensor, iso, 100.0)
        assert a == pytest.approx(1e-4 * iso / 100.0)
        assert b == pytest.approx(math.exp(1.20) * a**2.18)
        means, variances = [], []
        for level in (0.02, 0.1, 0.4):
            patch = np.full((160, 160), level, dtype=np.float32)
            noisy = cap.add_sensor_noise(patch, a, b, rng)
            means.append(noisy.mean())
            variances.append(noisy.var())
            assert noisy.mean() == pytest.approx(level, rel=0.01, abs=2e-4)
            assert noisy.var() == pytest.approx(a * level + b, rel=0.06)
        slope, intercept = np.polyfit(means, variances, 1)
        assert slope == pytest.approx(a, rel=0.08)
        a_of[iso] = slope
    assert a_of[100.0] < a_of[800.0] < a_of[3200.0]


def test_noise_in_the_photo_grows_with_iso() -> None:
    """End to end (no mosaic, 16-bit ADC, no tone curve): the photo's linear variance on a grey patch follows
    a x + b at the ISO the exposure fixed, plus 8-bit quantisation."""
    level, base_iso, ref = 0.2, 100.0, 0.01
    stds = []
    for iso in (400.0, 1600.0, 6400.0):
        exposure = Exposure(reference_shutter_s=ref, manual_iso=iso, manual_shutter_s=ref * base_iso / iso)
        params = CaptureParams(
            base_iso=base_iso,
            exposure=exposure,
            sensor=Sensor(shot_noise=1e-4, bayer=False, bit_depth=16, black_level=0.05, wb_gain_red=1.0,
                          wb_gain_blue=1.0),
        )  # fmt: skip
        photo = capture(flat(level, 64, 64), params, seed=4)
        assert photo.record["iso"] == iso and photo.record["exposure_gain"] == pytest.approx(1.0)
        a, b = photo.record["noise_a"], photo.record["noise_b"]
        values = linear(photo.rgb)
        step = (cap.srgb_decode(np.array([128 / 255])) - cap.srgb_decode(np.array([127 / 255])))[0]
        assert values.mean() == pytest.approx(level, rel=0.02)
        assert values.var() == pytest.approx(a * level + b + step**2 / 12, rel=0.1)
        stds.append(values.std())
    assert stds[0] < stds[1] < stds[2]


def test_burst_merge_divides_the_noise_variance_and_chroma_nr_keeps_luminance() -> None:
    """A merge of N frames: the photo's linear noise variance on a grey patch is 1/N of one frame's (HDR+,
    Hasinoff et al. 2016); chroma NR then cuts the colour noise (channel minus luminance) but not the mean."""
    level, base_iso, ref, iso = 0.2, 100.0, 0.01, 3200.0
    exposure = Exposure(reference_shutter_s=ref, manual_iso=iso, manual_shutter_s=ref * base_iso / iso)
    sensor = Sensor(shot_noise=1e-4, bayer=False, bit_depth=16, black_level=0.05, wb_gain_red=1.0, wb_gain_blue=1.0)
    one = CaptureParams(base_iso=base_iso, exposure=exposure, sensor=sensor)
    variances = {}
    for frames in (1, 4):
        params = replace(one, noise_reduction=NoiseReduction(merge_frames=frames))
        photo = capture(flat(level, 96, 96), params, seed=5)
        assert photo.record.get("merge_frames", 1) == frames
        variances[frames] = linear(photo.rgb).var()
    assert variances[4] == pytest.approx(variances[1] / 4, rel=0.15)
    plain = linear(capture(flat(level, 96, 96), one, seed=6).rgb)
    smooth = capture(flat(level, 96, 96), replace(one, noise_reduction=NoiseReduction(chroma_sigma_px=2.0)), seed=6)
    assert "chroma_denoise" in smooth.record["effects"]
    smooth_lin = linear(smooth.rgb)

    def chroma(x: np.ndarray) -> float:
        return float((x - x.mean(axis=2, keepdims=True)).std())

    assert chroma(smooth_lin) < 0.5 * chroma(plain)
    assert smooth_lin.mean() == pytest.approx(plain.mean(), rel=0.01)


def test_phone_profiles_merge_bursts_and_denoise_chroma() -> None:
    for name in ("phone", "phone-low-light", "web-photo"):
        nr = devices.profile(name).noise_reduction
        assert nr is not None and nr.merge_frames >= 4 and nr.chroma_sigma_px > 0, name
    assert devices.profile("ideal").noise_reduction is None


def grey_texture(scale: float, h: int = 64, w: int = 64) -> np.ndarray:
    v, u = np.mgrid[0:h, 0:w]
    t = scale * (1.0 + 0.5 * np.sin(u * 0.7) * np.cos(v * 0.45))
    return np.repeat(t[..., None], 3, axis=2).astype(np.float32)


def test_auto_exposure_brings_a_dark_frames_median_to_the_target() -> None:
    dark = grey_texture(0.01)
    exposure = Exposure(reference_shutter_s=1 / 60, target=0.18, min_shutter_s=1e-4, max_shutter_s=1.0,
                        iso_min=100.0, iso_max=12800.0)  # fmt: skip
    photo = capture(dark, CaptureParams(exposure=exposure), seed=0)
    assert float(np.median(linear(photo.rgb)[..., 1])) == pytest.approx(0.18, rel=0.03)
    assert photo.record["exposure_shortfall_stops"] == pytest.approx(0.0)
    assert photo.record["shutter_s"] == pytest.approx(1 / 60 * 18, rel=0.05) and photo.record["iso"] == 100.0
    brighter = capture(dark, CaptureParams(exposure=replace(exposure, ev_bias_stops=1.0)), seed=0)
    assert float(np.median(linear(brighter.rgb)[..., 1])) == pytest.approx(0.36, rel=0.03)
    # limits: 1/30 s and ISO 400 give 2 * 4 = 8x of the ~18x wanted: the shortfall is recorded and shows
    capped = replace(exposure, max_shutter_s=1 / 30, iso_max=400.0)
    short = capture(dark, CaptureParams(exposure=capped), seed=0)
    assert short.record["iso"] == 400.0 and short.record["shutter_s"] == pytest.approx(1 / 30)
    shortfall = short.record["exposure_shortfall_stops"]
    assert shortfall > 1.0
    assert float(np.median(linear(short.rgb)[..., 1])) == pytest.approx(0.18 * 2**-shortfall, rel=0.04)


def test_white_balance_error_shifts_grey_warm_or_cool() -> None:
    grey = flat(0.18, 32, 32)
    base = CaptureParams(sensor=NOISELESS, color_matrix=devices.MEAN_CCM)

    def rgb_mean(error_mired: float) -> np.ndarray:
        wb = WhiteBalance(illuminant_k=4700.0, error_mired=error_mired)
        return capture(grey, replace(base, white_balance=wb), seed=0).rgb.reshape(-1, 3).astype(float).mean(0)

    neutral, cool, warm = rgb_mean(0.0), rgb_mean(30.0), rgb_mean(-30.0)
    assert np.ptp(neutral) <= 1.0  # the ISP undoes sensor response and camera matrix exactly
    assert cool[2] - cool[0] > 10  # estimate warmer than the light: the photo turns blue
    assert warm[0] - warm[2] > 10  # estimate cooler: orange
    assert abs(cool[1] - neutral[1]) < 4 and abs(warm[1] - neutral[1]) < 4  # von Kries: green-normalised
    r3000, r6500 = cap.planckian_rgb(3000.0), cap.planckian_rgb(6500.0)
    assert r3000[0] > r3000[2] and r6500[2] > r3000[2]
    x, y = cap.planckian_xy(6504.0)  # near D65's (0.3127, 0.3290), below it on the locus
    assert x == pytest.approx(0.3135, abs=2e-3) and y == pytest.approx(0.3237, abs=2e-3)


def test_demosaic_keeps_a_flat_colour() -> None:
    """RGGB mosaic + OpenCV demosaic give the input colour back (catches a swapped Bayer code)."""
    colour = (0.5, 0.2, 0.05)
    for demosaic in ("bilinear", "edge-aware"):
        params = CaptureParams(sensor=replace(NOISELESS, demosaic=demosaic))
        out = capture(flat(colour, 16, 16), params, seed=0).rgb[4:-4, 4:-4]
        assert np.abs(out.astype(int) - linear_to_srgb_uint8(flat(colour, 8, 8)).astype(int)).max() <= 1


@pytest.mark.parametrize("stops", [0.5, 1.0, 2.0])
def test_vignetting_darkens_corners_by_the_configured_stops(stops: float) -> None:
    photo = capture(flat(0.3, 48, 64), CaptureParams(vignetting=Vignetting(corner_stops=stops)), seed=0)
    lin = linear(photo.rgb)[..., 1]
    corners = np.array([lin[0, 0], lin[0, -1], lin[-1, 0], lin[-1, -1]])
    centre = lin[23:25, 31:33].mean()
    assert np.log2(corners / centre) == pytest.approx(np.full(4, -stops), abs=0.03)  # 8-bit steps


def edge_width(row: np.ndarray) -> float:
    """10-90 % rise width (px) of a dark-to-bright step, linearly interpolated."""
    lo, hi = row.min(), row.max()
    norm = (row - lo) / (hi - lo)
    positions = np.arange(len(row), dtype=float)
    return float(np.interp(0.9, norm, positions) - np.interp(0.1, norm, positions))


def test_defocus_blurs_out_of_focus_depth_more() -> None:
    h, w = 64, 128
    x = flat(0.05, h, w)
    x[:, w // 2 :] = 0.6
    depth = np.full((h, w), 1.0, dtype=np.float32)
    depth[h // 2 :] = 8.0
    lens = Defocus(f_number=1.4, focal_length_mm=50.0, sensor_width_mm=36.0, focus_distance_m=1.0)
    coc = cap.circle_of_confusion_px(np.array([1.0, 8.0, np.inf]), lens, 1.0, w)
    expected = (50 / 1.4) * 50 * (7000 / 8000) / 950 * w / 36  # thin lens, by hand: ~5.8 px at 8 m
    assert coc[0] == 0.0 and coc[1] == pytest.approx(expected, rel=1e-4) and coc[2] > coc[1]
    photo = capture(x, CaptureParams(defocus=lens), seed=0, depth=depth)
    g = linear(photo.rgb)[..., 1]
    sharp, blurred = edge_width(g[8]), edge_width(g[h - 8])
    assert sharp <= 1.0
    assert 0.5 * expected <= blurred <= 1.1 * expected  # a disc of diameter d: 10-90 % over ~0.7 d
    assert photo.record["focus_distance_m"] == 1.0
    scene = np.full((h, w), 3.0, dtype=np.float32)
    scene[:, :40] = 0.5  # outside the central fifth
    scene[30:34, 60:68] = np.inf  # no depth: ignored
    auto = capture(x, CaptureParams(defocus=replace(lens, focus_distance_m=None)), seed=0, depth=scene)
    assert auto.record["focus_distance_m"] == 3.0  # autofocus: median finite depth of the central fifth
    with pytest.raises(ConfigError, match="defocus"):
        capture(x, CaptureParams(defocus=lens), seed=0)


def test_jpeg_is_deterministic_and_decodes() -> None:
    rng = np.random.default_rng(5)
    rgb = (rng.random((24, 40, 3)) * 255).astype(np.uint8)
    data = cap.encode_jpeg(rgb, Jpeg(quality=80))
    assert data == cap.encode_jpeg(rgb, Jpeg(quality=80))
    with Image.open(io.BytesIO(data)) as im:
        assert im.format == "JPEG" and im.size == (40, 24)
        assert JpegImagePlugin.get_sampling(im) == 2  # 4:2:0
    assert len(cap.encode_jpeg(rgb, Jpeg(quality=30))) < len(data)
    params = CaptureParams(tone_curve=ToneCurve(0.5), jpeg=Jpeg(quality=75))
    x = rng.random((24, 40, 3), dtype=np.float32)
    first, second = capture(x, params, seed=1), capture(x, params, seed=1)
    assert first.rgb.tobytes() == second.rgb.tobytes()
    assert first.record["jpeg_bytes"] > 0
    assert not np.array_equal(first.rgb, capture(x, replace(params, jpeg=None), seed=1).rgb)


def test_resize_to_the_longest_side() -> None:
    x = np.random.default_rng(6).random((48, 64, 3), dtype=np.float32)
    photo = capture(x, CaptureParams(resize=Resize(longest_px=32), recompress=Jpeg(quality=85)), seed=0)
    assert photo.rgb.shape == (24, 32, 3) and photo.record["resize_scale"] == [0.5, 0.5]
    assert capture(x, CaptureParams(resize=Resize(longest_px=128)), seed=0).rgb.shape == (48, 64, 3)
    assert capture(x, CaptureParams(resize=Resize(longest_px=128, upscale=True)), seed=0).rgb.shape == (96, 128, 3)


def test_draw_device_stays_within_the_profiles_ranges() -> None:
    qualities, sizes, recompress = set(), set(), set()
    for seed in range(40):
        p = devices.draw_device("web-photo", seed)
        assert 85 <= p.jpeg.quality <= 95 and 1024 <= p.resize.longest_px <= 2048
        assert 70 <= p.recompress.quality <= 90 and 1.9 <= p.sensor.wb_gain_red <= 2.4
        assert 3500.0 <= p.white_balance.illuminant_k <= 6500.0
        qualities.add(p.jpeg.quality)
        sizes.add(p.resize.longest_px)
        recompress.add(p.recompress.quality)
    assert len(qualities) > 3 and len(sizes) > 10 and len(recompress) > 5
    assert devices.draw_device("phone", 1).sensor.read_noise_log_offset != 0.0
    # phone-low-light at its nominal light: ISO near 2400 and a near the top of Brooks et al.'s range
    nominal = devices.profile("phone-low-light")
    chosen = cap.choose_exposure(0.18, nominal.exposure, nominal.base_iso)
    assert chosen["shutter_s"] == pytest.approx(1 / 15) and 2000 < chosen["iso"] < 3000
    assert 1e-3 < cap.noise_params(nominal.sensor, chosen["iso"], nominal.base_iso)[0] < 0.012


def test_pyrender_output_linearises_by_gamma_2_2() -> None:
    x = np.linspace(0.0, 1.0, 300, dtype=np.float32).reshape(10, 10, 3)
    pyrender_like = np.rint(255 * np.clip(x, 0, 1) ** (1 / 2.2)).astype(np.uint8)  # its shader, then GL rounding
    assert np.abs(cap.gamma22_to_linear(pyrender_like) - x).max() < 0.01
    assert np.abs(cap.srgb8_to_linear(linear_to_srgb_uint8(x)) - x).max() < 0.005


@pytest.mark.parametrize(
    ("make", "field"),
    [
        (lambda: Exposure(reference_shutter_s=0.01, iso_min=-100.0), "exposure.iso_min"),
        (lambda: Exposure(reference_shutter_s=0.01, iso_min=800.0, iso_max=400.0), "exposure.iso_max"),
        (lambda: Exposure(reference_shutter_s=-1.0), "exposure.reference_shutter_s"),
        (lambda: Sensor(shot_noise=-1e-4), "sensor.shot_noise"),
        (lambda: Sensor(demosaic="vng"), "sensor.demosaic"),
        (lambda: Sensor(bit_depth=20), "sensor.bit_depth"),
        (lambda: WhiteBalance(illuminant_k=500.0), "white_balance.illuminant_k"),
        (lambda: WhiteBalance(illuminant_k=20000.0, error_mired=-60.0), "white_balance.error_mired"),
        (lambda: Jpeg(quality=120), "jpeg.quality"),
        (lambda: Jpeg(subsampling="4:1:1"), "jpeg.subsampling"),
        (lambda: Resize(longest_px=0), "resize.longest_px"),
        (lambda: NoiseReduction(merge_frames=0), "noise_reduction.merge_frames"),
        (lambda: NoiseReduction(merge_frames=2.5), "noise_reduction.merge_frames"),
        (lambda: NoiseReduction(chroma_sigma_px=-1.0), "noise_reduction.chroma_sigma_px"),
        (lambda: Vignetting(corner_stops=-1.0), "vignetting.corner_stops"),
        (lambda: ToneCurve(strength=1.5), "tone_curve.strength"),
        (lambda: Defocus(f_number=0.0, focal_length_mm=5.0, sensor_width_mm=6.0), "defocus.f_number"),
        (lambda: CaptureParams(base_iso=-50.0), "capture.base_iso"),
        (lambda: CaptureParams(sensor="phone"), "capture.sensor"),
        (lambda: devices.draw_device("dslr", 0), "'dslr'"),
        (lambda: devices.profile("Phone"), "'Phone'"),
    ],
)
def test_parameter_errors_name_the_field(make, field: str) -> None:  # noqa: ANN001
    with pytest.raises(ConfigError) as info:
        make()
    assert field in str(info.value)
