"""Shelves, bookcases, cupboards, wardrobes, sideboards. Fronts (doors, open shelves) face +y."""

from __future__ import annotations

from synthleak.assets.builders.base import PartBuilder, builder


@builder(
    "shelf_open",
    materials=("carcass", "back"),
    params={"n_shelves": None, "board_thickness": 0.018, "plinth_height": 0.06, "back_inset": 0.01},
)
def shelf_open(b: PartBuilder, p: dict[str, float]) -> None:
    """Open bookcase: two sides, top, bottom, ``n_shelves`` compartments, plinth, back panel."""
    W, D, H = p["width"], p["depth"], p["height"]
    t, ph = p["board_thickness"], p["plinth_height"]
    n = max(1, int(round(p["n_shelves"])))
    b.box("carcass", (t, D, H), (-W / 2 + t / 2, 0, H / 2))
    b.box("carcass", (t, D, H), (W / 2 - t / 2, 0, H / 2))
    iw = W - 2 * t
    b.box("carcass", (iw, D, t), (0, 0, H - t / 2))
    b.surface(H, -W / 2, W / 2, -D / 2, D / 2)
    b.box("carcass", (iw, 0.02, ph), (0, D / 2 - 0.03, ph / 2))  # plinth front
    z_bottom = ph + t
    b.box("carcass", (iw, D - 0.02, t), (0, 0.01, ph + t / 2))
    b.box("back", (iw, 0.006, H - ph - t), (0, -D / 2 + p["back_inset"], (ph + H - t) / 2))
    pitch = (H - t - z_bottom) / n
    b.surface(z_bottom, -iw / 2, iw / 2, -D / 2 + p["back_inset"] + 0.003, D / 2)
    for k in range(1, n):
        z = z_bottom + k * pitch
        b.box("carcass", (iw, D - 0.03, t), (0, 0.015, z - t / 2))
        b.surface(z, -iw / 2, iw / 2, -D / 2 + p["back_inset"] + 0.003, D / 2)


@builder(
    "shelf_cube",
    materials=("carcass", "inserts"),
    params={"n_cols": None, "n_rows": None, "board_thickness": 0.038, "n_inserts": 3},
)
def shelf_cube(b: PartBuilder, p: dict[str, float]) -> None:
    """Cube-grid shelving (cf. IKEA KALLAX) with fabric storage boxes in some of the cubes."""
    W, D, H = p["width"], p["depth"], p["height"]
    t = p["board_thickness"]
    nc, nr = max(1, int(round(p["n_cols"]))), max(1, int(round(p["n_rows"])))
    cw, ch = (W - t) / nc, (H - t) / nr
    for i in range(nc + 1):
        b.box("carcass", (t, D, H), (-W / 2 + t / 2 + i * cw, 0, H / 2))
    for j in range(nr + 1):
        b.box("carcass", (W - 2 * t, D, t), (0, 0, t / 2 + j * ch))
    b.surface(H, -W / 2, W / 2, -D / 2, D / 2)
    cells = [(i, j) for j in range(nr) for i in range(nc)]
    n_ins = min(int(round(p["n_inserts"])), len(cells))
    chosen = set(int(k) for k in b.rng.permutation(len(cells))[:n_ins])
    for k, (i, j) in enumerate(cells):
        x = -W / 2 + t + i * cw + (cw - t) / 2
        z0 = t + j * ch
        if k in chosen:
            b.box("inserts", (cw - t - 0.01, D - 0.04, ch - t - 0.01), (x, 0.0, z0 + (ch - t) / 2))
        else:
            b.surface(z0, x - (cw - t) / 2, x + (cw - t) / 2, -D / 2, D / 2)


@builder(
    "cabinet",
    materials=("carcass", "fronts", "handles"),
    params={
        "n_doors": None,
        "n_drawers": None,
        "drawer_frac": 0.3,
        "leg_height": 0.0,
        "plinth": 0.08,
        "top_overhang": 0.0,
        "handle_length": 0.12,
    },
)
def cabinet(b: PartBuilder, p: dict[str, float]) -> None:
    """Closed cabinet (wardrobe, sideboard, chest of drawers, bedside table): carcass on legs or a plinth,
    ``n_doors`` doors above ``n_drawers`` drawers (drawers only when ``n_doors`` is 0), bar handles."""
    W, D, H = p["width"], p["depth"], p["height"]
    nd, nw = int(round(p["n_doors"])), int(round(p["n_drawers"]))
    lh, ov = p["leg_height"], p["top_overhang"]
    ft, top_t, hp = 0.018, 0.025, 0.026  # front thickness, top thickness, handle projection
    y_front = D / 2 - max(ov, hp)  # outer face of doors and drawers
    cw, cd = W - 2 * ov, y_front - ft + D / 2
    yc = -D / 2 + cd / 2
    base = lh if lh > 0 else p["plinth"]
    if lh > 0:
        for sx in (-1, 1):
            for sy in (-1, 1):
                b.tapered_box(
                    "handles",
                    (0.025, 0.025),
                    (0.035, 0.035),
                    lh,
                    (sx * (cw / 2 - 0.04), yc + sy * (cd / 2 - 0.04), 0),
                )
    else:
        b.box("carcass", (cw - 0.04, cd - 0.04, base), (0, yc, base / 2))
    body_h = H - top_t - base
    b.box("carcass", (cw, cd, body_h), (0, yc, base + body_h / 2))
    b.box_span("carcass", (-W / 2, -D / 2, H - top_t), (W / 2, y_front + ov, H))
    b.surface(H, -W / 2, W / 2, -D / 2, y_front + ov)
    yf = y_front - ft / 2
    gap = 0.003
    drawer_h = body_h * (p["drawer_frac"] if nd > 0 else 1.0) if nw > 0 else 0.0
    hl = p["handle_length"]
    for k in range(nw):
        fh = drawer_h / nw
        zc = base + fh * (k + 0.5)
        b.box("fronts", (cw - 2 * gap, ft, fh - 2 * gap), (0, yf, zc))
        b.bar(
            "handles",
            (-hl / 2, yf + ft / 2 + 0.02, zc + fh * 0.2),
            (hl / 2, yf + ft / 2 + 0.02, zc + fh * 0.2),
            0.006,
        )
        for sx in (-1, 1):
            b.box("handles", (0.01, 0.02, 0.01), (sx * (hl / 2 - 0.01), yf + ft / 2 + 0.01, zc + fh * 0.2))
    if nd > 0:
        z0 = base + drawer_h
        dh = body_h - drawer_h
        dw = cw / nd
        for k in range(nd):
            xc = -cw / 2 + dw * (k + 0.5)
            b.box("fronts", (dw - 2 * gap, ft, dh - 2 * gap), (xc, yf, z0 + dh / 2))
            hx = xc + (dw / 2 - 0.05) * (1 if k % 2 == 0 else -1) * (1 if nd > 1 else 0)
            zh = z0 + min(dh / 2, 0.9)
            vl = min(hl, dh * 0.4)
            b.bar(
                "handles", (hx, yf + ft / 2 + 0.02, zh - vl / 2), (hx, yf + ft / 2 + 0.02, zh + vl / 2), 0.006
            )
            for sz in (-1, 1):
                b.box("handles", (0.01, 0.02, 0.01), (hx, yf + ft / 2 + 0.01, zh + sz * (vl / 2 - 0.01)))
