"""Camera paths that see the furniture: a walk-through visiting every piece, and genuine close-ups.

A mapping crew (or a user walking around) looks at things, not at bare walls. :func:`furniture_walkthrough`
visits the room's furniture in order around the room and, for each piece, takes a short arc of views from its
open side (0.6-2.6 m from it, nearer for small pieces; eye height 1.3-1.8 m, looking at it).
:func:`closeup_views` are phone photos of one object or a small group 0.5-1.5 m away. Every candidate
viewpoint must stand in free floor space (inside the walls, clear of the footprints of floor furniture) and is
checked with a coarse exact ray cast (:class:`ViewProbe`): the view must show the target and as much furniture
as the candidates allow. All choices come from the ``rng`` passed in, so the poses are deterministic.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from synthleak.core.types import Camera, InstanceInfo, RenderScene
from synthleak.geometry.poses import look_at
from synthleak.render.raycast import RaycastGT
from synthleak.render.trajectories import EYE_HEIGHT, _clearance, _roll, room_bounds

FLAT_HEIGHT = 0.05
"""Instances lower than this (rugs) can be walked over."""
PROBE_SIZE = (64, 48)
"""Resolution of the coarse ray cast that scores candidate views."""


class ViewProbe:
    """Coarse exact ray casts of candidate views: the share of pixels on non-shell instances and on a target."""

    def __init__(self, scene: RenderScene, hfov_deg: float, aspect: float) -> None:
        self.tracer = RaycastGT(scene.meshes)
        self.hfov_deg, self.aspect = hfov_deg, aspect
        width = PROBE_SIZE[0]
        self.camera = Camera.from_hfov(width, max(8, round(width * aspect)), hfov_deg)
        self.shell = np.array(sorted(i for i, info in scene.instances.items() if info.role == "shell"), np.int64)

    def shares(self, cam_from_world: np.ndarray, target_ids: Sequence[int]) -> tuple[float, float]:
        """(share of pixels on any non-shell instance, share on ``target_ids``)."""
        _, instance = self.tracer.render(self.camera, cam_from_world)
        furniture = (instance > 0) & ~np.isin(instance, self.shell)
        return float(furniture.mean()), float(np.isin(instance, np.asarray(target_ids)).mean())


def _floor_footprints(scene: RenderScene) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """(xy centre, xy half-sizes, yaw) of the instances a person must walk around."""
    out = []
    for info in scene.instances.values():
        ext = np.asarray(info.extents, dtype=np.float64)
        if info.role == "shell" or info.support in ("wall", "ceiling") or ext[2] < FLAT_HEIGHT:
            continue
        pose = np.asarray(info.world_from_object, dtype=np.float64)
        out.append((pose[:2, 3].copy(), 0.5 * ext[:2], float(np.arctan2(pose[1, 0], pose[0, 0]))))
    return out


def _targets(scene: RenderScene) -> list[InstanceInfo]:
    """Furniture to look at (role ``object``), largest first."""
    infos = [i for i in scene.instances.values() if i.role == "object"]
    return sorted(infos, key=lambda i: (-float(np.prod(np.asarray(i.extents)[:2])), i.instance_id))


def _centre(info: InstanceInfo) -> np.ndarray:
    pose = np.asarray(info.world_from_object, dtype=np.float64)
    return pose[:3, :3] @ np.array([0.0, 0.0, 0.5 * float(np.asarray(info.extents)[2])]) + pose[:3, 3]


def _front(info: InstanceInfo, room_centre: np.ndarray) -> float:
    """Bearing (radians, world xy) of the object's open side: its +y, or towards the room centre for
    rotation-symmetric objects."""
    pose = np.asarray(info.world_from_object, dtype=np.float64)
    if info.symmetry == "z":
        d = room_centre[:2] - pose[:2, 3]
        return float(np.arctan2(d[1], d[0])) if np.linalg.norm(d) > 1e-6 else 0.0
    front = pose[:3, :3] @ np.array([0.0, 1.0, 0.0])
    return float(np.arctan2(front[1], front[0]))


class _Room:
    """Free-space tests of camera positions in one room."""

    def __init__(self, scene: RenderScene, wall_margin: float, clearance: float) -> None:
        self.lo, self.hi = room_bounds(scene)
        self.footprints = _floor_footprints(scene)
        self.wall_margin, self.clearance = wall_margin, clearance

    def free(self, xy: np.ndarray) -> bool:
        inside = bool(np.all(xy >= self.lo[:2] + self.wall_margin) and np.all(xy <= self.hi[:2] - self.wall_margin))
        return inside and float(_clearance(xy[None], self.footprints)[0]) >= self.clearance

    def eye_z(self, height: float) -> float:
        return float(min(self.lo[2] + height, self.hi[2] - 0.3))


def _free_spot(room: _Room, centre: np.ndarray, bearing: float, near: float, far: float) -> np.ndarray | None:
    """The farthest free floor point at most ``far`` and at least ``near`` from ``centre`` along ``bearing``
    (10 cm steps): a person steps closer when the room is too small to stand back."""
    direction = np.array([np.cos(bearing), np.sin(bearing)])
    for d in np.arange(far, near - 1e-9, -0.1):
        xy = centre[:2] + d * direction
        if room.free(xy):
            return xy
    return None


def _view(room: _Room, probe: ViewProbe, rng: np.random.Generator, info: InstanceInfo, bearing: float,
          distance: tuple[float, float], spread_deg: float, tries: int, min_target: float
          ) -> tuple[np.ndarray, float] | None:
    """The best of ``tries`` candidate poses looking at ``info`` from around ``bearing``: (pose, score).

    The wanted distance from the piece's side makes it span about 70 % of the view, within ``distance`` (so
    small pieces are seen from nearby, large ones from across the room); where the room is too small the
    camera stands as far back as the free floor allows."""
    centre = _centre(info)
    extents = np.asarray(info.extents, dtype=np.float64)
    radius = 0.5 * float(np.linalg.norm(extents[:2]))
    fov = 2.0 * np.arctan(np.tan(np.radians(probe.hfov_deg) / 2.0) * probe.aspect)
    fill = 0.5 * float(np.linalg.norm(extents)) / np.sin(0.35 * fov) - radius
    best: tuple[np.ndarray, float] | None = None
    for _ in range(tries):
        az = bearing + np.radians(float(rng.uniform(-spread_deg, spread_deg)))
        want = radius + float(np.clip(fill * rng.uniform(0.8, 1.25), *distance))
        height = float(rng.uniform(*EYE_HEIGHT))
        xy = _free_spot(room, centre, az, min(radius + distance[0], want), want)
        if xy is None:
            continue
        eye = np.array([xy[0], xy[1], room.eye_z(height)])
        look = centre + rng.normal(0.0, 0.1, 3) * np.array([1.0, 1.0, 0.5])
        pose = _roll(look_at(eye, look), np.radians(rng.normal(0.0, 1.5)))
        furniture, target = probe.shares(pose, [info.instance_id])
        if target < min_target:
            continue
        score = furniture + target
        if best is None or score > best[1]:
            best = (pose, score)
    return best


def _apportion(total: int, weights: Sequence[float]) -> np.ndarray:
    """``total`` split proportionally to ``weights`` (largest remainders, ties to the earlier)."""
    w = np.asarray(weights, dtype=np.float64)
    exact = total * w / w.sum()
    shares = np.floor(exact).astype(int)
    rest = np.argsort(-(exact - shares), kind="stable")[: total - int(shares.sum())]
    shares[rest] += 1
    return shares


def furniture_walkthrough(
    scene: RenderScene,
    n_frames: int,
    rng: np.random.Generator,
    hfov_deg: float = 65.0,
    aspect: float = 0.75,
    *,
    distance: tuple[float, float] = (0.6, 2.6),
    wall_margin: float = 0.35,
    clearance: float = 0.25,
) -> list[np.ndarray] | None:
    """``n_frames`` ``cam_from_world`` poses visiting the furniture (None when the room has no furniture
    or no free viewpoint: use :func:`~synthleak.render.trajectories.walkthrough` then); ``distance`` bounds
    the camera's distance from a piece's side (metres).

    Pieces are visited in order of their bearing around the room centre; each piece that can be seen from
    some free spot gets a share of the frames proportional to the square root of its frontal area, as an arc
    sweeping -40..40 degrees about its open side. Each frame is the best of a few candidate viewpoints near
    its arc position (most furniture in view, the piece itself visible)."""
    if n_frames < 1:
        raise ValueError(f"furniture_walkthrough: n_frames must be >= 1, got {n_frames}")
    targets = _targets(scene)
    if not targets:
        return None
    room = _Room(scene, wall_margin, clearance)
    room_centre = 0.5 * (room.lo + room.hi)
    probe = ViewProbe(scene, hfov_deg, aspect)
    fronts = [_front(t, room_centre) for t in targets]
    seen = [k for k, t in enumerate(targets)
            if _view(room, probe, rng, t, fronts[k], distance, 180.0, 16, 0.02) is not None]
    if not seen:
        return None
    bearings = {k: float(np.arctan2(*(_centre(targets[k])[:2] - room_centre[:2])[::-1])) for k in seen}
    start = rng.uniform(-np.pi, np.pi)
    order = sorted(seen, key=lambda k: (bearings[k] - start) % (2 * np.pi))
    if rng.random() < 0.5:
        order = order[::-1]
    frontal = [np.asarray(targets[k].extents, dtype=np.float64) for k in order]
    shares = _apportion(n_frames, [float(np.sqrt(max(e[0], e[1]) * e[2])) for e in frontal])
    poses: list[np.ndarray] = []
    for k, count in zip(order, shares, strict=True):
        info = targets[k]
        for j in range(int(count)):
            sweep = np.radians(-40.0 + 80.0 * (j + 0.5) / count)
            view = _view(room, probe, rng, info, fronts[k] + sweep, distance, 20.0, 8, 0.02)
            if view is None:  # no free spot in front of it: anywhere around it
                view = _view(room, probe, rng, info, fronts[k], distance, 180.0, 32, 0.0)
            if view is not None:
                poses.append(view[0])
            elif poses:  # (rare) no free spot left: hold the previous view
                poses.append(poses[-1])
    if len(poses) < n_frames:  # the first piece found no view at all for its first frames
        return None
    return poses


def closeup_views(
    scene: RenderScene,
    count: int,
    rng: np.random.Generator,
    hfov_deg: float = 65.0,
    aspect: float = 0.75,
    *,
    distance: tuple[float, float] = (0.5, 1.5),
    wall_margin: float = 0.25,
    clearance: float = 0.15,
) -> list[np.ndarray]:
    """``count`` phone close-ups: each 0.5-1.5 m from the side of one object (furniture, or a prop: with what
    stands around it, a small group), eye height 0.9-1.7 m, the object on at least 5 % of the view. Fewer
    when the room has no free spot near its objects."""
    room = _Room(scene, wall_margin, clearance)
    room_centre = 0.5 * (room.lo + room.hi)
    probe = ViewProbe(scene, hfov_deg, aspect)
    targets = [i for i in scene.instances.values() if i.role in ("object", "prop")
               and float(np.asarray(i.extents)[2]) >= FLAT_HEIGHT]
    targets.sort(key=lambda i: i.instance_id)
    poses: list[np.ndarray] = []
    for _ in range(20 * count):
        if len(poses) == count or not targets:
            break
        info = targets[int(rng.integers(len(targets)))]
        centre = _centre(info)
        front = _front(info, room_centre)
        half = 0.5 * float(min(np.asarray(info.extents)[:2]))
        best: tuple[np.ndarray, float] | None = None
        for _ in range(12):
            az = front + np.radians(float(rng.uniform(-60.0, 60.0)))
            xy = centre[:2] + (half + float(rng.uniform(*distance))) * np.array([np.cos(az), np.sin(az)])
            if not room.free(xy):
                continue
            eye = np.array([xy[0], xy[1], room.eye_z(float(rng.uniform(0.9, 1.7)))])
            pose = _roll(look_at(eye, centre + rng.normal(0.0, 0.05, 3)), np.radians(rng.normal(0.0, 4.0)))
            _, share = probe.shares(pose, [info.instance_id])
            if best is None or share > best[1]:
                best = (pose, share)
        if best is not None and best[1] >= 0.05:
            poses.append(best[0])
        elif best is None:
            targets.remove(info)  # nowhere to stand in front of it
    return poses
