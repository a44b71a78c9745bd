"""Decor: vases, desk organizer, wall hangings (framed picture, mirror, clock), plant pot.

Wall hangings: front faces +y; the back is one flat face at y = -depth / 2 in the canonical frame (the scene
puts that plane against the wall); origin at the bottom centre as for every model.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import PchipInterpolator

from synthleak.assets import primitives as prim
from synthleak.assets.builders.base import PartBuilder, builder


@builder(
    "vase",
    materials=("body",),
    params={"belly_height_frac": None, "neck_frac": None, "lip_frac": None, "foot_frac": 0.6, "wall": 0.006},
)
def vase(b: PartBuilder, p: dict[str, float]) -> None:
    """Turned vase: smooth profile (foot, belly at max radius = width/2, neck, lip), open top, thick wall."""
    W, H = p["width"], p["height"]
    R = W / 2
    zb = H * p["belly_height_frac"]
    zn = min(H * 0.9, zb + 0.55 * (H - zb))
    ctrl_z = [0.0, zb, zn, H]
    ctrl_r = [R * p["foot_frac"], R, R * p["neck_frac"], R * p["lip_frac"]]
    f = PchipInterpolator(ctrl_z, ctrl_r)
    z = np.linspace(0, H, 24)
    r = np.minimum(f(z), R)
    w = p["wall"]
    outer = list(zip(r, z, strict=True))
    zi = np.linspace(H, max(0.015, H * 0.08), 12)
    inner = [(max(float(f(zz)) - w, 0.004), float(zz)) for zz in zi]
    prof = [(0.0, 0.0), *outer, *inner, (0.0, inner[-1][1])]
    b.revolve("body", prof, segments=32)


@builder("desk_organizer", materials=("body", "items", "paper"), params={"n_pencils": 6, "wall": 0.008})
def desk_organizer(b: PartBuilder, p: dict[str, float]) -> None:
    """Desk organizer: tray with compartments, a pencil cup with pencils, a note block."""
    W, D, H = p["width"], p["depth"], p["height"]
    w = p["wall"]
    tray_h = 0.07
    b.box("body", (W, D, w), (0, 0, w / 2))
    for sy in (-1, 1):
        b.box("body", (W, w, tray_h), (0, sy * (D / 2 - w / 2), tray_h / 2))
    for x in (-W / 2 + w / 2, -W / 6, W / 2 - w / 2):
        b.box("body", (w, D - 2 * w, tray_h), (x, 0, tray_h / 2))
    cup_r = min(D / 2 - w - 0.005, 0.045)
    cx = W / 2 - w - cup_r - 0.01
    cup_h = 0.11
    b.revolve(
        "body",
        [(0, 0.0), (cup_r, 0.0), (cup_r, cup_h), (cup_r - 0.004, cup_h), (cup_r - 0.004, 0.01), (0, 0.01)],
        centre=(cx, 0, w),
        segments=24,
    )
    n = int(round(p["n_pencils"]))
    for k in range(n):
        a = 2 * np.pi * k / max(n, 1)
        rr = cup_r * 0.5
        p0 = np.array([cx + rr * np.cos(a), rr * np.sin(a), 0.02])
        d = np.array([rr * np.cos(a) * 0.6, rr * np.sin(a) * 0.6, 0.0])
        d[2] = H - 0.015 * (k % 3) - p0[2]
        d[2] -= (
            0.004 * np.linalg.norm(d[:2]) / np.linalg.norm(d)
        )  # the end cap's rim reaches the target height
        b.bar("items", p0, p0 + d, 0.004, segments=8)
    b.box("paper", (W / 3 - 2 * w - 0.01, D - 2 * w - 0.01, 0.05), (-W / 2 + W / 6 + 0.002, 0, w + 0.025))
    b.box("items", (0.08, D * 0.35, 0.025), (0.02, -D / 4 + 0.01, w + 0.0125))


def _frame_ring(b: PartBuilder, mat: str, W: float, H: float, D: float, fw: float) -> None:
    y = 0.0
    b.box(mat, (W, D, fw), (0, y, fw / 2))
    b.box(mat, (W, D, fw), (0, y, H - fw / 2))
    b.box(mat, (fw, D, H - 2 * fw), (-W / 2 + fw / 2, y, H / 2))
    b.box(mat, (fw, D, H - 2 * fw), (W / 2 - fw / 2, y, H / 2))


@builder("picture_frame", materials=("frame", "print"), params={"frame_width": None, "inset": 0.01})
def picture_frame(b: PartBuilder, p: dict[str, float]) -> None:
    """Framed print: the artwork is stretched over the whole inner panel (uv fit); flat back at y=-depth/2."""
    W, D, H = p["width"], p["depth"], p["height"]
    fw = p["frame_width"]
    _frame_ring(b, "frame", W, H, D, fw)
    b.box_span("print", (-W / 2 + fw, -D / 2, fw), (W / 2 - fw, D / 2 - p["inset"], H - fw), uv_mode="fit")


@builder("mirror", materials=("frame", "glass"), params={"frame_width": None, "glass_inset": 0.008})
def mirror(b: PartBuilder, p: dict[str, float]) -> None:
    """Wall mirror with a wide decorative frame; the glass part is reflective (metallic 1, roughness ~0)."""
    W, D, H = p["width"], p["depth"], p["height"]
    fw = p["frame_width"]
    _frame_ring(b, "frame", W, H, D, fw)
    b.box_span("glass", (-W / 2 + fw, -D / 2, fw), (W / 2 - fw, D / 2 - p["glass_inset"], H - fw))


@builder("clock", materials=("body", "dial", "hands"), params={"rim_frac": 0.08, "hour": 10.15})
def clock(b: PartBuilder, p: dict[str, float]) -> None:
    """Round wall clock: body disc (flat back at y=-depth/2), printed dial (uv fit), hands."""
    W, D, H = p["width"], p["depth"], p["height"]
    R = min(W, H) / 2
    R_dial = R * (1 - p["rim_frac"])
    face = prim.rot_x(-np.pi / 2) @ prim.rot_z(np.pi)  # local +z -> +y (front), texture up -> +z
    b.revolve(
        "body",
        [(0, 0), (R, 0), (R, D), (R_dial, D), (R_dial, D * 0.35), (0, D * 0.35)],
        centre=(0, -D / 2, R),
        rotation=face,
        segments=48,
    )
    b.revolve(
        "dial",
        [(0, 0), (R_dial - 0.001, 0), (R_dial - 0.001, 0.004), (0, 0.004)],
        centre=(0, -D / 2 + D * 0.35 - 0.002, R),
        rotation=face,
        segments=48,
        uv_mode="fit",
    )
    hour = p["hour"] % 12
    y_h = -D / 2 + D * 0.35 + 0.004
    for ang, ln, wd, dy in (
        (hour / 12 * 2 * np.pi, 0.5, 0.012, 0.003),
        ((hour % 1) * 2 * np.pi, 0.75, 0.008, 0.006),
    ):
        L = R_dial * ln
        c = (L / 2 * np.sin(ang), y_h + dy, R + L / 2 * np.cos(ang))
        b.box("hands", (wd, 0.003, L), c, rotation=prim.rot_y(ang))
    b.cylinder("hands", 0.008, 0.012, (0, y_h + 0.006, R), axis=(0, 1, 0), segments=16)


@builder(
    "plant_pot",
    materials=("pot", "soil", "foliage"),
    params={"pot_height": None, "n_leaves": None, "leaf_size": 0.11, "pot_taper": 0.75},
)
def plant_pot(b: PartBuilder, p: dict[str, float]) -> None:
    """Potted plant: tapered ceramic pot with rim, soil, stems and leaves filling the declared box above."""
    W, D, H = p["width"], p["depth"], p["height"]
    ph = p["pot_height"]
    pr = min(0.5 * min(W, D), 0.16)
    b.revolve(
        "pot",
        [
            (0, 0),
            (pr * p["pot_taper"], 0),
            (pr * 0.97, ph - 0.02),
            (pr, ph - 0.02),
            (pr, ph),
            (pr - 0.012, ph),
            (pr - 0.012, 0.02),
            (0, 0.02),
        ],
        segments=32,
    )
    b.cylinder("soil", pr - 0.013, 0.01, (0, 0, ph - 0.03), segments=32)
    rng = b.rng  # per model: every build and variant of a model grows the same plant
    ls = p["leaf_size"]
    n = int(round(p["n_leaves"]))
    for k in range(n):
        a = 2 * np.pi * k / n + rng.uniform(-0.3, 0.3)
        reach = rng.uniform(0.3, 1.0)
        c = np.array(
            [
                reach * np.cos(a) * W / 2,
                reach * np.sin(a) * D / 2,
                ph + 0.05 + rng.uniform(0.3, 1.0) * (H - ph - 0.05),
            ]
        )
        R = prim.rot_z(a) @ prim.rot_y(rng.uniform(0.3, 1.1))
        half = ls * rng.uniform(0.7, 1.2)
        b.bar("foliage", (0.06 * c[0], 0.06 * c[1], ph - 0.03), c, 0.004, segments=8)  # stem
        leaf = [
            (0.0, -half * 0.06),
            (half * 0.5, -half * 0.04),
            (half, 0.0),
            (half * 0.5, half * 0.04),
            (0.0, half * 0.06),
        ]
        b.revolve("foliage", leaf, centre=c, rotation=R, segments=16, uv_style="cyl")
    # normalise the foliage (stems and leaves) to fill the declared box exactly above the soil
    parts = b.parts["foliage"]
    V = np.concatenate([q.vertices for q in parts])
    lo, hi = V.min(0), V.max(0)
    target_lo = np.array([-W / 2, -D / 2, lo[2]])
    target_hi = np.array([W / 2, D / 2, H])
    sc = (target_hi - target_lo) / (hi - lo)
    for q in parts:
        q.vertices = target_lo + (q.vertices - lo) * sc
