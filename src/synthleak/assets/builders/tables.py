"""Tables: dining, side, coffee, bedside, desks. Support surfaces on every top and shelf."""

from __future__ import annotations

from synthleak.assets.builders.base import PartBuilder, builder


@builder(
    "table_rect",
    materials=("top", "legs"),
    params={
        "top_thickness": 0.03,
        "leg_width": 0.06,
        "apron_height": 0.08,
        "leg_inset": 0.03,
        "shelf": 0,
        "shelf_height": 0.12,
    },
)
def table_rect(b: PartBuilder, p: dict[str, float]) -> None:
    """Rectangular table: slab top, four square legs set in by ``leg_inset``, apron, optional lower shelf."""
    W, D, H = p["width"], p["depth"], p["height"]
    tt, lw, ah, ins = p["top_thickness"], p["leg_width"], p["apron_height"], p["leg_inset"]
    b.box("top", (W, D, tt), (0, 0, H - tt / 2))
    b.surface(H, -W / 2, W / 2, -D / 2, D / 2)
    lx, ly = W / 2 - ins - lw / 2, D / 2 - ins - lw / 2
    for sx in (-1, 1):
        for sy in (-1, 1):
            b.box("legs", (lw, lw, H - tt), (sx * lx, sy * ly, (H - tt) / 2))
    if ah > 0:
        za = H - tt - ah / 2
        b.box("legs", (2 * lx - lw, 0.02, ah), (0, ly, za))
        b.box("legs", (2 * lx - lw, 0.02, ah), (0, -ly, za))
        b.box("legs", (0.02, 2 * ly - lw, ah), (lx, 0, za))
        b.box("legs", (0.02, 2 * ly - lw, ah), (-lx, 0, za))
    if round(p["shelf"]) >= 1:
        zs = p["shelf_height"]
        b.box("top", (2 * lx + lw, 2 * ly + lw, 0.02), (0, 0, zs))
        b.surface(zs + 0.01, -lx + lw / 2, lx - lw / 2, -ly + lw / 2, ly - lw / 2)


@builder(
    "table_round",
    materials=("top", "base"),
    params={"top_thickness": 0.03, "column_radius": 0.05, "foot_radius_frac": 0.55, "foot_height": 0.04},
)
def table_round(b: PartBuilder, p: dict[str, float]) -> None:
    """Round pedestal table: disc top, central column, round foot."""
    W, H = p["width"], p["height"]
    tt, cr, fh = p["top_thickness"], p["column_radius"], p["foot_height"]
    R = W / 2
    b.cylinder("top", R, tt, (0, 0, H - tt / 2), segments=48)
    b.surface(H, -R * 0.7, R * 0.7, -R * 0.7, R * 0.7)
    fr = R * p["foot_radius_frac"]
    b.revolve(
        "base",
        [
            (0, 0),
            (fr, 0),
            (fr, fh * 0.5),
            (cr * 1.6, fh),
            (cr, fh + 0.05),
            (cr, H - tt - 0.04),
            (cr * 1.8, H - tt - 0.005),
            (cr * 1.8, H - tt),
            (0, H - tt),
        ],
        segments=32,
    )


@builder(
    "desk",
    materials=("top", "frame", "drawers"),
    params={"top_thickness": 0.03, "drawer_width": None, "n_drawers": None, "panel_thickness": 0.025},
)
def desk(b: PartBuilder, p: dict[str, float]) -> None:
    """Desk: top on a side panel (left) and a drawer unit (right), modesty panel at the back."""
    W, D, H = p["width"], p["depth"], p["height"]
    tt, dw, pt = p["top_thickness"], p["drawer_width"], p["panel_thickness"]
    n = int(round(p["n_drawers"]))
    b.box("top", (W, D, tt), (0, 0, H - tt / 2))
    b.surface(H, -W / 2, W / 2, -D / 2, D / 2)
    hb = H - tt
    b.box("frame", (pt, D - 0.04, hb), (-W / 2 + pt / 2 + 0.01, 0, hb / 2))
    b.box(
        "frame", (W - 2 * pt - dw, 0.018, hb * 0.45), (-pt / 2 - dw / 2 + 0.0, -D / 2 + 0.06, hb - hb * 0.225)
    )
    x0 = W / 2 - 0.01 - dw
    b.box("frame", (dw, D - 0.08, hb), (x0 + dw / 2, -0.02, hb / 2))
    gap = 0.004
    fh = (hb - 0.04) / n
    for k in range(n):
        zc = 0.03 + fh * (k + 0.5)
        b.box("drawers", (dw - 2 * gap, 0.02, fh - 2 * gap), (x0 + dw / 2, D / 2 - 0.03, zc))
        b.box("frame", (dw * 0.4, 0.02, 0.015), (x0 + dw / 2, D / 2 - 0.01, zc + fh * 0.25))
