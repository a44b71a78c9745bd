"""Props: small textured clutter (books, boxes, cushions, rugs, posters, cups, bowls, baskets, plants, shoes,
bins, bottles, candles, a laptop, toys, a folded blanket). Models with ``role = "prop"`` use these builders.

Same rules as the furniture builders (:mod:`.base`): the built bounding box is exactly the declared
``width x depth x height`` at any shape parameters, +z up, front +y. Builders that scatter items (a row of
books, a stack, fruit, leaves) lay them out with the per-model ``b.rng`` (the same layout in every build of a
model; draws are made for the largest count, so a count change does not reshuffle the other items' draws)
and, where turned or rounded items make the exact extents awkward to compute, map the layout onto the
declared box with :func:`_fit_box` (a per-axis affine map within 6 % of the identity). Props
record no support surfaces. They stay small in triangles (< 2,000 each) because rooms hold dozens of them.
"""

from __future__ import annotations

import numpy as np

from synthleak.assets import primitives as prim
from synthleak.assets.builders.base import PartBuilder, builder

_EMBED = 0.0002
"""How deep an attached piece (label, tape) sinks into its host: no coplanar faces, no shared vertices."""
_MAX_ITEMS = 12
"""Items drawn per layout whatever the count parameter (stable layouts when the count changes)."""


def _fit_box(b: PartBuilder, W: float, D: float, H: float) -> None:
    """Map every part drawn so far (per-axis scale and shift) onto ``[-W/2, W/2] x [-D/2, D/2] x [0, H]``."""
    parts = [q for qs in b.parts.values() for q in qs]
    V = np.concatenate([q.vertices for q in parts])
    lo, hi = V.min(0), V.max(0)
    t_lo, t_hi = np.array([-W / 2, -D / 2, 0.0]), np.array([W / 2, D / 2, H])
    sc = (t_hi - t_lo) / (hi - lo)
    for q in parts:
        q.vertices = t_lo + (q.vertices - lo) * sc


def _count(p: dict[str, float], key: str) -> int:
    return int(np.clip(round(p[key]), 1, _MAX_ITEMS))


# ------------------------------------------------------------------------------------------ books, papers
@builder(
    "book_row",
    materials=("covers", "pages"),
    params={"n_books": None, "height_spread": 0.25, "depth_spread": 0.2, "board": 0.003},
)
def book_row(b: PartBuilder, p: dict[str, float]) -> None:
    """Books standing in a row along x, spines to the front (+y) and flush there; varied thicknesses,
    heights and depths (the tallest is the height, the deepest the depth); page edges show on top."""
    W, D, H = p["width"], p["depth"], p["height"]
    n = _count(p, "n_books")
    rng = b.rng
    thick = rng.uniform(0.6, 1.5, _MAX_ITEMS)[:n]
    h_u, d_u = rng.uniform(0, 1, _MAX_ITEMS)[:n], rng.uniform(0, 1, _MAX_ITEMS)[:n]
    h_u[int(np.argmin(h_u))] = 0.0
    d_u[int(np.argmin(d_u))] = 0.0
    gap = 0.0006
    widths = thick / thick.sum() * (W - gap * (n - 1))
    x = -W / 2
    for k in range(n):
        w, h, d = widths[k], H * (1 - p["height_spread"] * h_u[k]), D * (1 - p["depth_spread"] * d_u[k])
        t = min(p["board"], w / 4)
        b.box_span("covers", (x, D / 2 - d, 0.0), (x + w, D / 2, h - 0.0008))
        b.box_span("pages", (x + t, D / 2 - d + t, h - 0.004), (x + w - t, D / 2 - t, h))
        x += w + gap


@builder(
    "book_stack",
    materials=("covers", "pages"),
    params={"n_books": None, "size_spread": 0.25, "twist_deg": 6.0, "board": 0.002},
)
def book_stack(b: PartBuilder, p: dict[str, float]) -> None:
    """Books or magazines lying in a stack: each a cover block with its page block showing on three sides
    (spines alternate left/right), varied sizes, offsets and small turns about z."""
    W, D, H = p["width"], p["depth"], p["height"]
    n = _count(p, "n_books")
    rng = b.rng
    su = rng.uniform(0, 1, (_MAX_ITEMS, 2))[:n]
    su[0] = 0.0  # the bottom book is the largest, square to the box: it sets width and depth
    th = rng.uniform(0.6, 1.4, _MAX_ITEMS)[:n]
    off = rng.uniform(-1, 1, (_MAX_ITEMS, 2))[:n]
    turn = np.deg2rad(p["twist_deg"]) * rng.uniform(-1, 1, _MAX_ITEMS)[:n]
    turn[0] = 0.0
    gap = 0.0004
    th = th / th.sum() * (H - gap * (n - 1))
    Wc, Dc = W - 0.0016, D - 0.0016  # the cover blocks' box (pages stand 0.8 mm proud)
    z = 0.0
    for k in range(n):
        w, d = Wc * (1 - p["size_spread"] * su[k, 0]), Dc * (1 - p["size_spread"] * su[k, 1])
        ca, sa = abs(np.cos(turn[k])), abs(np.sin(turn[k]))
        shrink = min(1.0, Wc / (w * ca + d * sa), Dc / (w * sa + d * ca))  # a turned book stays in the box
        w, d = w * shrink, d * shrink
        ex, ey = w * ca + d * sa, w * sa + d * ca
        c = np.array([off[k, 0] * (Wc - ex) / 2, off[k, 1] * (Dc - ey) / 2, z + th[k] / 2])
        R = prim.rot_z(float(turn[k]))
        t = min(p["board"], th[k] / 4)
        side = 1 if k % 2 else -1  # spine side (x)
        b.box("covers", (w, d, th[k]), c, rotation=R)
        # page block: from the spine board to 0.8 mm proud of the cover on the other three sides
        lo_x, hi_x = sorted((side * (w / 2 - t), -side * (w / 2 + 0.0008)))
        pc = c + R @ np.array([(lo_x + hi_x) / 2, 0.0, 0.0])
        b.box("pages", (hi_x - lo_x, d + 0.0016, th[k] - 2 * t), pc, rotation=R)
        z += th[k] + gap
    _fit_box(b, W, D, H)


# ------------------------------------------------------------------------------------------ boxes
@builder(
    "box_lidded",
    materials=("body", "lid"),
    params={"lid_height": None, "overhang": 0.006, "label_frac": 0.45},
    optional_materials=("label",),
)
def box_lidded(b: PartBuilder, p: dict[str, float]) -> None:
    """Storage box with a slip-over lid (the lid sets width and depth), optional label on the front."""
    W, D, H = p["width"], p["depth"], p["height"]
    ov, lh = p["overhang"], p["lid_height"]
    b.box_span("body", (-W / 2 + ov, -D / 2 + ov, 0.0), (W / 2 - ov, D / 2 - ov, H - 0.002))
    b.box_span("lid", (-W / 2, -D / 2, H - lh), (W / 2, D / 2, H))
    if b.has("label"):
        lw = (W - 2 * ov) * p["label_frac"]
        zc = (H - lh) / 2
        lh_ = min(lw * 0.6, 0.7 * (H - lh))
        y = D / 2 - ov + _EMBED  # label front; its back sits _EMBED inside the body (no coplanar faces)
        b.box_span("label", (-lw / 2, y - 0.001, zc - lh_ / 2), (lw / 2, y, zc + lh_ / 2), uv_mode="fit")


@builder(
    "carton",
    materials=("carton", "tape"),
    params={"tape_width": 0.05, "tape_drop": 0.08, "label_frac": 0.35},
    optional_materials=("label",),
)
def carton(b: PartBuilder, p: dict[str, float]) -> None:
    """Closed cardboard box: printed carton, packing tape over the top seam and down both ends (x), an
    optional shipping label on the front."""
    W, D, H = p["width"], p["depth"], p["height"]
    tt = 0.0008
    tw = min(p["tape_width"], D * 0.4)
    lt = 0.0006 if b.has("label") else 0.0  # the label is the front-most layer
    b.box_span("carton", (-W / 2 + tt, -D / 2, 0.0), (W / 2 - tt, D / 2 - lt, H - tt))
    b.box_span("tape", (-W / 2 + tt / 2, -tw / 2, H - tt - _EMBED), (W / 2 - tt / 2, tw / 2, H))
    drop = min(p["tape_drop"], H * 0.6)
    for sx in (-1, 1):
        xa, xb = sorted((sx * (W / 2 - tt - _EMBED), sx * W / 2))
        b.box_span("tape", (xa, -tw / 2, H - drop), (xb, tw / 2, H - tt - 0.0002))
    if b.has("label"):
        lw = W * p["label_frac"]
        lo = (W * 0.18 - lw / 2, D / 2 - lt - _EMBED, H * 0.55 - lw * 0.33)
        b.box_span("label", lo, (W * 0.18 + lw / 2, D / 2, H * 0.55 + lw * 0.33), uv_mode="fit")


# ------------------------------------------------------------------------------------------ soft goods
@builder("cushion", materials=("cover",), params={"roundness": 0.45, "puff": 0.25})
def cushion(b: PartBuilder, p: dict[str, float]) -> None:
    """Cushion: a rounded block, thinner towards its edges (``puff``) as a filled cover is."""
    W, D, H = p["width"], p["depth"], p["height"]
    part = b.rounded_box("cover", (W, D, H), (0, 0, H / 2), p["roundness"] * H, cells=8)
    V = part.vertices
    rx, ry = V[:, 0] / (W / 2), V[:, 1] / (D / 2)
    pinch = 1 - p["puff"] * np.clip(np.maximum(np.abs(rx), np.abs(ry)), 0, 1) ** 2
    V[:, 2] = H / 2 + (V[:, 2] - H / 2) * pinch
    _fit_box(b, W, D, H)


@builder("folded_blanket", materials=("cloth",), params={"n_layers": None, "slip": 0.02})
def folded_blanket(b: PartBuilder, p: dict[str, float]) -> None:
    """Folded throw: ``n_layers`` soft layers stacked, each shifted a little (``slip``), the folds rounded."""
    W, D, H = p["width"], p["depth"], p["height"]
    n = _count(p, "n_layers")
    rng = b.rng
    sl = rng.uniform(-1, 1, (_MAX_ITEMS, 2))[:n] * p["slip"]
    span = sl.max(0) - sl.min(0)
    sl -= 0.5 * (sl.max(0) + sl.min(0))
    th = H / (n + 0.02)  # layers overlap by 2 % of their thickness
    for k in range(n):
        b.rounded_box(
            "cloth",
            (W - span[0], D - span[1], th * 1.02),
            (sl[k, 0], sl[k, 1], th * (k + 0.51)),
            th * 0.5,
            cells=4,
        )
    _fit_box(b, W, D, H)


# ------------------------------------------------------------------------------------------ rugs, prints
@builder(
    "rug",
    materials=("field", "border"),
    params={"border_frac": 0.07, "fringe_length": 0.05},
    optional_materials=("fringe",),
)
def rug(b: PartBuilder, p: dict[str, float]) -> None:
    """Flat rectangular rug along x: patterned field, bound border (slightly proud), fringes at both ends
    (material ``fringe``, when defined)."""
    W, D, H = p["width"], p["depth"], p["height"]
    fl = p["fringe_length"] if b.has("fringe") else 0.0
    bw = p["border_frac"] * min(W, D)
    x0, x1 = -W / 2 + fl, W / 2 - fl
    e = 0.001
    b.box_span("field", (x0 + bw - e, -D / 2 + bw - e, 0.0), (x1 - bw + e, D / 2 - bw + e, H - 0.0006))
    for sy in (-1, 1):
        b.box_span(
            "border",
            (x0, min(sy * D / 2, sy * (D / 2 - bw)), 0.0),
            (x1, max(sy * D / 2, sy * (D / 2 - bw)), H),
        )
    for sx in (-1, 1):
        xa, xb = sorted((sx * (W / 2 - fl), sx * (W / 2 - fl - bw)))
        b.box_span("border", (xa, -D / 2 + bw - e, 0.0), (xb, D / 2 - bw + e, H - 0.0003))
    if fl > 0:
        for sx in (-1, 1):
            xa, xb = sorted((sx * W / 2, sx * (W / 2 - fl - e)))
            b.box_span("fringe", (xa, -D / 2 + bw, 0.0), (xb, D / 2 - bw, H * 0.35))


@builder("rug_round", materials=("field", "border"), params={"border_frac": 0.06})
def rug_round(b: PartBuilder, p: dict[str, float]) -> None:
    """Flat round rug: patterned disc inside a bound border ring (slightly proud)."""
    W, H = p["width"], p["height"]
    R = W / 2
    bw = p["border_frac"] * W
    b.cylinder("field", R - bw + 0.001, H - 0.0006, (0, 0, (H - 0.0006) / 2), segments=48)
    ring = [(R - bw, 0.0), (R, 0.0), (R, H), (R - bw, H), (R - bw, 0.0)]
    b.revolve("border", ring, segments=48)


@builder("poster", materials=("print", "sheet"), params={"margin": 0.02})
def poster(b: PartBuilder, p: dict[str, float]) -> None:
    """Unframed poster: a paper sheet (flat back at y = -depth/2) with the print (uv fit) inside a margin."""
    W, D, H = p["width"], p["depth"], p["height"]
    m = p["margin"]
    b.box_span("sheet", (-W / 2, -D / 2, 0.0), (W / 2, 0.0, H))
    b.box_span("print", (-W / 2 + m, -0.0005, m * 1.4), (W / 2 - m, D / 2, H - m), uv_mode="fit")


# ------------------------------------------------------------------------------------------ tableware
@builder(
    "mug", materials=("body",), params={"taper": 0.9, "wall": 0.004, "handle_top": 0.8, "handle_bottom": 0.22}
)
def mug(b: PartBuilder, p: dict[str, float]) -> None:
    """Mug: tapered turned body (open, with a floor) of diameter ``depth``, a loop handle towards +x from
    ``handle_bottom`` to ``handle_top`` (fractions of the height) reaching the width."""
    W, D, H = p["width"], p["depth"], p["height"]
    R = D / 2
    r0 = R * p["taper"]
    w = p["wall"]
    xc = -W / 2 + R
    b.revolve(
        "body",
        [(0, 0), (r0, 0), (R, H), (R - w, H), (r0 - w, 0.008), (0, 0.008)],
        centre=(xc, 0, 0),
        segments=32,
    )
    reach = W - 2 * R
    hr = min(0.006, reach * 0.25)
    z_top, z_bot = H * p["handle_top"], H * p["handle_bottom"]

    def wall_x(z: float) -> float:
        return xc + r0 + (R - r0) * z / H - w / 2

    t = np.linspace(-np.pi / 2, np.pi / 2, 13)
    s = (t + np.pi / 2) / np.pi
    xa = wall_x(z_bot) * (1 - s) + wall_x(z_top) * s
    a = (W / 2 - hr) - xa
    path = np.stack(
        [xa + a * np.cos(t), np.zeros_like(t), (z_bot + z_top) / 2 + (z_top - z_bot) / 2 * np.sin(t)], 1
    )
    b.tube("body", path, hr, segments=8)
    _fit_box(b, W, D, H)


def _bowl_profile(R: float, H: float, foot: float, wall: float, n: int = 6) -> list[tuple[float, float]]:
    z = np.linspace(0, H, n)
    r = R * (foot + (1 - foot) * np.sin(0.5 * np.pi * z / H) ** 0.8)
    outer = list(zip(r, z, strict=True))
    zi = np.linspace(H, max(wall * 1.5, 0.004), n - 1)
    inner = [
        (max(R * (foot + (1 - foot) * np.sin(0.5 * np.pi * zz / H) ** 0.8) - wall, 0.003), zz) for zz in zi
    ]
    return [(0.0, 0.0), *outer, *inner, (0.0, inner[-1][1])]


@builder("bowl", materials=("body",), params={"foot_frac": 0.45, "wall": 0.005})
def bowl(b: PartBuilder, p: dict[str, float]) -> None:
    """Open bowl: a smooth turned profile from a small foot to the rim (diameter = width)."""
    W, H = p["width"], p["height"]
    b.revolve("body", _bowl_profile(W / 2, H, p["foot_frac"], p["wall"]), segments=32)


@builder(
    "fruit_bowl",
    materials=("bowl", "fruit", "fruit2"),
    params={"bowl_frac": 0.55, "n_fruit": None},
)
def fruit_bowl(b: PartBuilder, p: dict[str, float]) -> None:
    """A bowl holding a ring of fruit with one on top (two kinds alternate); the fruit size is chosen so the
    pile reaches the declared height."""
    W, H = p["width"], p["height"]
    R = W / 2
    hb = H * p["bowl_frac"]
    foot, wall = 0.45, 0.006
    b.revolve("bowl", _bowl_profile(R, hb, foot, wall, n=6), segments=24)
    ring = max(_count(p, "n_fruit") - 1, 2)
    jitter = b.rng.uniform(-0.1, 0.1, _MAX_ITEMS)

    def pile(rf: float) -> tuple[float, float, float]:
        """(ring radius, ring centre z, top fruit centre z) for fruit of radius ``rf``: the ring leans on
        the inner wall (the largest radius at which no fruit crosses it), the last fruit rests on the ring."""
        zc = 1.5 * wall + rf
        zz = np.linspace(zc - rf, zc + rf, 24)
        r_in = R * (foot + (1 - foot) * np.sin(0.5 * np.pi * np.clip(zz / hb, 0, 1)) ** 0.8) - wall
        rho = max(0.0, float(np.min(r_in - np.sqrt(np.clip(rf**2 - (zz - zc) ** 2, 0, None)))) - 0.001)
        rho = max(rho, rf / np.sin(np.pi / ring))  # ring fruit do not overlap each other
        return rho, zc, zc + float(np.sqrt(max(4 * rf**2 - rho**2, 0.0)))

    # the fruit size that makes the pile the declared height (bisection), with the ring inside the bowl
    lo, hi = 0.12 * R, min(0.45 * R, (R - wall - 0.001) / (1 + 1 / np.sin(np.pi / ring)))
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if pile(mid)[2] + mid < H else (lo, mid)
    rf = 0.5 * (lo + hi)
    rho, zc, z_top = pile(rf)
    for k in range(ring):
        a = 2 * np.pi * k / ring + jitter[k]
        mat = "fruit" if k % 2 == 0 else "fruit2"
        b.sphere(mat, rf, (rho * np.cos(a), rho * np.sin(a), zc), segments=12, rings=6)
    b.sphere("fruit2", rf, (0.0, 0.0, z_top), segments=12, rings=6)
    _fit_box(b, W, p["depth"], H)


@builder(
    "bottle_set",
    materials=("glass", "label", "cap"),
    params={"n_items": None, "height_spread": 0.3, "neck_frac": 0.35, "shoulder_frac": 0.6},
)
def bottle_set(b: PartBuilder, p: dict[str, float]) -> None:
    """Bottles or jars in a row along x: turned glass bodies of varied heights and girths with a printed
    label band and a cap (a short neck and wide cap make a jar)."""
    W, D, H = p["width"], p["depth"], p["height"]
    n = _count(p, "n_items")
    rng = b.rng
    hu = rng.uniform(0, 1, _MAX_ITEMS)[:n]
    hu[int(np.argmin(hu))] = 0.0
    ru = rng.uniform(0.75, 1.0, _MAX_ITEMS)[:n]
    ru[int(np.argmax(ru))] = 1.0
    gap = 0.006
    d = ru * D
    d *= min(1.0, (W - gap * (n - 1)) / d.sum())
    gap = (W - d.sum()) / max(n - 1, 1)
    x = -W / 2
    for k in range(n):
        r = d[k] / 2 - 0.0008  # the label band sets the girth
        h = H * (1 - p["height_spread"] * hu[k])
        rn = max(r * p["neck_frac"], 0.004)
        cap_h = min(0.02, 0.12 * h)
        hs = (h - cap_h) * p["shoulder_frac"]
        xc = x + r
        b.revolve(
            "glass",
            [
                (0, 0),
                (r, 0),
                (r, hs),
                (rn, hs + 0.6 * (h - cap_h - hs)),
                (rn, h - cap_h + 0.002),
                (0, h - cap_h + 0.002),
            ],
            centre=(xc, 0, 0),
            segments=16,
        )
        lb = 0.6 * hs
        b.cylinder("label", r + 0.0008, lb, (xc, 0, 0.15 * hs + lb / 2), segments=16)
        b.cylinder("cap", rn + 0.0015, cap_h, (xc, 0, h - cap_h / 2), segments=12)
        x += d[k] + gap
    _fit_box(b, W, D, H)


@builder(
    "candles",
    materials=("wax", "holder", "wick"),
    params={"n_candles": None, "tray_height": 0.015, "band_frac": 0.3},
    optional_materials=("band",),
)
def candles(b: PartBuilder, p: dict[str, float]) -> None:
    """Pillar candles of different heights on a round tray (the tray sets width and depth), each with a
    printed paper band (material ``band``, ``band_frac`` of its height) when defined."""
    W, D, H = p["width"], p["depth"], p["height"]
    R = min(W, D) / 2
    th = p["tray_height"]
    b.revolve(
        "holder",
        [(0, 0), (R * 0.92, 0), (R, th), (R - 0.006, th), (R - 0.006, th * 0.4), (0, th * 0.4)],
        segments=32,
    )
    n = _count(p, "n_candles")
    rng = b.rng
    hu = rng.uniform(0.45, 1.0, _MAX_ITEMS)[:n]
    hu[0] = 1.0
    rc = R * (0.45 if n == 1 else 0.34 if n == 2 else 0.3)
    wick_h = 0.012
    for k in range(n):
        a = 2 * np.pi * k / n + 0.4
        rho = 0.0 if n == 1 else R - 0.008 - rc
        c = np.array([rho * np.cos(a), rho * np.sin(a)])
        hc = (H - th * 0.4 - wick_h) * hu[k]
        b.cylinder("wax", rc, hc, (c[0], c[1], th * 0.4 + hc / 2), segments=16)
        if b.has("band"):
            b.cylinder(
                "band", rc + 0.0008, hc * p["band_frac"], (c[0], c[1], th * 0.4 + hc * 0.45), segments=16
            )
        b.bar(
            "wick",
            (c[0], c[1], th * 0.4 + hc - 0.003),
            (c[0], c[1], th * 0.4 + hc + wick_h),
            0.0012,
            segments=4,
        )
    _fit_box(b, W, D, H)


# ------------------------------------------------------------------------------------------ containers
@builder(
    "basket",
    materials=("weave", "rim"),
    params={"taper": 0.8, "rim_radius": 0.008, "handle_rise": 0.0, "wall": 0.006},
    optional_materials=("handle",),
)
def basket(b: PartBuilder, p: dict[str, float]) -> None:
    """Round woven basket: tapered open body with a floor, a rolled rim and (material ``handle``) an arched
    handle across it rising ``handle_rise`` of the height above the rim."""
    W, D, H = p["width"], p["depth"], p["height"]
    R = min(W, D) / 2
    rr, w = p["rim_radius"], p["wall"]
    hb = H * (1 - p["handle_rise"]) if b.has("handle") else H
    top = hb - rr
    rt = R - rr
    r0 = rt * p["taper"]
    b.revolve("weave", [(0, 0), (r0, 0), (rt, top), (rt - w, top), (r0 - w, 0.01), (0, 0.01)], segments=24)
    b.torus("rim", rt, rr, (0, 0, top), segments=32, ring_segments=8)
    if b.has("handle") and hb < H:
        hr = 0.008
        t = np.linspace(0, np.pi, 13)
        ax = rt - rr - hr
        path = np.stack([ax * np.cos(t), np.zeros_like(t), top + (H - hr - top) * np.sin(t)], 1)
        b.tube("handle", path, hr, segments=8)
    _fit_box(b, W, D, H)


@builder("waste_bin", materials=("body", "liner"), params={"taper": 0.85, "wall": 0.004, "fold": 0.03})
def waste_bin(b: PartBuilder, p: dict[str, float]) -> None:
    """Round waste bin: tapered open body with a floor and a bin liner folded over the rim (``fold`` deep)."""
    W, H = p["width"], p["height"]
    R = W / 2
    w = p["wall"]
    lt, e = 0.0015, 0.0003  # liner thickness, clearance to the bin
    rt = R - lt
    r0 = rt * p["taper"]
    top = H - lt
    b.revolve("body", [(0, 0), (r0, 0), (rt, top), (rt - w, top), (r0 - w, 0.01), (0, 0.01)], segments=32)
    zb = top - p["fold"]

    def r_out(z: float) -> float:
        return r0 + (rt - r0) * z / top

    def r_in(z: float) -> float:
        return (r0 - w) + (rt - r0) * (z - 0.01) / (top - 0.01)

    # the liner: a sheet down the inner wall, over the rim, and folded down the outside by ``fold``
    loop = [
        (r_in(zb) - e - lt, zb),
        (r_in(top) - e - lt, top),
        (r_in(top) - e - lt, H),
        (R, H),
        (R, top),
        (r_out(zb) + e + lt, zb),
        (r_out(zb) + e, zb),
        (rt + e, top + e),
        (r_in(top) - e, top + e),
        (r_in(zb) - e, zb),
        (r_in(zb) - e - lt, zb),
    ]
    b.revolve("liner", loop, segments=32)
    _fit_box(b, W, p["depth"], H)


# ------------------------------------------------------------------------------------------ plants
@builder(
    "plant_prop",
    materials=("pot", "soil", "foliage"),
    params={"pot_height": None, "n_leaves": None, "leaf_size": 0.06, "pot_frac": 0.6},
)
def plant_prop(b: PartBuilder, p: dict[str, float]) -> None:
    """Small potted plant (light in triangles): turned pot with rim, soil, leaves on stems filling the
    declared box above the soil (the foliage sets width and depth, the pot is ``pot_frac`` of them)."""
    W, D, H = p["width"], p["depth"], p["height"]
    ph = p["pot_height"]
    pr = 0.5 * min(W, D) * p["pot_frac"]
    b.revolve(
        "pot",
        [
            (0, 0),
            (pr * 0.75, 0),
            (pr * 0.97, ph - 0.012),
            (pr, ph - 0.012),
            (pr, ph),
            (pr - 0.006, ph),
            (pr - 0.006, 0.012),
            (0, 0.012),
        ],
        segments=20,
    )
    b.cylinder("soil", pr - 0.007, 0.008, (0, 0, ph - 0.014), segments=20)
    rng = b.rng
    n = _count(p, "n_leaves")
    ls = p["leaf_size"]
    draws = rng.uniform(0, 1, (_MAX_ITEMS, 5))
    for k in range(n):
        u = draws[k]
        a = 2 * np.pi * k / n + (u[0] - 0.5) * 0.6
        reach = 0.3 + 0.7 * u[1]
        c = np.array(
            [
                reach * np.cos(a) * W / 2,
                reach * np.sin(a) * D / 2,
                ph + 0.02 + (0.3 + 0.7 * u[2]) * (H - ph - 0.02),
            ]
        )
        R = prim.rot_z(a) @ prim.rot_y(0.3 + 0.8 * u[3])
        half = ls * (0.7 + 0.5 * u[4])
        b.bar("foliage", (0.08 * c[0], 0.08 * c[1], ph - 0.014), c, 0.0025, segments=6)
        leaf = [
            (0.0, -half * 0.07),
            (half * 0.5, -half * 0.05),
            (half, 0.0),
            (half * 0.5, half * 0.05),
            (0.0, half * 0.07),
        ]
        b.revolve("foliage", leaf, centre=c, rotation=R, segments=8, uv_style="cyl")
    parts = b.parts["foliage"]
    V = np.concatenate([q.vertices for q in parts])
    lo, hi = V.min(0), V.max(0)
    t_lo, t_hi = np.array([-W / 2, -D / 2, lo[2]]), np.array([W / 2, D / 2, H])
    sc = (t_hi - t_lo) / (hi - lo)
    for q in parts:
        q.vertices = t_lo + (q.vertices - lo) * sc


# ------------------------------------------------------------------------------------------ shoes
@builder(
    "shoes_pair",
    materials=("upper", "sole", "lining"),
    params={"gap": 0.03, "splay_deg": 8.0, "toe_drop": 0.45, "sole_thickness": 0.025, "n_laces": 4},
    optional_materials=("laces",),
)
def shoes_pair(b: PartBuilder, p: dict[str, float]) -> None:
    """A pair of shoes side by side, toes to the front (+y), slightly splayed: rubber sole, upper lower at
    the toe (``toe_drop``), dark collar opening at the heel, ``n_laces`` lace rungs over the instep (material
    ``laces``, when defined)."""
    W, D, H = p["width"], p["depth"], p["height"]
    g = p["gap"]
    th = np.deg2rad(p["splay_deg"])
    c, s = np.cos(th), np.sin(th)
    ex, ey = (W - g) / 2, D  # one turned shoe's footprint
    ts = p["sole_thickness"]
    uh = H - ts
    t = np.linspace(0, 2 * np.pi, 17)[:-1]
    # sole outline: an egg, wider at the toe (+y), for a unit shoe; scaled to sw x sl so that the turned
    # sole and upper (rounded-box corners) fill ex x ey (a few fixed-point steps from a rectangle's solution)
    egg = np.stack([0.5 * np.cos(t) * (1 + 0.12 * np.sin(t)), 0.5 * np.sin(t)], 1)
    sw = max((ex * c - ey * s) / (c * c - s * s), 0.3 * ex)
    sl = (ey - sw * s) / c
    R2 = np.array([[c, s], [-s, c]])
    for _ in range(4):
        r = min(uh * 0.45, 0.47 * sw * 0.999)
        k = 0.47 - (r - r / np.sqrt(2)) / np.array([sw, sl])
        pts = np.concatenate([egg, np.array([[sx * k[0], sy * k[1]] for sx in (-1, 1) for sy in (-1, 1)])])
        foot = (pts * [sw, sl]) @ R2.T
        ext = foot.max(0) - foot.min(0)
        sw, sl = sw * ex / ext[0], sl * ey / ext[1]
    ox, oy = sw * egg[:, 0], sl * egg[:, 1]
    for side in (-1, 1):
        R = prim.rot_z(-side * th)  # toes turn outwards
        cx = side * (g + ex) / 2
        outline = np.stack([side * ox, oy], 1)
        if side < 0:
            outline = outline[::-1]
        b.extrude("sole", outline, ts, centre=(cx, 0, ts / 2), rotation=R)
        upper = b.rounded_box(
            "upper", (sw * 0.94, sl * 0.94, uh), (0, 0, ts + uh / 2 - 0.001), uh * 0.45, cells=6
        )
        V = upper.vertices
        f = 1 - p["toe_drop"] * np.clip(V[:, 1] / (sl * 0.47), 0, 1) ** 1.5
        V[:, 2] = ts - 0.001 + (V[:, 2] - ts + 0.001) * f
        upper.vertices = V @ R.T + np.array([cx, 0, 0])
        if b.has("laces"):
            for j in range(int(round(p["n_laces"]))):
                yl = sl * (0.0 + 0.06 * j)
                zl = ts - 0.001 + uh * (1 - p["toe_drop"] * min(yl / (sl * 0.47), 1.0) ** 1.5) - 0.0005
                half = 0.12 * sw
                ends = [R @ np.array([sx * half, yl, zl]) + np.array([cx, 0.0, 0.0]) for sx in (-1, 1)]
                b.bar("laces", ends[0], ends[1], 0.002, segments=4)
        collar = [(0.5 * sw * 0.55 * np.cos(a), -0.18 * sl + 0.12 * sl * np.sin(a)) for a in t]
        b.extrude("lining", collar, 0.004, centre=(cx, 0, H - 0.0015), rotation=R)
    _fit_box(b, W, D, H)


# ------------------------------------------------------------------------------------------ gadgets, toys
@builder("laptop", materials=("shell", "trim", "stickers"), params={"base_frac": 0.5, "n_stickers": 3})
def laptop(b: PartBuilder, p: dict[str, float]) -> None:
    """Closed laptop: rounded base and lid with a dark gap line, hinge at the back (-y), stickers on the lid
    (uv fit), front (+y) is the opening edge."""
    W, D, H = p["width"], p["depth"], p["height"]
    st = 0.0004
    hb = (H - st) * p["base_frac"]
    hl = H - st - hb - 0.0015
    r = min(0.005, hb * 0.45, hl * 0.45)
    b.rounded_box("shell", (W, D, hb), (0, 0, hb / 2), r, cells=6)
    b.rounded_box("shell", (W - 0.002, D - 0.002, hl), (0, 0.001, hb + 0.0015 + hl / 2), r, cells=6)
    b.box("trim", (W - 2 * r, D - 2 * r, 0.003), (0, 0, hb + 0.00075))
    b.cylinder("trim", 0.0035, W * 0.7, (0, -D / 2 + 0.0036, hb + 0.0008), axis=(1, 0, 0), segments=8)
    rng = b.rng
    n = int(round(p["n_stickers"]))
    u = rng.uniform(0, 1, (_MAX_ITEMS, 3))
    z_top = hb + 0.0015 + hl
    for k in range(n):
        s = 0.03 + 0.04 * u[k, 2]
        x = (u[k, 0] - 0.5) * (W - 2 * s - 0.02)
        y = (u[k, 1] - 0.5) * (D - 2 * s - 0.02)
        b.box("stickers", (s, s * 0.8, st * (2 - 0.2 * k)), (x, y, z_top), uv_mode="fit")  # no coplanar tops
    _fit_box(b, W, D, H)


@builder("ball", materials=("cover",), params={"flat": 0.04})
def ball(b: PartBuilder, p: dict[str, float]) -> None:
    """A ball (printed cover) resting on the floor: its bottom pressed flat by ``flat`` of its radius."""
    W = p["width"]
    R = W / 2
    d = p["flat"] * R
    a0 = np.arcsin(np.clip((d - R) / R, -1, 1))
    a = np.concatenate([np.linspace(a0, 0, 7), np.linspace(0, np.pi / 2, 7)[1:]])
    prof = [(0.0, 0.0), *zip(R * np.cos(a), R * np.sin(a) + R - d, strict=True)]
    prof[-1] = (0.0, 2 * R - d)
    b.revolve("cover", prof, segments=24, uv_style="cyl")
    _fit_box(b, W, p["depth"], p["height"])


@builder("toy_blocks", materials=("blocks",), params={"twist_deg": 10.0, "shift": 0.5})
def toy_blocks(b: PartBuilder, p: dict[str, float]) -> None:
    """Toy building blocks: a 3-2-1 pyramid. The bottom row of three cubes sets the box; the blocks above
    are turned up to ``twist_deg`` about z (their square footprint shrinks so it stays within a cube's) and
    slide up to ``shift`` of the free space along the row."""
    W, D, H = p["width"], p["depth"], p["height"]
    u = b.rng.uniform(-1, 1, (6, 2))
    s = D
    gx = max((W - 3 * s) / 2, 0.0)  # the gap between neighbours in the bottom row
    pitch = s + gx
    sz = (H - 0.001) / 3  # block height (0.5 mm between rows)
    k = 0
    for row, n in enumerate((3, 2, 1)):
        for j in range(n):
            x = (j - (n - 1) / 2) * pitch
            a = np.deg2rad(p["twist_deg"]) * u[k, 0] if row else 0.0
            f = 1.0 / (abs(np.cos(a)) + abs(np.sin(a)))
            if row:
                x += p["shift"] * u[k, 1] * gx / 2
            z = sz * (row + 0.5) + 0.0005 * row
            b.box("blocks", (s * f, s * f, sz), (x, 0.0, z), rotation=prim.rot_z(float(a)))
            k += 1
    _fit_box(b, W, D, H)
