"""Lamps: table, floor, pendant (ceiling). Shades are thick lathe shells (closed surfaces).

Pendant lamps hang from the ceiling: their canopy is a flat disc whose top is the object's top,
z = height in the canonical frame (the scene places that plane against the ceiling).
"""

from __future__ import annotations

import numpy as np

from synthleak.assets.builders.base import PartBuilder, builder


def _shade(
    b: PartBuilder,
    mat: str,
    z0: float,
    h: float,
    r_bottom: float,
    r_top: float,
    wall: float = 0.006,
    segments: int = 32,
) -> None:
    prof = [(r_bottom, z0), (r_top, z0 + h), (r_top - wall, z0 + h), (r_bottom - wall, z0), (r_bottom, z0)]
    b.revolve(mat, prof, segments=segments)


@builder(
    "lamp_table",
    materials=("base", "shade", "metal"),
    params={"shade_height": None, "shade_top_frac": 0.75, "base_height": None, "base_radius_frac": 0.45},
)
def lamp_table(b: PartBuilder, p: dict[str, float]) -> None:
    """Table lamp: turned ceramic base, metal stem and socket, conical fabric shade."""
    W, H = p["width"], p["height"]
    R = W / 2
    sh, bh = p["shade_height"], p["base_height"]
    rb = R * p["base_radius_frac"]
    b.revolve(
        "base",
        [
            (0, 0),
            (rb * 0.7, 0),
            (rb * 0.75, 0.01),
            (rb, bh * 0.45),
            (rb * 0.5, bh * 0.9),
            (rb * 0.3, bh),
            (0, bh),
        ],
        segments=32,
    )
    b.bar("metal", (0, 0, bh - 0.005), (0, 0, H - sh * 0.4), 0.008)
    b.cylinder("metal", 0.018, 0.05, (0, 0, H - sh * 0.45))
    _shade(b, "shade", H - sh, sh, R, R * p["shade_top_frac"])
    rt = R * p["shade_top_frac"]
    b.bar("metal", (-rt + 0.01, 0, H - 0.01), (rt - 0.01, 0, H - 0.01), 0.002)  # shade spider


@builder(
    "lamp_floor",
    materials=("base", "shade", "metal"),
    params={"shade_height": None, "shade_top_frac": 0.8, "base_radius_frac": 0.6, "pole_radius": 0.012},
)
def lamp_floor(b: PartBuilder, p: dict[str, float]) -> None:
    """Floor lamp: heavy round base, pole, drum shade."""
    W, H = p["width"], p["height"]
    R = W / 2
    sh = p["shade_height"]
    rb = R * p["base_radius_frac"]
    b.revolve("base", [(0, 0), (rb, 0), (rb, 0.02), (rb * 0.8, 0.035), (0.03, 0.04), (0, 0.04)], segments=32)
    b.bar("metal", (0, 0, 0.035), (0, 0, H - sh * 0.4), p["pole_radius"])
    b.cylinder("metal", 0.02, 0.06, (0, 0, H - sh * 0.45))
    b.cylinder("metal", 0.03, 0.04, (0, 0, 0.6))  # switch
    _shade(b, "shade", H - sh, sh, R, R * p["shade_top_frac"])


@builder(
    "lamp_pendant",
    materials=("shade", "metal", "bulb"),
    params={"shade_height": None, "cord_length_frac": 0.55, "canopy_radius": 0.06},
)
def lamp_pendant(b: PartBuilder, p: dict[str, float]) -> None:
    """Pendant lamp: ceiling canopy (flat top at z = height), cord, dome shade, bulb."""
    W, H = p["width"], p["height"]
    R = W / 2
    sh = p["shade_height"]
    cr = p["canopy_radius"]
    b.cylinder("metal", cr, 0.03, (0, 0, H - 0.015), segments=32)
    b.bar("metal", (0, 0, sh - 0.01), (0, 0, H - 0.029), 0.004)  # cord
    rc, wall = 0.04, 0.005
    t = np.linspace(0, np.pi / 2, 12)
    outer = [(rc + (R - rc) * np.sin(a), sh * np.cos(a)) for a in t]
    inner = [(rc + (R - wall - rc) * np.sin(a), (sh - wall) * np.cos(a)) for a in t[::-1]]
    b.revolve("shade", [*outer, *inner, outer[0]], segments=32)
    b.cylinder("metal", 0.022, 0.05, (0, 0, sh - 0.02))
    b.sphere("bulb", 0.03, (0, 0, sh * 0.45))
