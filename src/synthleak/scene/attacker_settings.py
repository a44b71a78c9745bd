"""Where the attacker photographs its objects: varied settings, as web photos have them (issue 30, step 4).

Each attacker object gets its own setting, drawn from the study seed (``derive_seed(seed, "attacker_setting",
object_id)``): an inventory hall, a home, a shop floor, a photo studio with seamless paper sweeps or a walled
courtyard (:data:`SETTING_KINDS`). The four walls of a setting are drawn one by one, so a group of consecutive
orbit views (neighbouring azimuths, the same wall behind the object) shares a background and a quarter orbit
later the background is another: a web photo set of one object is a few photos in one place, a few in another.

Per-photo settings as *several stages per object*, or a background swapped per frame, are not what the
pipeline supports: one attacker stage renders one sequence ``attackers/<id>`` (``render.pipeline.stage_jobs``)
prepared once per renderer, and the local models read that one sequence; so the variation lives inside the
one stage, wall by wall.

Nothing of a setting's surfaces is shared with the rooms: the textures come from their own seed stream
(``make_rng(seed, "attacker_setting", object_id, surface)``, never the rooms') and from this module's own
generators only (:data:`OWN_KINDS`: paper sweep, brick, paving, shop shelves, sky, epoxy floor, corrugated
cladding, carpet, paint), none of :func:`synthleak.assets.textures.make_texture`'s, which the rooms' shells and
furniture use. Colours alone did not keep them apart (SETTINGS_FORMAT 1 drew concrete, metal, fabric, marble,
plastic and pattern from that module with palettes of their own): grey-level features do not see colour, and on
study-small 69 % of the query-side inliers of the attacker queries localized on a room's shell lay on those
floors and walls (``benchmarks/shell_inliers.py``). With these generators the shell-localized queries that were
left came from the server's tolerance, not from shared surfaces: 12 px on 480-px frames let chance consensus of
background to background reach a tier's inlier count; the study presets' strict servers now use HLoc's threshold
as a share of the image width (docs/learned-tiers.md, "The PnP threshold").
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from synthleak import portable
from synthleak.assets.mesh import ObjectMesh
from synthleak.geometry.poses import make_pose
from synthleak.scene.room import SHELL_IDS, SLAB_THICKNESS, WALL_NAMES, WALL_THICKNESS, RoomShell, room_walls
from synthleak.scene.shell_geometry import box_with_holes, planar_box
from synthleak.scene.spec import PlacedObject
from synthleak.scene.styles import Finish, ShellStyle
from synthleak.seeding import make_rng

Colour = tuple[float, float, float]
SETTINGS_FORMAT = 2
"""Part of the attacker stages' skip keys: bump when a setting's output changes for the same seed."""


# ----------------------------------------------------------------------------------- the settings' own textures
def _smooth(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    grid = rng.standard_normal((cells + 1, cells + 1)).astype(np.float32)
    out = cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
    return (out - out.mean()) / max(float(out.std()), 1e-6)


def _u8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)


def _sweep(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """A seamless paper sweep: a soft light fall-off, faint mottling and paper grain (few features)."""
    yy = np.linspace(0.0, 1.0, size, dtype=np.float32)[:, None]
    lum = 1.0 - 0.10 * yy + 0.02 * _smooth(rng, size, 3) + 0.008 * rng.standard_normal((size, size)).astype(
        np.float32)
    return _u8(lum[..., None] * np.asarray(base, np.float32))


def _brick(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """Running-bond brick with mortar joints and a tint per brick."""
    rows = int(rng.integers(14, 20))
    h = size / rows
    w = 2.1 * h
    img = np.empty((size, size, 3), np.float32)
    img[:] = np.asarray((0.72, 0.70, 0.66), np.float32)  # mortar
    base_arr = np.asarray(base, np.float32)
    for r in range(rows + 1):
        offset = (r % 2) * w / 2 + rng.uniform(-2, 2)
        for c in range(-1, int(size / w) + 2):
            x0, y0 = c * w + offset, r * h
            tint = base_arr * float(rng.uniform(0.75, 1.15)) + rng.normal(0, 0.03, 3).astype(np.float32)
            cv2.rectangle(img, (int(x0 + 2), int(y0 + 2)), (int(x0 + w - 2), int(y0 + h - 2)),
                          tuple(float(v) for v in tint), -1)
    return _u8(img * (1.0 + 0.06 * _smooth(rng, size, 40))[..., None])


def _paving(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """Stone pavers of uneven sizes with dark joints."""
    img = np.empty((size, size, 3), np.float32)
    img[:] = np.asarray(base, np.float32) * 0.45
    y = 0.0
    while y < size:
        h = float(rng.uniform(0.08, 0.16) * size)
        x = float(rng.uniform(-0.1, 0) * size)
        while x < size:
            w = float(rng.uniform(0.10, 0.22) * size)
            tint = np.asarray(base, np.float32) * float(rng.uniform(0.8, 1.2))
            cv2.rectangle(img, (int(x + 3), int(y + 3)), (int(x + w - 3), int(y + h - 3)),
                          tuple(float(v) for v in tint), -1)
            x += w
        y += h
    return _u8(img * (1.0 + 0.10 * _smooth(rng, size, 60))[..., None])


def _shelves(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """Shop shelving: shelf boards (``base``) filled with boxes and packs of many colours."""
    img = np.empty((size, size, 3), np.float32)
    img[:] = np.asarray(base, np.float32) * 0.55
    levels = int(rng.integers(4, 7))
    h = size / levels
    for lv in range(levels):
        y1 = int((lv + 1) * h) - 6
        cv2.rectangle(img, (0, y1), (size, y1 + 6), tuple(float(v) for v in base), -1)
        x = float(rng.uniform(0, 8))
        while x < size:
            w = float(rng.uniform(0.03, 0.09) * size)
            top = y1 - float(rng.uniform(0.45, 0.9) * h)
            colour = tuple(float(v) for v in rng.uniform(0.1, 0.95, 3))
            cv2.rectangle(img, (int(x), int(top)), (int(x + w - 2), y1), colour, -1)
            if rng.random() < 0.6:  # a label band
                band = tuple(float(v) for v in rng.uniform(0.05, 1.0, 3))
                mid = int(top + 0.4 * (y1 - top))
                cv2.rectangle(img, (int(x + 2), mid), (int(x + w - 4), mid + int(0.1 * (y1 - top)) + 2), band, -1)
            x += w
    return _u8(img)


def _sky(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """A hazy sky (the courtyard's far ceiling): a smooth gradient and soft clouds."""
    clouds = np.clip(_smooth(rng, size, 4), 0, None)
    img = np.asarray(base, np.float32) * (1 - 0.3 * clouds[..., None]) + 0.3 * clouds[..., None]
    return _u8(img)


def _epoxy(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """A poured epoxy floor: a smooth coat with broad mottling, painted safety lines and long tyre scuffs (no
    pores or flecks: a room's concrete, plastic and fabric share their speckle, this floor does not)."""
    lum = 1.0 + 0.05 * _smooth(rng, size, 5) + 0.02 * _smooth(rng, size, 24)
    img = lum[..., None] * np.asarray(base, np.float32)
    paint = np.asarray((0.86, 0.74, 0.18) if rng.random() < 0.6 else (0.90, 0.90, 0.88), np.float32)
    for _ in range(int(rng.integers(1, 3))):  # long straight painted lane lines
        width = int(rng.uniform(0.012, 0.025) * size)
        at = int(rng.uniform(0.15, 0.85) * size)
        if rng.random() < 0.5:
            img[:, at:at + width] = paint
        else:
            img[at:at + width, :] = paint
    scuffs = np.zeros((size, size), np.float32)
    for _ in range(int(rng.integers(3, 7))):  # tyre scuffs: wide soft arcs
        centre = tuple(int(v) for v in rng.uniform(-0.5, 1.5, 2) * size)
        radius = int(rng.uniform(0.4, 1.2) * size)
        start = float(rng.uniform(0, 360))
        cv2.ellipse(scuffs, centre, (radius, radius), 0.0, start, start + float(rng.uniform(20, 60)), 1.0,
                    max(2, size // 90), cv2.LINE_AA)  # anti-aliased: no blur pass (GaussianBlur is CPU-dispatched)
    return _u8(img * (1.0 - 0.25 * scuffs[..., None]))


def _cladding(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """Corrugated metal cladding: vertical ribs, horizontal panel seams and broad weathering."""
    xx = np.arange(size, dtype=np.float32)[None, :]
    period = size / float(rng.integers(28, 44))
    ribs = 0.5 + 0.5 * portable.cos(2 * np.pi * xx / period)  # numpy's own cos: other bits on another CPU
    lum = 0.88 + 0.16 * ribs + 0.05 * _smooth(rng, size, 4)
    img = np.repeat(lum, size, axis=0) if lum.shape[0] == 1 else lum
    img = img[..., None] * np.asarray(base, np.float32)
    panels = int(rng.integers(2, 4))
    for k in range(1, panels):  # seams between sheet rows
        y = int(k * size / panels + rng.uniform(-0.02, 0.02) * size)
        img[max(0, y - 2):y + 2] *= 0.55
    return _u8(img)


def _carpet(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """A loop-pile carpet: a pile finer than a camera pixel at orbit distance and soft wear patches."""
    pile = rng.standard_normal((size, size)).astype(np.float32)
    lum = 1.0 + 0.03 * pile + 0.06 * _smooth(rng, size, 6)
    return _u8(lum[..., None] * np.asarray(base, np.float32))


def _paint(rng: np.random.Generator, base: Colour, size: int) -> np.ndarray:
    """A painted wall: roller marks (soft vertical streaks) on an even coat."""
    streaks = cv2.resize(rng.standard_normal((1, int(rng.integers(30, 60)))).astype(np.float32), (size, size),
                         interpolation=cv2.INTER_CUBIC)
    lum = 1.0 + 0.012 * streaks + 0.02 * _smooth(rng, size, 3)
    return _u8(lum[..., None] * np.asarray(base, np.float32))


OWN_KINDS: dict[str, Callable[[np.random.Generator, Colour, int], np.ndarray]] = {
    "sweep": _sweep,
    "brick": _brick,
    "paving": _paving,
    "shelves": _shelves,
    "sky": _sky,
    "epoxy": _epoxy,
    "cladding": _cladding,
    "carpet": _carpet,
    "paint": _paint,
}
"""The settings' texture kinds: every surface of a setting draws from these, none from
:mod:`synthleak.assets.textures` (whose generators the rooms' shells and furniture share, colours aside: grey
features do not see colour)."""


# ----------------------------------------------------------------------------------------------- the settings
@dataclass(frozen=True)
class SettingKind:
    """One kind of setting: size ranges (metres), a finish per surface, lights and fill."""

    name: str
    size_x: tuple[float, float]
    size_y: tuple[float, float]
    height: tuple[float, float]
    finishes: dict[str, Finish]
    light_colour: Colour
    light_intensity: tuple[float, float]
    ambient: tuple[float, float]
    lights: tuple[int, int]

    def style(self, size: tuple[float, float, float]) -> ShellStyle:
        return ShellStyle(self.name, self.finishes, self.light_colour, self.light_intensity, self.ambient, size)


@dataclass(frozen=True)
class PairedFinish(Finish):
    """A finish whose ``kinds[i]`` goes with ``colours[i]`` (red brick, green foliage, not the other way)."""

    def draw(self, rng: np.random.Generator) -> tuple[str, Colour]:
        i = int(rng.integers(len(self.kinds)))
        return self.kinds[i], self.colours[i]


def _f(kinds: tuple[str, ...], *colours: Colour) -> Finish:
    """Kinds and colours drawn independently (one kind: every colour goes with it), else paired one to one."""
    if len(kinds) == 1:
        return Finish(kinds, tuple(colours))
    if len(kinds) != len(colours):
        raise ValueError(f"attacker setting finish: {len(kinds)} kinds need as many colours, got {len(colours)}")
    return PairedFinish(kinds, tuple(colours))


SETTING_KINDS: tuple[SettingKind, ...] = (
    SettingKind("inventory_hall", (11.0, 14.0), (9.0, 12.0), (4.2, 5.0), {
        "floor": _f(("epoxy",), (0.30, 0.40, 0.42), (0.52, 0.46, 0.36)),  # epoxy teal / dusty ochre
        "wall": _f(("cladding", "cladding", "shelves", "shelves"), (0.26, 0.36, 0.52), (0.62, 0.34, 0.22),
                   (0.40, 0.46, 0.30), (0.75, 0.75, 0.70)),
        "ceiling": _f(("cladding",), (0.62, 0.60, 0.52)),
        "pedestal": _f(("paint", "paint"), (0.20, 0.40, 0.70), (0.25, 0.25, 0.28)),
        "panel": _f(("sweep",), (0.86, 0.86, 0.84)),
    }, (0.88, 0.94, 1.0), (14.0, 22.0), (0.08, 0.12), (4, 7)),
    SettingKind("home", (7.5, 9.0), (7.0, 8.5), (2.6, 3.0), {
        "floor": _f(("carpet", "carpet", "epoxy"), (0.45, 0.22, 0.20), (0.30, 0.36, 0.50), (0.92, 0.90, 0.86)),
        "wall": _f(("paint", "paint", "brick"), (0.64, 0.54, 0.76), (0.52, 0.70, 0.56), (0.74, 0.40, 0.30)),
        "ceiling": _f(("sweep",), (0.96, 0.95, 0.92)),
        "pedestal": _f(("paint", "paint"), (0.28, 0.16, 0.10), (0.80, 0.80, 0.78)),
        "panel": _f(("paint",), (0.40, 0.55, 0.70)),
    }, (1.0, 0.86, 0.70), (5.0, 9.0), (0.05, 0.09), (2, 4)),
    SettingKind("shop_floor", (10.0, 13.0), (8.0, 11.0), (3.4, 4.2), {
        "floor": _f(("epoxy", "carpet"), (0.80, 0.78, 0.70), (0.34, 0.34, 0.38)),
        "wall": _f(("shelves",), (0.85, 0.85, 0.88), (0.30, 0.30, 0.32), (0.70, 0.58, 0.40)),
        "ceiling": _f(("sweep",), (0.90, 0.92, 0.94)),
        "pedestal": _f(("paint",), (0.95, 0.95, 0.95), (0.80, 0.15, 0.15)),
        "panel": _f(("shelves",), (0.90, 0.90, 0.90)),
    }, (0.96, 0.98, 1.0), (9.0, 15.0), (0.08, 0.12), (4, 6)),
    SettingKind("photo_studio", (7.5, 9.0), (7.5, 9.0), (3.0, 3.6), {
        "floor": _f(("sweep",), (0.93, 0.93, 0.92), (0.72, 0.73, 0.75), (0.20, 0.20, 0.22)),
        "wall": _f(("sweep",), (0.95, 0.95, 0.94), (0.66, 0.68, 0.70), (0.18, 0.18, 0.20), (0.55, 0.70, 0.85)),
        "ceiling": _f(("sweep",), (0.30, 0.30, 0.30)),
        "pedestal": _f(("sweep",), (0.97, 0.97, 0.97)),
        "panel": _f(("sweep",), (0.94, 0.94, 0.93)),
    }, (1.0, 0.98, 0.96), (10.0, 16.0), (0.10, 0.16), (3, 5)),
    SettingKind("courtyard", (10.0, 14.0), (10.0, 14.0), (7.0, 9.0), {
        "floor": _f(("paving",), (0.62, 0.58, 0.52), (0.50, 0.40, 0.30)),
        "wall": _f(("brick", "paint", "brick"), (0.62, 0.30, 0.22), (0.80, 0.76, 0.66), (0.55, 0.52, 0.48)),
        "ceiling": _f(("sky",), (0.62, 0.74, 0.90)),
        "pedestal": _f(("paving",), (0.60, 0.60, 0.58)),
        "panel": _f(("brick",), (0.58, 0.34, 0.26)),
    }, (1.0, 0.97, 0.90), (18.0, 26.0), (0.14, 0.20), (3, 5)),
)
"""The kinds a setting is drawn from (uniformly, per attacker object)."""


def setting_texture(kind: str, colour: Colour, rng: np.random.Generator, size: int) -> np.ndarray:
    """One surface's texture: the settings' own generator of ``kind`` (:data:`OWN_KINDS`)."""
    try:
        return OWN_KINDS[kind](rng, colour, size)
    except KeyError:
        raise ValueError(f"attacker setting texture kind {kind!r} is not a setting's own "
                         f"(known: {', '.join(OWN_KINDS)})") from None


@dataclass
class Setting:
    """A drawn setting: its kind, the shell (with ``style`` for props and lights) and what each surface got."""

    kind: SettingKind
    style: ShellStyle
    shell: RoomShell
    surfaces: dict[str, tuple[str, Colour]]
    """surface (floor, ceiling, wall_south, ...) -> (texture kind, colour)."""


def draw_surface(setting: SettingKind, surface: str, seed: int, object_id: str, name: str,
                 size: int) -> tuple[np.ndarray, str, Colour]:
    """Texture, kind and colour of one surface ``name`` (a finish ``surface``), from its own seed stream."""
    rng = make_rng(seed, "attacker_setting", object_id, name)
    kind, colour = setting.finishes[surface].draw(rng)
    return setting_texture(kind, colour, rng, size), kind, colour


def min_room_size(extents: np.ndarray) -> float:
    """Least interior side (m) keeping an orbit around an object of ``extents`` inside the walls: the
    bounding sphere seen at 65 degrees hfov, 4:3 (``render.trajectories.orbit_distance``), times 1.1, plus 0.5 m."""
    half_angle = 0.5 * 2.0 * np.arctan(np.tan(np.radians(32.5)) * 0.75)
    distance = 0.5 * float(np.linalg.norm(extents)) / np.sin(half_angle)
    return 2.0 * (1.1 * distance + 0.5)


def draw_setting(seed: int, object_id: str, target_extents: np.ndarray, texture_size: int = 1024) -> Setting:
    """The setting of attacker object ``object_id``: its kind, size, and floor, ceiling and four walls (each
    wall its own texture draw); no openings."""
    rng = make_rng(seed, "attacker_setting", object_id, "kind")
    kind = SETTING_KINDS[int(rng.integers(len(SETTING_KINDS)))]
    least = min_room_size(target_extents)
    x = max(float(rng.uniform(*kind.size_x)), least)
    y = max(float(rng.uniform(*kind.size_y)), least)
    h = float(rng.uniform(*kind.height))
    t, s = WALL_THICKNESS, SLAB_THICKNESS
    walls = room_walls((x, y, h))
    pieces: list[PlacedObject] = []
    surfaces: dict[str, tuple[str, Colour]] = {}

    def piece(name: str, part, pose: np.ndarray, support: str, ext) -> PlacedObject:
        return PlacedObject(instance_id=SHELL_IDS[name], name=name, model_id=f"shell_{name.split('_')[0]}",
                            category="shell", symmetry="none", world_from_object=pose, mesh=ObjectMesh([part]),
                            role="shell", support=support, extents=np.asarray(ext, dtype=np.float64))

    for name, z in (("floor", -s), ("ceiling", h)):
        ext = np.array([x + 2 * t, y + 2 * t, s])
        lo, hi = np.array([-ext[0] / 2, -ext[1] / 2, 0.0]), np.array([ext[0] / 2, ext[1] / 2, s])
        tex, tkind, colour = draw_surface(kind, name, seed, object_id, name,
                                          texture_size if name == "floor" else texture_size // 2)
        surfaces[name] = (tkind, colour)
        part = planar_box(name, lo, hi, tex, lo, hi, roughness=0.7 if name == "floor" else 0.9)
        pieces.append(piece(name, part, make_pose(np.eye(3), [0, 0, z]), "none", ext))
    for name in WALL_NAMES:
        wall = walls[name]
        extra = t if name in ("wall_south", "wall_north") else 0.0
        tex, tkind, colour = draw_surface(kind, "wall", seed, object_id, name, texture_size)
        surfaces[name] = (tkind, colour)
        part = box_with_holes(name, wall.length, t, h, [], tex, x_extra=extra, roughness=0.9)
        pose = wall.world_from_wall @ make_pose(np.eye(3), [0.0, -t / 2, 0.0])
        pieces.append(piece(name, part, pose, "floor", (wall.length + 2 * extra, t, h)))
    shell = RoomShell((x, y, h), pieces, walls, [])
    return Setting(kind, kind.style((x, y, h)), shell, surfaces)
