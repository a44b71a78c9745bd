"""Bicycle, bed, kitchen appliances (stove/oven, microwave).

Bicycle: it rolls along x, its drive side faces +y (the canonical "front" = the side a viewer looks at);
handlebar width is the y extent.
"""

from __future__ import annotations

import numpy as np

from synthleak.assets.builders.base import PartBuilder, builder


@builder(
    "bicycle",
    materials=("frame", "tyres", "metal", "saddle", "basket"),
    params={"wheel_diameter": None, "tube_radius": 0.017, "n_spokes": 18, "basket_size": 0.3},
)
def bicycle(b: PartBuilder, p: dict[str, float]) -> None:
    """City bicycle: diamond frame, two spoked wheels, fork, handlebar, saddle, crank, front basket."""
    L, D, H = p["width"], p["depth"], p["height"]
    Rw = p["wheel_diameter"] / 2
    tr = 0.02  # tyre tube radius
    tube = p["tube_radius"]
    xr, xf = -L / 2 + Rw, L / 2 - Rw
    zc = Rw
    for xw in (xr, xf):
        b.torus("tyres", Rw - tr, tr, (xw, 0, zc), axis=(0, 1, 0), segments=48, ring_segments=8)
        b.torus(
            "metal", Rw - 2 * tr - 0.004, 0.008, (xw, 0, zc), axis=(0, 1, 0), segments=48, ring_segments=8
        )
        b.cylinder("metal", 0.02, 0.1, (xw, 0, zc), axis=(0, 1, 0), segments=12)
        n = int(round(p["n_spokes"]))
        for k in range(n):
            a = 2 * np.pi * k / n
            side = 0.04 if k % 2 else -0.04
            b.bar(
                "metal",
                (xw, side, zc),
                (xw + (Rw - 2 * tr - 0.01) * np.cos(a), 0, zc + (Rw - 2 * tr - 0.01) * np.sin(a)),
                0.0015,
                segments=4,
            )
    bb = np.array([xr + 0.42, 0.0, 0.30])  # bottom bracket
    seat_top = np.array([bb[0] - 0.13, 0.0, H - 0.16])
    head_top = np.array([xf - 0.16, 0.0, H - 0.12])
    head_bot = np.array([xf - 0.11, 0.0, zc + 0.2])
    hub_r, hub_f = np.array([xr, 0, zc]), np.array([xf, 0, zc])
    for a_, c_ in (
        (bb, seat_top + [0.04, 0, -0.06]),
        (bb, head_bot),
        (seat_top + [0.04, 0, -0.1], head_top + [0, 0, -0.05]),
        (head_bot, head_top),
    ):
        b.bar("frame", a_, c_, tube)
    for sy in (-1, 1):
        off = np.array([0, sy * 0.05, 0])
        b.bar("frame", bb + off * 0.6, hub_r + off, tube * 0.6)  # chain stays
        b.bar("frame", seat_top + [0.04, 0, -0.1], hub_r + off, tube * 0.55)  # seat stays
        b.bar("frame", head_bot + off * 0.4, hub_f + off, tube * 0.7)  # fork
    # handlebar: stem up from the head tube, bar across y (its grips set the depth), top at z = H
    gr = 0.016
    bar_z = H - gr
    b.bar("metal", head_top, (head_top[0] - 0.04, 0, bar_z), 0.012)
    b.bar(
        "metal", (head_top[0] - 0.04, -D / 2 + 0.12, bar_z), (head_top[0] - 0.04, D / 2 - 0.12, bar_z), 0.011
    )
    for sy in (-1, 1):
        b.bar(
            "saddle",
            (head_top[0] - 0.04, sy * (D / 2 - 0.12), bar_z),
            (head_top[0] - 0.04, sy * D / 2, bar_z),
            gr,
            segments=12,
        )
    # seat post and saddle
    b.bar("metal", seat_top + [0.04, 0, -0.08], seat_top + [0.0, 0, 0.08], 0.013)
    b.rounded_box("saddle", (0.27, 0.16, 0.07), seat_top + [-0.01, 0, 0.11], 0.03, cells=4)
    # crank, chainring, pedals
    b.torus("metal", 0.09, 0.006, bb + [0, 0.06, 0], axis=(0, 1, 0), segments=32, ring_segments=6)
    b.cylinder("metal", 0.03, 0.14, bb, axis=(0, 1, 0), segments=12)
    for sy, ang in ((1, 0.6), (-1, 0.6 + np.pi)):
        tip = bb + [0.17 * np.cos(ang), sy * 0.08, 0.17 * np.sin(ang)]
        b.bar("metal", bb + [0, sy * 0.07, 0], tip, 0.01)
        b.box("tyres", (0.1, 0.08, 0.025), tip + [0, sy * 0.05, 0])
    # front basket above the front wheel
    bs = p["basket_size"]
    b.box("basket", (bs * 0.85, bs, bs * 0.7), (xf + 0.02, 0, head_top[2] - 0.1 - bs * 0.35))
    b.bar("metal", head_top + [0, 0, -0.06], (xf + 0.02 - bs * 0.42, 0, head_top[2] - 0.12), 0.006)
    # rear rack and mudguards
    b.box("frame", (0.36, 0.12, 0.012), (xr + 0.05, 0, 2 * Rw + 0.06))
    b.bar("metal", (xr + 0.2, 0, 2 * Rw + 0.054), seat_top + [0.04, 0, -0.12], 0.006)
    b.bar("metal", (xr - 0.12, 0, 2 * Rw + 0.054), hub_r, 0.006)


@builder(
    "bed",
    materials=("frame", "mattress", "bedding", "headboard"),
    params={"headboard_height": None, "frame_height": 0.3, "mattress_height": 0.2, "n_pillows": 2},
)
def bed(b: PartBuilder, p: dict[str, float]) -> None:
    """Bed: wooden frame on legs, padded headboard at -y (the foot end faces +y), mattress, duvet, pillows."""
    W, D, H = p["width"], p["depth"], p["height"]
    fh, mh = p["frame_height"], p["mattress_height"]
    hb_t = 0.08
    b.rounded_box("headboard", (W, hb_t, H), (0, -D / 2 + hb_t / 2, H / 2), 0.03)
    y0, y1 = -D / 2 + hb_t, D / 2
    b.box_span("frame", (-W / 2, y0, 0.1), (W / 2, y1, fh))
    for sx in (-1, 1):
        b.box("frame", (0.06, 0.06, 0.1), (sx * (W / 2 - 0.05), y1 - 0.05, 0.05))
        b.box("frame", (0.06, 0.06, 0.1), (sx * (W / 2 - 0.05), y0 + 0.05, 0.05))
    mw = W - 0.06
    b.rounded_box("mattress", (mw, y1 - y0 - 0.03, mh), (0, (y0 + y1) / 2, fh + mh / 2), 0.04)
    top = fh + mh
    duvet_len = (y1 - y0) * 0.72
    b.rounded_box("bedding", (mw + 0.04, duvet_len, 0.07), (0, y1 - duvet_len / 2 - 0.005, top + 0.03), 0.03)
    n = int(round(p["n_pillows"]))
    pw = (mw - 0.1) / max(n, 1)
    for k in range(n):
        b.rounded_box(
            "bedding", (pw - 0.04, 0.42, 0.13), (-mw / 2 + 0.05 + pw * (k + 0.5), y0 + 0.27, top + 0.06), 0.05
        )


@builder(
    "stove",
    materials=("body", "glass", "panel", "trim"),
    params={"window_frac": 0.55, "n_knobs": 4, "panel_height": 0.1, "door_frac": 0.62},
)
def stove(b: PartBuilder, p: dict[str, float]) -> None:
    """Freestanding cooker: enamel body, oven door with window and bar handle, ceramic hob with four
    burner rings, back control panel with knobs."""
    W, D, H = p["width"], p["depth"], p["height"]
    ph = p["panel_height"]
    hob_z = H - ph
    knob_d = 0.03
    yb = -D / 2
    yfront = D / 2 - 0.06  # door outer face; the handle reaches D/2
    b.box_span("body", (-W / 2, yb, 0), (W / 2, yfront - 0.02, hob_z - 0.01))
    b.box_span("glass", (-W / 2, yb, hob_z - 0.01), (W / 2, yfront - 0.02, hob_z))  # ceramic hob
    for sx in (-1, 1):
        for sy in (-1, 1):
            r = 0.07 if sx * sy > 0 else 0.095
            b.torus(
                "trim",
                r,
                0.004,
                (sx * W / 4, (yb + yfront) / 2 + sy * D / 5.5, hob_z),
                segments=32,
                ring_segments=6,
            )
    door_h = (hob_z - 0.1) * p["door_frac"] + 0.05
    z0 = 0.1
    b.box_span("body", (-W / 2 + 0.01, yfront - 0.02, z0), (W / 2 - 0.01, yfront, z0 + door_h))
    wf = p["window_frac"]
    b.box("glass", (W * wf, 0.006, door_h * wf), (0, yfront + 0.002, z0 + door_h * 0.48))
    b.bar(
        "trim",
        (-W / 2 + 0.06, D / 2 - 0.012, z0 + door_h - 0.04),
        (W / 2 - 0.06, D / 2 - 0.012, z0 + door_h - 0.04),
        0.012,
    )
    for sx in (-1, 1):
        b.box("trim", (0.02, 0.05, 0.02), (sx * (W / 2 - 0.08), yfront + 0.02, z0 + door_h - 0.04))
    b.box_span("body", (-W / 2 + 0.01, yfront - 0.02, 0.01), (W / 2 - 0.01, yfront, z0 - 0.01))  # drawer
    b.box_span("panel", (-W / 2, yb, hob_z), (W / 2, yb + 0.05, H))  # back control panel
    n = int(round(p["n_knobs"]))
    for k in range(n):
        x = -W / 2 + W * (k + 0.5) / n
        b.cylinder(
            "trim", 0.018, knob_d, (x, yb + 0.05 + knob_d / 2, hob_z + ph / 2), axis=(0, 1, 0), segments=16
        )
    b.surface(hob_z, -W / 2, W / 2, yb + 0.05, yfront - 0.02)


@builder(
    "microwave", materials=("body", "glass", "panel", "trim"), params={"panel_frac": 0.26, "window_frac": 0.7}
)
def microwave(b: PartBuilder, p: dict[str, float]) -> None:
    """Counter-top microwave: box body on four feet, door with dark window, control panel with buttons."""
    W, D, H = p["width"], p["depth"], p["height"]
    foot = 0.012
    yfront = D / 2 - 0.025
    b.box_span("body", (-W / 2, -D / 2, foot), (W / 2, yfront, H))
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.cylinder("trim", 0.012, foot, (sx * (W / 2 - 0.04), sy * (D / 2 - 0.06), foot / 2), segments=12)
    pw = W * p["panel_frac"]
    dw = W - pw
    wf = p["window_frac"]
    b.box_span(
        "body", (-W / 2 + 0.005, yfront, foot + 0.005), (-W / 2 + dw - 0.005, yfront + 0.012, H - 0.005)
    )
    b.box(
        "glass",
        (dw * wf, 0.004, (H - foot) * wf),
        (-W / 2 + dw * 0.45, yfront + 0.013, foot + (H - foot) / 2),
    )
    b.box_span("panel", (W / 2 - pw, yfront, foot + 0.005), (W / 2 - 0.005, yfront + 0.008, H - 0.005))
    for k in range(6):
        b.box(
            "trim",
            (pw * 0.3, 0.01, 0.018),
            (W / 2 - pw * (0.3 + 0.4 * (k % 2)), yfront + 0.012, foot + 0.05 + 0.03 * (k // 2)),
        )
    b.cylinder("trim", 0.025, 0.02, (W / 2 - pw / 2, yfront + 0.015, H - 0.08), axis=(0, 1, 0), segments=16)
    b.surface(H, -W / 2, W / 2, -D / 2, yfront)
