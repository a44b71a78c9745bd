"""Camera paths as ``cam_from_world`` poses in the stage world: room walk-throughs and object orbits."""

from __future__ import annotations

import numpy as np

from synthleak.core.types import InstanceInfo, RenderScene
from synthleak.geometry.poses import look_at, make_pose

EYE_HEIGHT = (1.3, 1.8)
WALKTHROUGHS = ("loop", "furniture")
"""``render.walkthrough`` values: this module's loop, or :mod:`synthleak.render.furniture_views`' tour."""
OPEN_HEIGHT = 2.5
"""Height of the space above the floor of a stage without walls or ceiling (walk-throughs stay 0.3 m below)."""


def _roll(cam_from_world: np.ndarray, roll_rad: float) -> np.ndarray:
    c, s = np.cos(roll_rad), np.sin(roll_rad)
    return make_pose(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.zeros(3)) @ cam_from_world


def room_bounds(scene: RenderScene) -> np.ndarray:
    """(2, 3) world bounds of the room's interior: x, y from its floor (the shell piece named ``floor``, else
    the lowest shell piece), z from the floor's top to the lowest shell piece above it (the ceiling).
    Pieces outside the room (a backdrop behind a window) do not count. Without a shell (stages of other tools):
    the bounds of all meshes, at least :data:`OPEN_HEIGHT` high (an open stage: a floor and furniture)."""
    shell_ids = {i for i, info in scene.instances.items() if info.role == "shell"}
    shell = [m for m in scene.meshes if m.instance_id in shell_ids]
    if not shell:
        if not scene.meshes:
            raise ValueError(f"{scene.source or 'scene'}: no meshes to bound the room")
        verts = np.concatenate([np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in scene.meshes])
        lo, hi = verts.min(axis=0), verts.max(axis=0)
        hi[2] = max(hi[2], lo[2] + OPEN_HEIGHT)
        return np.stack([lo, hi])
    verts = {id(m): np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in shell}
    names = {m.instance_id: scene.instances[m.instance_id].name.lower() for m in shell}
    floors = [m for m in shell if "floor" in names[m.instance_id]]
    floor = floors[0] if floors else min(shell, key=lambda m: verts[id(m)][:, 2].max())
    fv = verts[id(floor)]
    top = fv[:, 2].max()
    above = [verts[id(m)][:, 2].min() for m in shell if verts[id(m)][:, 2].min() > top + 1.0]
    ceiling = min(above) if above else top + 2.5
    return np.array([[*fv[:, :2].min(axis=0), top], [*fv[:, :2].max(axis=0), ceiling]])


def _footprints(scene: RenderScene) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(xy centre, xy half-sizes along the object's axes, yaw) of every object instance."""
    out = []
    for info in scene.instances.values():
        if info.role != "object":
            continue
        pose = np.asarray(info.world_from_object, dtype=np.float64)
        ext = np.asarray(info.extents, dtype=np.float64)
        out.append((pose[:2, 3].copy(), 0.5 * ext[:2], float(np.arctan2(pose[1, 0], pose[0, 0]))))
    return out


def _clearance(points: np.ndarray, footprints: list[tuple[np.ndarray, np.ndarray, float]]) -> np.ndarray:
    """Distance of each (N, 2) point to the nearest object footprint (0 inside one); +inf without objects."""
    best = np.full(len(points), np.inf)
    for centre, half, yaw in footprints:
        c, s = np.cos(yaw), np.sin(yaw)
        local = (points - centre) @ np.array([[c, -s], [s, c]])
        outside = np.maximum(np.abs(local) - half, 0.0)
        best = np.minimum(best, np.linalg.norm(outside, axis=1))
    return best


def _free_loop(
    centre: np.ndarray,
    semi: np.ndarray,
    angles: np.ndarray,
    wobble: np.ndarray,
    footprints: list[tuple[np.ndarray, np.ndarray, float]],
    clearance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) points and the centre of the largest ellipse-like loop inside the wall margin that keeps
    ``clearance`` from every object footprint (centre searched over a grid); the clearest one otherwise."""
    unit = np.stack([np.cos(angles), np.sin(angles)], axis=1) * wobble[:, None]
    probe = np.linspace(0.0, 2.0 * np.pi, 72, endpoint=False)
    probe_unit = np.stack([np.cos(probe), np.sin(probe)], axis=1) * 1.08
    best, best_key = None, None
    for scale in np.linspace(1.0, 0.2, 9):
        size = scale * semi
        room = np.maximum(semi - size, 0.0)
        for dx in np.linspace(-1.0, 1.0, 7):
            for dy in np.linspace(-1.0, 1.0, 7):
                c = centre + np.array([dx, dy]) * room
                free = float(_clearance(c + probe_unit * size, footprints).min())
                key = (free >= clearance, scale if free >= clearance else free, -abs(dx) - abs(dy))
                if best_key is None or key > best_key:
                    best, best_key = (c, size), key
        if best_key is not None and best_key[0]:
            break
    c, size = best
    return c + unit * size, c


def walkthrough(
    scene: RenderScene,
    n_frames: int,
    rng: np.random.Generator,
    room_size: tuple[float, float, float] | None = None,
    wall_margin: float = 0.7,
    object_clearance: float = 0.35,
) -> list[np.ndarray]:
    """A loop through the room at eye height (1.3-1.8 m), looking across the room at the furniture.

    The path is the largest ellipse in the free floor space (``wall_margin`` from the walls,
    ``object_clearance`` from every object's footprint); the camera looks inwards across the loop towards
    the far side of the room, 10-20 degrees down, with a slow yaw sway, so consecutive frames overlap.
    ``room_size`` (x, y, z) overrides the bounds taken from the room's shell meshes (then centred on them).
    """
    if n_frames < 1:
        raise ValueError(f"walkthrough: n_frames must be >= 1, got {n_frames}")
    lo, hi = room_bounds(scene)
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo) if room_size is None else 0.5 * np.asarray(room_size, dtype=np.float64)
    floor = lo[2] if room_size is None else centre[2] - half[2]
    ceiling = hi[2] if room_size is None else centre[2] + half[2]
    semi = np.maximum(half[:2] - wall_margin, 0.2)
    phase0 = rng.uniform(0.0, 2.0 * np.pi)
    direction = rng.choice([-1.0, 1.0])
    angles = phase0 + direction * 2.0 * np.pi * np.arange(n_frames) / n_frames
    wobble = 1.0 + 0.08 * np.sin(3.0 * angles + rng.uniform(0, 2 * np.pi))
    xy, loop_centre = _free_loop(centre[:2], semi, angles, wobble, _footprints(scene), object_clearance)
    eye_base = rng.uniform(1.45, 1.65)
    height = eye_base + 0.08 * np.sin(2.0 * angles + rng.uniform(0, 2 * np.pi)) + rng.normal(0, 0.01, n_frames)
    height = np.clip(height, *EYE_HEIGHT)
    height = np.minimum(floor + height, ceiling - 0.3)
    yaw_offset = np.radians(20.0) * np.sin(angles * 2.0 + rng.uniform(0, 2 * np.pi))
    target_z = floor + rng.uniform(0.55, 0.85) + 0.15 * np.sin(5.0 * angles) + rng.normal(0, 0.02, n_frames)
    objects = np.array([f[0] for f in _footprints(scene)]).reshape(-1, 2)
    reach = 1.2 * float(np.linalg.norm(half[:2]))  # a point across the room, towards its far side
    poses = []
    for i in range(n_frames):
        eye = np.array([xy[i, 0], xy[i, 1], height[i]])
        yaw = _view_yaw(xy[i], loop_centre, centre[:2], objects) + yaw_offset[i]
        target = np.array([xy[i, 0] + reach * np.cos(yaw), xy[i, 1] + reach * np.sin(yaw), target_z[i]])
        pose = look_at(eye, target)
        poses.append(_roll(pose, np.radians(rng.normal(0.0, 1.5))))
    return poses


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-9 else np.zeros_like(v)


def _view_yaw(eye: np.ndarray, loop_centre: np.ndarray, room_centre: np.ndarray, objects: np.ndarray) -> float:
    """Yaw looking across the room (between the loop's and the room's centre), pulled smoothly towards
    the furniture within about 40 degrees of it so that objects stay in view."""
    base = _unit(loop_centre - eye) + _unit(room_centre - eye)
    if np.linalg.norm(base) < 1e-6:
        base = (
            _unit(room_centre - loop_centre)
            if np.linalg.norm(room_centre - loop_centre) > 1e-6
            else np.array([1.0, 0.0])
        )
    yaw = float(np.arctan2(base[1], base[0]))
    if len(objects) == 0:
        return yaw
    bearings = np.arctan2(objects[:, 1] - eye[1], objects[:, 0] - eye[0])
    delta = (bearings - yaw + np.pi) % (2.0 * np.pi) - np.pi
    weights = np.exp(-((delta / np.radians(40.0)) ** 2))
    return yaw + float(np.sum(weights * delta) / (0.4 + np.sum(weights)))


def orbit_distance(extents: np.ndarray, hfov_deg: float, aspect: float, fill: float,
                   direction: np.ndarray | None = None, points: np.ndarray | None = None) -> float:
    """Distance from the box centre at which the object spans ``fill`` of the image's shorter field of view.

    Seen from ``direction`` (unit, object frame, from the object towards the camera), every one of ``points``
    (object frame, relative to the box centre; default: the bounding box's corners) stays within that angle of
    the optical axis, so a thin object seen end-on is approached closer; without a direction, the bounding
    sphere's distance (any view)."""
    hfov = np.radians(hfov_deg)
    vfov = 2.0 * np.arctan(np.tan(hfov / 2.0) * aspect)
    half_angle = 0.5 * fill * min(hfov, vfov)
    half = 0.5 * np.asarray(extents, dtype=np.float64)
    if direction is None:
        return float(np.linalg.norm(half)) / np.sin(half_angle)
    v = np.asarray(direction, dtype=np.float64) / np.linalg.norm(direction)
    if points is None:
        points = half * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    along = points @ v
    across = np.sqrt(np.maximum(np.einsum("ij,ij->i", points, points) - along**2, 0.0))
    return float(np.max(across / np.tan(half_angle) + along))


def _hull_points(scene: RenderScene, target_id: int, object_from_world: np.ndarray) -> np.ndarray | None:
    """The target's convex-hull vertices in its object frame (None without a mesh)."""
    from scipy.spatial import ConvexHull, QhullError

    verts = [np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in scene.meshes
             if m.instance_id == target_id]
    if not verts:
        return None
    pts = np.concatenate(verts) @ object_from_world[:3, :3].T + object_from_world[:3, 3]
    try:
        return pts[ConvexHull(pts).vertices]
    except QhullError:  # flat or degenerate: all points
        return pts


def orbit(
    scene: RenderScene,
    target_id: int,
    n_frames: int,
    rng: np.random.Generator,
    support: str | None = None,
    hfov_deg: float = 65.0,
    aspect: float = 0.75,
    fill: float = 1.0,
) -> list[np.ndarray]:
    """Views around one object that fill a large part of the frame (its silhouette, as seen from each view,
    spans ``fill`` of the shorter field of view, the distance then times 0.85-1.1).

    ``support`` (default: the instance's own) shapes the orbit: ``floor``/``surface``/``none`` go 360 degrees
    around at elevations 10-60 degrees; ``wall`` stays within +-70 degrees of the front (+y) at -20-45
    degrees; ``ceiling`` goes 360 degrees around seen from below (-60 to -10 degrees).
    """
    if target_id not in scene.instances:
        raise ValueError(f"{scene.source or 'scene'}: target_instance_id {target_id} is not an instance")
    if n_frames < 1:
        raise ValueError(f"orbit: n_frames must be >= 1, got {n_frames}")
    info: InstanceInfo = scene.instances[target_id]
    support = support or getattr(info, "support", "floor")
    world_from_object = np.asarray(info.world_from_object, dtype=np.float64)
    extents = np.asarray(info.extents, dtype=np.float64)
    centre_obj = np.array([0.0, 0.0, 0.5 * extents[2]])
    t = np.arange(n_frames) / n_frames
    phase = rng.uniform(0.0, 2.0 * np.pi)
    if support == "wall":
        az = np.radians(70.0) * np.sin(2.0 * np.pi * t + phase)
        el_lo, el_hi = -20.0, 45.0
    elif support == "ceiling":
        az = phase + 2.0 * np.pi * t
        el_lo, el_hi = -60.0, -10.0
    elif support in ("floor", "surface", "none"):
        az = phase + 2.0 * np.pi * t
        el_lo, el_hi = 10.0, 60.0
    else:
        raise ValueError(f"orbit: unknown support {support!r} for instance {target_id}")
    az = az + np.radians(rng.normal(0.0, 2.0, n_frames))
    mid, amp = 0.5 * (el_lo + el_hi), 0.5 * (el_hi - el_lo)
    el = np.radians(
        np.clip(
            mid + amp * np.sin(2.0 * np.pi * 2.0 * t + rng.uniform(0, 2 * np.pi)) + rng.normal(0.0, 3.0, n_frames),
            el_lo,
            el_hi,
        )
    )
    scale = rng.uniform(0.85, 1.1, n_frames)
    radius = 0.5 * float(np.linalg.norm(extents))
    hull = _hull_points(scene, target_id, np.linalg.inv(world_from_object))
    points = None if hull is None else hull - centre_obj
    poses = []
    for i in range(n_frames):
        offset = np.array([np.sin(az[i]) * np.cos(el[i]), np.cos(az[i]) * np.cos(el[i]), np.sin(el[i])])
        distance = orbit_distance(extents, hfov_deg, aspect, fill, offset, points)
        eye_obj = centre_obj + scale[i] * distance * offset
        target_obj = centre_obj + rng.normal(0.0, 0.05 * radius, 3)
        eye = world_from_object[:3, :3] @ eye_obj + world_from_object[:3, 3]
        target = world_from_object[:3, :3] @ target_obj + world_from_object[:3, 3]
        poses.append(_roll(look_at(eye, target), np.radians(rng.normal(0.0, 3.0))))
    return poses
