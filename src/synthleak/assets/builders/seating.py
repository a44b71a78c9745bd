"""Chairs, stools, sofas, armchairs. Front faces +y (a sitter looks towards +y), backrests at -y."""

from __future__ import annotations

import numpy as np

from synthleak.assets.builders.base import PartBuilder, builder


@builder(
    "chair_ladderback",
    materials=("frame", "seat"),
    params={
        "seat_height": None,
        "n_slats": None,
        "leg_width": 0.035,
        "seat_thickness": 0.03,
        "stretcher_height": 0.16,
    },
)
def chair_ladderback(b: PartBuilder, p: dict[str, float]) -> None:
    """Wooden ladder-back chair: square legs, rear posts rising to the top, horizontal back slats."""
    W, D, H = p["width"], p["depth"], p["height"]
    lw, st, sh = p["leg_width"], p["seat_thickness"], p["seat_height"]
    xs = (-W / 2 + lw / 2, W / 2 - lw / 2)
    yf, yb = D / 2 - lw / 2, -D / 2 + lw / 2
    for x in xs:
        b.box("frame", (lw, lw, sh - st), (x, yf, (sh - st) / 2))  # front legs
        b.box("frame", (lw, lw, H), (x, yb, H / 2))  # rear posts
        b.box("frame", (0.6 * lw, D - 2 * lw, 0.6 * lw), (x, 0, p["stretcher_height"]))  # side stretchers
    b.box("frame", (W - 2 * lw, 0.6 * lw, 0.6 * lw), (0, yf, p["stretcher_height"] + 0.05))
    b.box("frame", (W - 2 * lw, 0.6 * lw, 0.6 * lw), (0, yb, p["stretcher_height"] + 0.05))
    b.box("seat", (W - 0.004, D - lw - 0.004, st), (0, lw / 2, sh - st / 2))
    n = int(round(p["n_slats"]))
    z0, z1 = sh + 0.12, H - 0.02
    slat_h = min(0.07, 0.6 * (z1 - z0) / n)
    for k in range(n):
        z = z1 - slat_h / 2 - k * (z1 - z0 - slat_h) / max(n - 1, 1)
        b.box("frame", (W - 2 * lw, 0.018, slat_h), (0, yb, z))


@builder(
    "chair_stacking",
    materials=("frame", "shell"),
    params={"seat_height": None, "tube_radius": 0.011, "back_height": None, "seat_thickness": 0.012},
)
def chair_stacking(b: PartBuilder, p: dict[str, float]) -> None:
    """Stacking chair: bent steel-tube frame (bars), moulded seat and back panels."""
    W, D, H = p["width"], p["depth"], p["height"]
    r, sh, st = p["tube_radius"], p["seat_height"], p["seat_thickness"]
    bh = min(p["back_height"], H - sh - 0.05)
    x = W / 2 - r
    yf, yb = D / 2 - r, -D / 2 + r
    for sx in (-1, 1):
        b.leg(
            "frame", (sx * x, yf, 0.0), (sx * (x - 0.02), yf - 0.04, sh - st), r
        )  # front legs (slightly splayed)
        b.leg("frame", (sx * x, yb, 0.0), (sx * (x - 0.02), yb + 0.06, sh - st), r)  # rear legs
        b.bar(
            "frame", (sx * (x - 0.02), yb + 0.06, sh - st), (sx * (x - 0.02), yb, H - 0.003), r
        )  # back uprights
        b.bar("frame", (sx * (x - 0.02), yf - 0.04, sh - st), (sx * (x - 0.02), yb + 0.06, sh - st), r)
    b.box("shell", (W - 0.02, D - 0.07, st), (0, 0.0, sh - st / 2))
    b.box("shell", (W - 0.04 - 4 * r, 0.012, bh), (0, yb, H - 0.02 - bh / 2), rotation=None)


@builder(
    "chair_office",
    materials=("base", "seat", "arms"),
    params={"seat_height": None, "back_height": None, "seat_thickness": 0.07, "arm_height": 0.2},
)
def chair_office(b: PartBuilder, p: dict[str, float]) -> None:
    """Office swivel chair: five-star base on casters, gas lift, upholstered seat and back, arm rests."""
    W, D, H = p["width"], p["depth"], p["height"]
    sh, st, bh = p["seat_height"], p["seat_thickness"], p["back_height"]
    R = min(W, D) / 2 - 0.025
    cr = 0.025
    for k in range(5):
        a = np.pi / 2 + 2 * np.pi * k / 5
        tip = np.array([R * np.cos(a), R * np.sin(a)])
        b.bar("base", (0, 0, 0.09), (tip[0], tip[1], 0.07), 0.018)
        b.sphere("base", cr, (tip[0], tip[1], cr))  # caster
        b.bar("base", (tip[0], tip[1], cr), (tip[0], tip[1], 0.075), 0.008)
    b.cylinder("base", 0.035, 0.06, (0, 0, 0.09))
    b.cylinder("base", 0.022, sh - st - 0.1, (0, 0, 0.1 + (sh - st - 0.1) / 2))
    seat_d = D * 0.62
    y_seat = D / 2 - seat_d / 2
    b.rounded_box("seat", (W * 0.85, seat_d, st), (0, y_seat, sh - st / 2), 0.025)
    # backrest on a spine: a horizontal bar under the seat to the back, then up to the backrest
    back_t = 0.07
    yb = -D / 2 + back_t / 2
    b.rounded_box("seat", (W * 0.8, back_t, bh), (0, yb, H - bh / 2), 0.025)
    seat_back = y_seat - seat_d / 2
    b.box_span("arms", (-0.03, yb - 0.015, sh - st - 0.02), (0.03, seat_back + 0.06, sh - st))
    b.box_span("arms", (-0.025, yb - 0.015, sh - st - 0.02), (0.025, yb + 0.015, H - bh + 0.04))
    ah = p["arm_height"]
    for sx in (-1, 1):  # arm rests: post on a bracket under the seat, pad on top
        xa = sx * (W / 2 - 0.035)
        b.box("arms", (0.04, 0.03, 0.03), (xa - sx * 0.04, y_seat, sh - st - 0.01))
        b.box("arms", (0.03, 0.03, ah), (xa, y_seat, sh + ah / 2 - 0.02))
        b.box("arms", (0.07, seat_d * 0.7, 0.03), (xa, y_seat, sh + ah - 0.005))


@builder(
    "chair_upholstered",
    materials=("legs", "upholstery"),
    params={
        "seat_height": None,
        "leg_width": 0.035,
        "seat_thickness": 0.08,
        "back_thickness": 0.07,
        "leg_taper": 0.6,
    },
)
def chair_upholstered(b: PartBuilder, p: dict[str, float]) -> None:
    """Dining chair with tapered wooden legs, padded seat and a padded, slightly raked back."""
    W, D, H = p["width"], p["depth"], p["height"]
    lw, sh, st, bt = p["leg_width"], p["seat_height"], p["seat_thickness"], p["back_thickness"]
    tw = lw * p["leg_taper"]
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = (sx * (W / 2 - lw / 2 - 0.01), sy * (D / 2 - lw / 2 - 0.01), 0.0)
            b.tapered_box("legs", (tw, tw), (lw, lw), sh - st, c)
    b.rounded_box("upholstery", (W, D - bt, st), (0, bt / 2, sh - st / 2), 0.02)
    rake = 0.04
    lo, hi = sh - st, H
    C = np.array(
        [
            [-W / 2, -D / 2 + rake, lo],
            [W / 2, -D / 2 + rake, lo],
            [W / 2, -D / 2 + rake + bt, lo],
            [-W / 2, -D / 2 + rake + bt, lo],
            [-W / 2, -D / 2, hi],
            [W / 2, -D / 2, hi],
            [W / 2, -D / 2 + bt, hi],
            [-W / 2, -D / 2 + bt, hi],
        ]
    )
    b.hexahedron("upholstery", C)


@builder(
    "armchair",
    materials=("upholstery", "cushion", "legs"),
    params={
        "seat_height": None,
        "arm_width": None,
        "arm_height": None,
        "back_depth": 0.18,
        "leg_height": 0.12,
        "roundness": 0.04,
    },
)
def armchair(b: PartBuilder, p: dict[str, float]) -> None:
    """Upholstered armchair / sofa body: base, arms, back, loose seat cushion(s), short legs."""
    _upholstered(b, p, n_seats=1)


@builder(
    "sofa",
    materials=("upholstery", "cushion", "legs"),
    params={
        "n_seats": None,
        "seat_height": None,
        "arm_width": None,
        "arm_height": None,
        "back_depth": 0.2,
        "leg_height": 0.1,
        "roundness": 0.05,
    },
)
def sofa(b: PartBuilder, p: dict[str, float]) -> None:
    """Sofa with ``n_seats`` seat and back cushions."""
    _upholstered(b, p, n_seats=int(round(p["n_seats"])))


def _upholstered(b: PartBuilder, p: dict[str, float], n_seats: int) -> None:
    W, D, H = p["width"], p["depth"], p["height"]
    sh, aw, ah, bd, lh, rr = (
        p["seat_height"],
        p["arm_width"],
        p["arm_height"],
        p["back_depth"],
        p["leg_height"],
        p["roundness"],
    )
    base_h = sh - 0.12 - lh
    lw = 0.045
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.tapered_box(
                "legs", (lw * 0.7, lw * 0.7), (lw, lw), lh, (sx * (W / 2 - 0.06), sy * (D / 2 - 0.06), 0)
            )
    b.rounded_box("upholstery", (W - 2 * aw + 0.02, D - bd, base_h), (0, bd / 2, lh + base_h / 2), rr)
    for sx in (-1, 1):
        b.rounded_box("upholstery", (aw, D, ah - lh), (sx * (W / 2 - aw / 2), 0, lh + (ah - lh) / 2), rr)
    b.rounded_box("upholstery", (W - 2 * aw + 0.02, bd, H - lh), (0, -D / 2 + bd / 2, lh + (H - lh) / 2), rr)
    inner = W - 2 * aw
    cw = inner / n_seats
    depth = D - bd - 0.02
    for k in range(n_seats):
        x = -inner / 2 + cw * (k + 0.5)
        b.rounded_box("cushion", (cw - 0.01, depth, 0.12), (x, D / 2 - depth / 2 - 0.005, sh - 0.06), rr)
        bk_h = min(0.45, H - sh - 0.02)
        b.rounded_box("cushion", (cw - 0.01, 0.14, bk_h), (x, -D / 2 + bd + 0.06, sh + bk_h / 2), rr)


@builder(
    "stool_bar",
    materials=("seat", "legs"),
    params={"seat_thickness": 0.05, "leg_radius": 0.013, "ring_height": None, "seat_radius_frac": 0.9},
)
def stool_bar(b: PartBuilder, p: dict[str, float]) -> None:
    """Bar stool: round padded seat, four splayed legs, foot ring."""
    W, H = p["width"], p["height"]
    st, lr = p["seat_thickness"], p["leg_radius"]
    R = W / 2
    rs = R * p["seat_radius_frac"]
    b.cylinder("seat", rs, st, (0, 0, H - st / 2), segments=32)
    top_r = rs * 0.6
    for k in range(4):
        a = k * np.pi / 2
        foot = ((R - lr) * np.cos(a), (R - lr) * np.sin(a), 0.0)
        b.leg("legs", foot, (top_r * np.cos(a), top_r * np.sin(a), H - st), lr)
    zr = p["ring_height"]
    frac = 1 - zr / (H - st)
    ring_r = top_r + (R - lr - top_r) * frac
    b.torus("legs", ring_r / np.sqrt(1.0) * 1.0, lr * 0.8, (0, 0, zr), segments=32)
    b.cylinder("legs", top_r + 0.01, 0.02, (0, 0, H - st - 0.01), segments=32)


@builder(
    "stool_round",
    materials=("seat", "legs"),
    params={"seat_thickness": 0.035, "leg_radius": 0.016, "splay": 0.6},
)
def stool_round(b: PartBuilder, p: dict[str, float]) -> None:
    """Low round stool: solid seat on three splayed legs (cf. IKEA KYRRE)."""
    W, D, H = p["width"], p["depth"], p["height"]
    st, lr = p["seat_thickness"], p["leg_radius"]
    R = min(W, D) / 2
    b.cylinder("seat", R, st, (0, 0, H - st / 2), segments=32)
    for k in range(3):
        a = np.pi / 2 + 2 * np.pi * k / 3
        rt = R * (1 - p["splay"]) + 0.02
        foot = ((R * 0.95 - lr) * np.cos(a), (R * 0.95 - lr) * np.sin(a), 0.0)
        b.leg("legs", foot, (rt * np.cos(a), rt * np.sin(a), H - st / 2 - lr), lr)
        b.leg("legs", foot, (0.0, 0.0, 0.12), lr * 0.6)


@builder(
    "stool_step",
    materials=("frame", "treads"),
    params={"step_height": None, "side_thickness": 0.02, "tread_thickness": 0.025},
)
def stool_step(b: PartBuilder, p: dict[str, float]) -> None:
    """Two-step stool: trapezoid side boards, two treads (lower one at +y, the front)."""
    W, D, H = p["width"], p["depth"], p["height"]
    t, tt, s1 = p["side_thickness"], p["tread_thickness"], p["step_height"]
    for sx in (-1, 1):
        x = sx * (W / 2 - t / 2)
        C = np.array(
            [
                [x - t / 2, -D / 2, 0],
                [x + t / 2, -D / 2, 0],
                [x + t / 2, D / 2, 0],
                [x - t / 2, D / 2, 0],
                [x - t / 2, -D / 2, H],
                [x + t / 2, -D / 2, H],
                [x + t / 2, 0.0, H],
                [x - t / 2, 0.0, H],
            ]
        )
        b.hexahedron("frame", C)
    iw = W - 2 * t
    b.box("treads", (iw, D / 2 - 0.01, tt), (0, -D / 4 + 0.005, H - tt / 2))
    b.box("treads", (iw, D / 2 - 0.02, tt), (0, D / 4 - 0.01, s1 - tt / 2))
    b.box("frame", (iw, t, 0.08), (0, -D / 2 + t, 0.15))
