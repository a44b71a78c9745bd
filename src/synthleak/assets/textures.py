"""Procedural RGB textures (uint8, ``size x size x 3``) for furniture, walls and floors.

Every texture is a pure function of ``(kind, rng state, base_colour, size, options)``: all randomness comes
from the explicit ``numpy.random.Generator`` (derive it with :func:`synthleak.seeding.make_rng`), never from a
global RNG. ``base_colour`` is linear-ish RGB in [0, 1] (what a designer would pick as "the colour").

Textures are meant to be *feature-rich* at the scales a 640x480 camera sees (structures of 5-60 texels with
real contrast, not periodic only): SIFT must find keypoints on them. Kinds (see :data:`TEXTURE_KINDS`):

``wood`` (grain, rings, knots, grain along image rows = u), ``fabric`` (woven threads, slubs, flecks),
``pattern`` (printed motifs on fabric), ``metal`` (brushed, scratches, dents), ``plaster``, ``wallpaper``
(printed repeat), ``parquet`` (planks), ``tiles`` (grout grid), ``concrete``, ``ceramic`` (glaze, speckle,
painted bands), ``paper`` (printed text page), ``print`` (poster/artwork), ``leather``, ``plastic``,
``rubber``, ``glass``, ``marble``, ``foliage``, ``soil``, ``dial`` (clock face).

Options common to all kinds (keyword arguments of :func:`make_texture`): ``colour2`` secondary colour
(motifs, rings, grout...; derived from the base colour when omitted) and ``feature_scale`` (multiplies the
size of the structures, default 1).
"""

from __future__ import annotations

import colorsys
from collections.abc import Callable

import cv2
import numpy as np

from synthleak.portable import cos as pcos
from synthleak.portable import exp as pexp
from synthleak.portable import power as ppow
from synthleak.portable import sin as psin

Colour = tuple[float, float, float]


# ----------------------------------------------------------------------------------------------- helpers
def _fsc(fs: float, size: int) -> float:
    """The ``feature_scale`` option back from the pixel scale ``fs`` (counts per image use it, so a smaller
    texture shows the same picture at lower resolution)."""
    return fs * 512.0 / size


def _noise(
    rng: np.random.Generator,
    size: int,
    cells: float | tuple[float, float],
    octaves: int = 1,
    persistence: float = 0.5,
) -> np.ndarray:
    """Smooth value noise (fBm over ``octaves``), zero mean, unit std, float32 (size, size).

    ``cells`` = number of random lattice cells across (rows, cols); a tuple gives anisotropic noise."""
    cy, cx = (cells, cells) if np.isscalar(cells) else cells
    out = np.zeros((size, size), np.float32)
    amp = 1.0
    for o in range(octaves):
        ny = max(2, int(round(cy * 2**o)) + 1)
        nx = max(2, int(round(cx * 2**o)) + 1)
        grid = rng.standard_normal((ny, nx)).astype(np.float32)
        out += amp * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
        amp *= persistence
    out -= out.mean()
    std = float(out.std())
    return out / std if std > 0 else out


def _colour_img(lum: np.ndarray, base: Colour) -> np.ndarray:
    """Float RGB image = base colour modulated by a luminance field (1 = base)."""
    return lum[..., None] * np.asarray(base, np.float32)[None, None, :]


def _lerp(c1: Colour | np.ndarray, c2: Colour | np.ndarray, t: np.ndarray) -> np.ndarray:
    c1 = np.asarray(c1, np.float32)
    c2 = np.asarray(c2, np.float32)
    return c1 + (c2 - c1) * t[..., None]


def _to_u8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def _shade(c: Colour, f: float) -> Colour:
    return tuple(float(np.clip(v * f, 0.0, 1.0)) for v in c)  # type: ignore[return-value]


def _hsv_rotate(c: Colour, dh: float, ds: float = 0.0, dv: float = 0.0) -> Colour:
    h, s, v = colorsys.rgb_to_hsv(*[float(x) for x in c])
    return colorsys.hsv_to_rgb((h + dh) % 1.0, float(np.clip(s + ds, 0, 1)), float(np.clip(v + dv, 0, 1)))


def _contrast_colour(c: Colour) -> Colour:
    """A default secondary colour that stands out from ``c``."""
    h, s, v = colorsys.rgb_to_hsv(*[float(x) for x in c])
    v2 = v - 0.45 if v > 0.5 else v + 0.45
    return colorsys.hsv_to_rgb((h + 0.5) % 1.0, min(1.0, s + 0.25), float(np.clip(v2, 0.05, 0.95)))


def _palette(rng: np.random.Generator, base: Colour, n: int) -> list[Colour]:
    """``n`` distinct colours harmonising with ``base`` (mixed hue offsets and values)."""
    h, s, v = colorsys.rgb_to_hsv(*[float(x) for x in base])
    out = []
    for _ in range(n):
        hh = (h + rng.choice([-0.33, -0.12, 0.08, 0.17, 0.5]) + rng.normal(0, 0.03)) % 1.0
        ss = float(np.clip(s + rng.uniform(-0.2, 0.5), 0.15, 1.0))
        vv = float(np.clip(v + rng.choice([-1, 1]) * rng.uniform(0.25, 0.5), 0.08, 0.97))
        out.append(colorsys.hsv_to_rgb(hh, ss, vv))
    return out


def _rgb255(c: Colour | np.ndarray) -> tuple[float, float, float]:
    return tuple(float(x) for x in np.clip(np.asarray(c) * 255.0, 0, 255))  # type: ignore[return-value]


def _draw_motifs(
    img8: np.ndarray,
    rng: np.random.Generator,
    colours: list[Colour],
    count: int,
    rmin: float,
    rmax: float,
    shapes=("circle", "leaf", "flower", "dot", "stroke", "ring", "tri"),
) -> None:
    """Scatter random motifs (anti-aliased) onto a uint8 image, in place."""
    size = img8.shape[0]
    for _ in range(count):
        col = _rgb255(colours[int(rng.integers(len(colours)))])
        cx, cy = rng.uniform(0, size, 2)
        r = rng.uniform(rmin, rmax)
        shape = shapes[int(rng.integers(len(shapes)))]
        ang = rng.uniform(0, 360)
        c = (int(cx * 16), int(cy * 16))
        if shape == "circle":
            cv2.circle(img8, c, int(r * 16), col, -1, cv2.LINE_AA, 4)
        elif shape == "ring":
            cv2.circle(img8, c, int(r * 16), col, max(2, int(r / 4)), cv2.LINE_AA, 4)
        elif shape == "dot":
            cv2.circle(img8, c, int(max(2.0, r / 3) * 16), col, -1, cv2.LINE_AA, 4)
        elif shape == "leaf":
            cv2.ellipse(img8, c, (int(r * 16), int(r * 0.35 * 16)), ang, 0, 360, col, -1, cv2.LINE_AA, 4)
        elif shape == "flower":
            for k in range(5):
                a = np.deg2rad(ang + 72 * k)
                pc = (int((cx + 0.6 * r * pcos(a)) * 16), int((cy + 0.6 * r * psin(a)) * 16))
                cv2.ellipse(
                    img8,
                    pc,
                    (int(0.5 * r * 16), int(0.25 * r * 16)),
                    np.rad2deg(a),
                    0,
                    360,
                    col,
                    -1,
                    cv2.LINE_AA,
                    4,
                )
            centre_col = _rgb255(colours[int(rng.integers(len(colours)))])
            cv2.circle(img8, c, int(0.25 * r * 16), centre_col, -1, cv2.LINE_AA, 4)
        elif shape == "stroke":
            n = int(rng.integers(3, 7))
            pts = np.cumsum(rng.normal(0, r * 0.6, (n, 2)), axis=0) + [cx, cy]
            cv2.polylines(img8, [np.int32(pts * 16)], False, col, max(2, int(r / 5)), cv2.LINE_AA, 4)
        else:  # triangle
            a0 = np.deg2rad(ang)
            pts = np.array(
                [[cx + r * pcos(a0 + k * 2.094), cy + r * psin(a0 + k * 2.094)] for k in range(3)]
            )
            cv2.fillPoly(img8, [np.int32(pts * 16)], col, cv2.LINE_AA, 4)


def _speckle(rng: np.random.Generator, size: int, density: float, rmax: float = 2.0) -> np.ndarray:
    """Float mask in [0, 1] of random small blurred dots."""
    mask = np.zeros((size, size), np.float32)
    n = int(density * size * size / 1000.0)
    for _ in range(n):
        x, y = rng.integers(0, size, 2)
        cv2.circle(
            mask,
            (int(x), int(y)),
            int(rng.integers(1, max(2, int(rmax)) + 1)),
            float(rng.uniform(0.5, 1.0)),
            -1,
            cv2.LINE_AA,
        )
    return cv2.GaussianBlur(mask, (0, 0), 0.7)


# ----------------------------------------------------------------------------------------------- kinds
def _wood(rng, base, size, c2, fs):
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    warp = _noise(rng, size, (2, 1.5), octaves=3) * 18 * fs
    period = rng.uniform(14, 24) * fs
    d = yy + warp + 0.04 * xx * rng.uniform(-1, 1)
    for _ in range(int(rng.integers(2, 4))):  # flat-sawn "cathedral" arcs
        x0, y0 = rng.uniform(0, size, 2)
        ln = rng.uniform(80, 200) * fs
        d += 60 * fs * pexp(-(((xx - x0) / ln) ** 2)) * pexp(-(((yy - y0) / (70 * fs)) ** 2))
    knots = np.zeros((size, size), np.float32)
    for _ in range(int(rng.integers(6, 11))):  # knots: rings bend around a dark core
        kx, ky = rng.uniform(0, size, 2)
        kr = rng.uniform(4, 13) * fs
        rr = np.sqrt(((xx - kx) / 2.2) ** 2 + (yy - ky) ** 2)
        d += 2.0 * kr * pexp(-((rr / (2.5 * kr)) ** 2)) * np.sign(yy - ky + 1e-3)
        knots = np.maximum(knots, np.clip(2.5 * (1.0 - rr / kr), 0, 1))
    ring = (d / period + 0.15 * _noise(rng, size, (12, 3))) % 1.0
    late = ppow(np.clip((ring - 0.55) / 0.45, 0, 1), 1.5)
    fibre = _noise(rng, size, (90, 3), octaves=2)
    pores = _speckle(rng, size, 5.0, 2.0)
    rays = np.zeros((size, size), np.float32)  # ray flecks: soft elongated spots along the grain (1-4 cm)
    for _ in range(int(500 / _fsc(fs, size))):
        x0, y0 = rng.uniform(0, size, 2)
        ax = (int(rng.uniform(4, 12) * fs * 16), int(rng.uniform(1.5, 3.5) * fs * 16))
        cv2.ellipse(
            rays,
            (int(x0 * 16), int(y0 * 16)),
            ax,
            float(rng.normal(0, 8)),
            0,
            360,
            float(rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.0)),
            -1,
            cv2.LINE_AA,
            4,
        )
    rays = cv2.GaussianBlur(rays, (0, 0), 0.8 * fs)
    blotch = _noise(rng, size, 5, octaves=3)
    t = np.clip(0.5 * late + 0.06 * fibre + 0.07 * blotch + 0.5 * pores + 0.8 * knots, 0, 1)
    img = _lerp(base, c2, t) * (1.0 + 0.06 * blotch[..., None] + 0.25 * rays[..., None])
    return img


def _fabric(rng, base, size, c2, fs):
    p = max(4, int(round(rng.uniform(6, 9) * fs)))
    yy, xx = np.mgrid[0:size, 0:size]
    ci, cj = yy // p, xx // p
    fy, fx = (yy % p + 0.5) / p, (xx % p + 0.5) / p
    twill = rng.random() < 0.5
    over = ((ci + cj) % 2 == 0) if not twill else (((cj - ci) % 4) < 2)
    # thread brightness: each warp (column) / weft (row) thread its own level + slubs along it
    warp_lvl = rng.normal(0, 0.07, size // p + 2)[cj]
    weft_lvl = rng.normal(0, 0.07, size // p + 2)[ci]
    slub_w = _noise(rng, size, (size / 24, size / p / 1.0)) * 0.06
    slub_h = _noise(rng, size, (size / p / 1.0, size / 24)) * 0.06
    prof_w = ppow(pcos((fx - 0.5) * np.pi), 0.6)
    prof_h = ppow(pcos((fy - 0.5) * np.pi), 0.6)
    lum = np.where(over, 0.80 + 0.25 * prof_h + weft_lvl + slub_h, 0.78 + 0.25 * prof_w + warp_lvl + slub_w)
    melange = _noise(rng, size, 10, octaves=3)
    img = _colour_img(lum.astype(np.float32) * (1 + 0.08 * melange), base)
    fleck = _speckle(rng, size, 4.0, 2.5)
    img = img * (1 - fleck[..., None]) + np.asarray(c2, np.float32) * fleck[..., None]
    return img


def _pattern(rng, base, size, c2, fs):
    img = _fabric(rng, base, size, _shade(base, 0.8), fs) * 0.6 + np.asarray(base, np.float32) * 0.4
    img8 = _to_u8(img)
    cols = [c2, *_palette(rng, base, 3)]
    _draw_motifs(img8, rng, cols, int(rng.integers(70, 110) / _fsc(fs, size) ** 2), 7 * fs, 30 * fs)
    _draw_motifs(
        img8, rng, cols, int(160 / _fsc(fs, size) ** 2), 2 * fs, 6 * fs, shapes=("dot", "leaf", "tri")
    )
    return img8.astype(np.float32) / 255.0 * (1 + 0.03 * _noise(rng, size, 40))[..., None]


def _metal(rng, base, size, c2, fs):
    brushed = _noise(rng, size, (size / 1.5, 3), octaves=1) * 0.05 + _noise(rng, size, (120, 2)) * 0.04
    sheen = _noise(rng, size, (2, 3), octaves=2) * 0.10
    blot = _noise(rng, size, 8, octaves=3) * 0.05
    lum = 1.0 + brushed + sheen + blot
    img = _colour_img(lum, base)
    scratches = np.zeros((size, size), np.float32)
    for _ in range(int(rng.integers(140, 220))):
        x0, y0 = rng.uniform(0, size, 2)
        ln = rng.exponential(35 * fs) + 5
        a = rng.uniform(0, np.pi) if rng.random() < 0.6 else rng.normal(0, 0.08)
        x1, y1 = x0 + ln * pcos(a), y0 + ln * psin(a)
        cv2.line(
            scratches,
            (int(x0 * 16), int(y0 * 16)),
            (int(x1 * 16), int(y1 * 16)),
            float(rng.choice([-1, 1]) * rng.uniform(0.25, 0.6)),
            1,
            cv2.LINE_AA,
            4,
        )
    spots = _speckle(rng, size, 0.8, 4) * rng.choice([-1.0, 1.0], size=(1,))[0]
    dents = (_speckle(rng, size, 0.15, 9) > 0.3).astype(np.float32)
    dents = cv2.GaussianBlur(dents, (0, 0), 2.0)
    img = (
        img
        + 0.35 * scratches[..., None]
        + 0.18 * spots[..., None]
        - 0.2 * dents[..., None] * np.asarray(base)
    )
    tint = np.asarray(c2, np.float32)
    stain = np.clip(_noise(rng, size, 6, octaves=2) - 1.2, 0, 1)[..., None]
    return img * (1 - 0.5 * stain) + tint * 0.5 * stain


def _plaster(rng, base, size, c2, fs):
    lum = 1.0 + 0.05 * _noise(rng, size, 6, octaves=4) + 0.04 * _noise(rng, size, (30, 10), octaves=2)
    pits = _speckle(rng, size, 1.5, 2.5)
    trowel = np.clip(_noise(rng, size, (4, 9), octaves=3), 0.6, 2.0) - 0.6
    lum = lum - 0.35 * pits + 0.09 * trowel
    img = _colour_img(lum, base)
    stain = np.clip(_noise(rng, size, 3, octaves=3) - 1.0, 0, 1)[..., None] * 0.3
    return img * (1 - stain) + np.asarray(c2, np.float32) * stain


def _wallpaper(rng, base, size, c2, fs):
    reps = int(rng.integers(3, 6))
    cell = size // reps
    tile = np.zeros((cell, cell, 3), np.uint8)
    tile[:] = _to_u8(np.asarray(base, np.float32))
    cols = [c2, *_palette(rng, base, 2)]
    _draw_motifs(
        tile, rng, cols, 10, cell * 0.06, cell * 0.22, shapes=("flower", "leaf", "ring", "dot", "stroke")
    )
    img = np.tile(tile, (reps + 1, reps + 1, 1))
    shift = cell // 2
    for r in range(1, reps + 1, 2):  # half-drop repeat
        img[r * cell : (r + 1) * cell] = np.roll(img[r * cell : (r + 1) * cell], shift, axis=1)
    img = img[:size, :size].astype(np.float32) / 255.0
    paper = 1.0 + 0.04 * _noise(rng, size, 60) + 0.05 * _noise(rng, size, 5, octaves=2)
    return img * paper[..., None]


def _parquet(rng, base, size, c2, fs):
    plank_w = int(round(rng.uniform(36, 52) * fs))
    n_rows = size // plank_w + 2
    yy, xx = np.mgrid[0:size, 0:size]
    row = yy // plank_w
    row_off = rng.uniform(0, 400, n_rows)
    length = rng.uniform(150, 320, n_rows) * fs
    pos = xx + row_off[row]
    plank = (pos // length[row]).astype(np.int64)
    pid = (row * 97 + plank) % 997
    tint = rng.normal(0, 0.07, 997)[pid]
    phase = rng.uniform(0, 100, 997)[pid]
    grain = _wood(rng, base, size, c2, fs)
    # per-plank shift of the grain: sample the grain image at a plank-dependent row offset
    src_y = ((yy + phase).astype(np.int64)) % size
    img = grain[src_y, xx] * (1 + tint)[..., None]
    gap = (((yy % plank_w) < 2) | ((pos % length[row]) < 2)).astype(np.float32)
    gap = cv2.GaussianBlur(gap, (0, 0), 0.6)
    return img * (1 - 0.6 * gap[..., None])


def _tiles(rng, base, size, c2, fs):
    n = max(2, int(round(rng.integers(3, 7) / _fsc(fs, size))))
    cell = size / n
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    ti, tj = (yy // cell).astype(int), (xx // cell).astype(int)
    tint = rng.normal(0, 0.05, (n + 1, n + 1))[ti, tj]
    glaze = 0.05 * _noise(rng, size, n * 3, octaves=2)
    lum = 1 + tint + glaze - 0.35 * _speckle(rng, size, 1.0, 1.5)
    accent = (rng.random((n + 1, n + 1)) < 0.25)[ti, tj].astype(np.float32)  # some tiles in a second glaze
    img = _lerp(base, _palette(rng, base, 1)[0], 0.7 * accent) * lum[..., None]
    gw = max(2.0, 4 * fs)
    grout = (((yy % cell) < gw) | ((xx % cell) < gw)).astype(np.float32)
    grout = cv2.GaussianBlur(grout, (0, 0), 0.8)[..., None]
    gcol = np.asarray(c2, np.float32) * (1 + 0.1 * _noise(rng, size, 40))[..., None]
    return img * (1 - grout) + gcol * grout


def _concrete(rng, base, size, c2, fs):
    lum = 1.0 + 0.08 * _noise(rng, size, 8, octaves=4) + 0.05 * _noise(rng, size, 60)
    pores = _speckle(rng, size, 3.0, 2.0)
    aggregate = _speckle(rng, size, 1.5, 3.0)
    lum = lum - 0.45 * pores + 0.15 * aggregate
    img = _colour_img(lum, base)
    stain = np.clip(_noise(rng, size, 3, octaves=3) - 0.8, 0, 1)[..., None] * 0.35
    return img * (1 - stain) + np.asarray(c2, np.float32) * stain


def _ceramic(rng, base, size, c2, fs):
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    lum = 1.0 + 0.06 * _noise(rng, size, 4, octaves=3) + 0.05 * _noise(rng, size, (3, 40))  # drips (vertical)
    img = _colour_img(lum, base)
    n_bands = int(rng.integers(1, 4))
    for _ in range(n_bands):  # painted horizontal bands (v = rows)
        y0 = rng.uniform(0, size)
        w = rng.uniform(6, 22) * fs
        wav = y0 + 6 * psin(xx / size * 2 * np.pi * rng.integers(2, 6) + rng.uniform(0, 6))
        band = ppow(np.clip(1 - np.abs(yy - wav) / w, 0, 1), 0.3)
        img = img * (1 - band[..., None]) + np.asarray(c2, np.float32) * band[..., None]
    img8 = _to_u8(img)
    _draw_motifs(
        img8,
        rng,
        [c2, *_palette(rng, base, 2)],
        int(90 / _fsc(fs, size) ** 2),
        5 * fs,
        18 * fs,
        shapes=("flower", "leaf", "dot", "stroke"),
    )
    img = img8.astype(np.float32) / 255.0
    spk = _speckle(rng, size, 1.5, 1.5)[..., None]
    return img * (1 - 0.6 * spk)


def _paper(rng, base, size, c2, fs):
    lum = 1.0 + 0.03 * _noise(rng, size, (80, 20)) + 0.03 * _noise(rng, size, 5, octaves=2)
    img8 = _to_u8(_colour_img(lum, base))
    ink = _rgb255(c2)
    y = int(size * 0.08)
    margin = int(size * 0.08)
    while y < size - margin:
        lh = int(rng.integers(7, 11) * fs)
        if rng.random() < 0.12:  # paragraph break or figure
            if rng.random() < 0.4:
                h = int(rng.integers(40, 100))
                sub = img8[y : y + h, margin : size - margin]
                _draw_motifs(sub, rng, _palette(rng, base, 3), 12, 4, 18)
                cv2.rectangle(img8, (margin, y), (size - margin, min(size - 1, y + h)), ink, 1)
                y += h + lh
            y += lh
            continue
        x = margin
        xend = size - margin - int(rng.integers(0, size // 4) if rng.random() < 0.2 else 0)
        while x < xend:
            w = int(rng.integers(6, 38) * fs)
            cv2.rectangle(img8, (x, y), (min(x + w, xend), y + max(2, lh // 2)), ink, -1)
            x += w + int(rng.integers(4, 8))
        y += lh + 4
    return img8.astype(np.float32) / 255.0


def _print(rng, base, size, c2, fs):
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    cols = _palette(rng, base, 5)
    a = rng.uniform(0, 2 * np.pi)
    grad = np.clip(0.5 + 0.5 * (pcos(a) * (xx - 0.5) + psin(a) * (yy - 0.5)) * 1.6, 0, 1)
    img = _lerp(base, cols[0], grad)
    img8 = _to_u8(img * (1 + 0.06 * _noise(rng, size, 6, octaves=3))[..., None])
    for _ in range(int(rng.integers(5, 10))):  # big blocks
        col = _rgb255(cols[int(rng.integers(len(cols)))])
        x0, y0 = rng.integers(0, size, 2)
        w, h = rng.integers(size // 10, size // 3, 2)
        if rng.random() < 0.5:
            cv2.rectangle(img8, (int(x0), int(y0)), (int(x0 + w), int(y0 + h)), col, -1, cv2.LINE_AA)
        else:
            cv2.circle(img8, (int(x0), int(y0)), int(w // 2), col, -1, cv2.LINE_AA)
    _draw_motifs(img8, rng, [c2, *cols], int(120 / _fsc(fs, size) ** 2), 5 * fs, 35 * fs)
    _draw_motifs(
        img8,
        rng,
        [c2, *cols],
        int(200 / _fsc(fs, size) ** 2),
        2 * fs,
        7 * fs,
        shapes=("dot", "stroke", "tri"),
    )
    return img8.astype(np.float32) / 255.0


def _leather(rng, base, size, c2, fs):
    cells = _noise(rng, size, 60 / _fsc(fs, size), octaves=1)
    creases = np.abs(_noise(rng, size, 14 / _fsc(fs, size), octaves=2))
    grain = np.clip(0.35 - creases, 0, 1) / 0.35
    wrinkle = _noise(rng, size, (6, 18), octaves=3)
    lum = 1.0 + 0.05 * cells - 0.35 * grain**2 + 0.08 * wrinkle
    img = _colour_img(lum, base)
    wear = np.clip(_noise(rng, size, 4, octaves=3) - 0.9, 0, 1)[..., None] * 0.5
    return img * (1 - wear) + np.asarray(c2, np.float32) * wear


def _plastic(rng, base, size, c2, fs):
    lum = 1.0 + 0.04 * _noise(rng, size, 100) + 0.05 * _noise(rng, size, 5, octaves=3)
    img = _colour_img(lum, base)
    cols = _palette(rng, base, 3) + [c2]
    for col in cols:  # recycled-plastic flecks
        m = _speckle(rng, size, 0.9, 3.0)[..., None]
        img = img * (1 - m) + np.asarray(col, np.float32) * m
    return img


def _rubber(rng, base, size, c2, fs):
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    period = 24 * fs
    tread = np.abs(((xx + 0.6 * np.abs((yy % (2 * period)) - period)) % period) - period / 2) < period / 6
    lum = 1.0 + 0.35 * tread.astype(np.float32) + 0.1 * _noise(rng, size, 30, octaves=2)
    img = _colour_img(lum, base)
    dirt = _speckle(rng, size, 2.0, 2.0)[..., None]
    return img * (1 - dirt) + np.asarray(c2, np.float32) * dirt


def _glass(rng, base, size, c2, fs):
    lum = 1.0 + 0.03 * _noise(rng, size, 3, octaves=2)
    img = _colour_img(lum, base)
    smudge = np.clip(_noise(rng, size, 10, octaves=3) - 1.2, 0, 1)[..., None] * 0.25
    return img * (1 - smudge) + np.asarray(c2, np.float32) * smudge


def _marble(rng, base, size, c2, fs):
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32) / size
    turb = _noise(rng, size, 3, octaves=5, persistence=0.6)
    a = rng.uniform(0, np.pi)
    v = np.abs(psin((pcos(a) * xx + psin(a) * yy) * rng.uniform(6, 12) / _fsc(fs, size) + 2.2 * turb))
    veins = np.clip(1 - v / 0.12, 0, 1) + 0.4 * np.clip(
        1 - np.abs(_noise(rng, size, 6, octaves=3)) / 0.08, 0, 1
    )
    img = _lerp(base, c2, np.clip(veins, 0, 1) * 0.8)
    return img * (1 + 0.04 * _noise(rng, size, 20, octaves=2))[..., None]


def _foliage(rng, base, size, c2, fs):
    img = _colour_img(1 + 0.1 * _noise(rng, size, 6, octaves=3), base)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float32)
    for _ in range(int(rng.integers(6, 11))):  # veins
        x0 = rng.uniform(0, size)
        curve = (
            x0
            + 30 * psin(yy / size * np.pi * rng.uniform(0.5, 2))
            + 0.3 * (yy - size / 2) * rng.uniform(-1, 1)
        )
        vein = np.clip(1 - np.abs(xx - curve) / 2.5, 0, 1)
        img = img * (1 - 0.5 * vein[..., None]) + np.asarray(c2, np.float32) * 0.5 * vein[..., None]
    spots = _speckle(rng, size, 2.5, 3)[..., None]
    img8 = _to_u8(img * (1 - 0.4 * spots))
    _draw_motifs(
        img8,
        rng,
        [_shade(base, 0.5), _shade(base, 1.5), c2],
        int(60 / _fsc(fs, size) ** 2),
        3 * fs,
        9 * fs,
        shapes=("dot", "leaf", "ring"),
    )  # blemishes, holes, light spots
    return img8.astype(np.float32) / 255.0


def _soil(rng, base, size, c2, fs):
    lum = 1.0 + 0.15 * _noise(rng, size, 30, octaves=3)
    img = _colour_img(lum, base)
    for col, dens in ((c2, 3.0), (_shade(base, 0.4), 4.0), (_shade(base, 1.6), 1.0)):
        m = _speckle(rng, size, dens, 3.0)[..., None]
        img = img * (1 - m) + np.asarray(col, np.float32) * m
    return img


def _dial(rng, base, size, c2, fs):
    """A clock face: tick marks, numerals-like blocks, brand text, printed on paper-like ground."""
    img8 = _to_u8(
        _colour_img(1 + 0.03 * _noise(rng, size, 40) + 0.03 * _noise(rng, size, 4, octaves=2), base)
    )
    ink = _rgb255(c2)
    c = size / 2
    for k in range(60):
        a = 2 * np.pi * k / 60
        r0 = 0.40 * size if k % 5 else 0.36 * size
        p0 = (int((c + r0 * psin(a)) * 16), int((c - r0 * pcos(a)) * 16))
        p1 = (int((c + 0.46 * size * psin(a)) * 16), int((c - 0.46 * size * pcos(a)) * 16))
        cv2.line(img8, p0, p1, ink, 2 if k % 5 else 5, cv2.LINE_AA, 4)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for h in range(1, 13):
        a = 2 * np.pi * h / 12
        txt = str(h)
        (tw, th), _ = cv2.getTextSize(txt, font, size / 400, max(1, size // 170))
        x = c + 0.29 * size * psin(a) - tw / 2
        y = c - 0.29 * size * pcos(a) + th / 2
        cv2.putText(img8, txt, (int(x), int(y)), font, size / 400, ink, max(1, size // 170), cv2.LINE_AA)
    accent = _rgb255(_palette(rng, base, 1)[0])
    cv2.putText(
        img8, "SYNTH", (int(c - size * 0.09), int(c + size * 0.16)), font, size / 900, accent, 1, cv2.LINE_AA
    )
    cv2.circle(img8, (int(c), int(c)), int(size * 0.48), ink, max(2, size // 100), cv2.LINE_AA)
    return img8.astype(np.float32) / 255.0


_KINDS: dict[str, Callable] = {
    "wood": _wood,
    "fabric": _fabric,
    "pattern": _pattern,
    "metal": _metal,
    "plaster": _plaster,
    "wallpaper": _wallpaper,
    "parquet": _parquet,
    "tiles": _tiles,
    "concrete": _concrete,
    "ceramic": _ceramic,
    "paper": _paper,
    "print": _print,
    "leather": _leather,
    "plastic": _plastic,
    "rubber": _rubber,
    "glass": _glass,
    "marble": _marble,
    "foliage": _foliage,
    "soil": _soil,
    "dial": _dial,
}
TEXTURE_KINDS: tuple[str, ...] = tuple(sorted(_KINDS))
"""All kinds :func:`make_texture` accepts."""

_DEFAULT_C2: dict[str, Callable[[Colour], Colour]] = {
    "wood": lambda c: _hsv_rotate(_shade(c, 0.55), 0.0, 0.1),
    "fabric": lambda c: _contrast_colour(c),
    "metal": lambda c: _shade(c, 0.55),
    "plaster": lambda c: _shade(c, 0.8),
    "parquet": lambda c: _hsv_rotate(_shade(c, 0.55), 0.0, 0.1),
    "tiles": lambda c: _shade(c, 0.6) if sum(c) > 1.5 else (0.85, 0.85, 0.82),
    "concrete": lambda c: _shade(c, 0.7),
    "paper": lambda c: (0.08, 0.08, 0.1),
    "leather": lambda c: _shade(c, 1.35),
    "rubber": lambda c: (0.35, 0.3, 0.25),
    "glass": lambda c: _shade(c, 0.85),
    "marble": lambda c: _shade(c, 0.35),
    "foliage": lambda c: _hsv_rotate(_shade(c, 1.4), 0.03, -0.2),
    "soil": lambda c: _shade(c, 1.8),
    "dial": lambda c: (0.05, 0.05, 0.06),
}


def make_texture(
    kind: str,
    rng: np.random.Generator,
    base_colour: tuple[float, float, float],
    size: int = 512,
    *,
    colour2: tuple[float, float, float] | None = None,
    feature_scale: float = 1.0,
) -> np.ndarray:
    """A procedural ``(size, size, 3)`` uint8 texture of ``kind`` around ``base_colour`` (RGB in [0, 1]).

    Raises ``ValueError`` for an unknown kind. ``feature_scale`` scales structure sizes relative to a 512 px
    texture (structures scale with ``size`` automatically)."""
    if kind not in _KINDS:
        raise ValueError(f"unknown texture kind {kind!r}; known: {', '.join(TEXTURE_KINDS)}")
    if size < 16:
        raise ValueError(f"texture size must be >= 16, got {size}")
    base = tuple(float(np.clip(c, 0.0, 1.0)) for c in base_colour)
    if len(base) != 3:
        raise ValueError(f"base_colour must be RGB, got {base_colour!r}")
    c2 = (
        tuple(float(c) for c in colour2)
        if colour2 is not None
        else _DEFAULT_C2.get(kind, _contrast_colour)(base)
    )
    fs = float(feature_scale) * size / 512.0
    img = _KINDS[kind](rng, base, size, c2, fs)
    return _to_u8(np.asarray(img, np.float32)) if img.dtype != np.uint8 else img


def hsv_shift(texture: np.ndarray, dh: float, ds: float, dv: float) -> np.ndarray:
    """Shift hue by ``dh`` turns (wraps), add ``ds`` to saturation and ``dv`` to value (clipped to [0, 1]).

    Returns a new uint8 array; ``(0, 0, 0)`` returns an exact copy."""
    if dh == 0 and ds == 0 and dv == 0:
        return texture.copy()
    hsv = cv2.cvtColor(texture.astype(np.float32) / 255.0, cv2.COLOR_RGB2HSV)  # H in degrees, S, V in [0, 1]
    hsv[..., 0] = (hsv[..., 0] + 360.0 * dh) % 360.0
    hsv[..., 1] = np.clip(hsv[..., 1] + ds, 0.0, 1.0)
    hsv[..., 2] = np.clip(hsv[..., 2] + dv, 0.0, 1.0)
    return _to_u8(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB))
