"""Lens distortion and resize geometry of the capture model (:mod:`synthleak.render.capture`).

The distortion is OpenCV's radial-tangential (Brown-Conrady) model, COLMAP's ``OPENCV`` camera (``FULL_OPENCV``
with k3): a camera-frame point (x, y, 1) goes to ``x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y +
p2 (r^2 + 2 x^2)`` (and y alike), r^2 = x^2 + y^2, then ``u = fx x_d + cx`` (Brown 1966, "Decentering
distortion of lenses"; OpenCV ``projectPoints``). A pinhole render is turned into the distorted photo by
resampling: each output pixel centre is undistorted (Newton on the forward model) and projected into the render.

Choice (documented in docs/renderers.md): the render is not widened. The output keeps the render's size and
principal point and takes the focal length ``s * f`` with the smallest ``s`` (rounded up to 1e-6) for which every
output pixel samples inside the render (bilinear between render pixel centres), so the whole frame is valid:
barrel distortion (k1 < 0) zooms in slightly (s > 1), pincushion zooms out (s < 1).

Depth and instance ids of a geometric capture are ray cast again for the output camera (one ray per output pixel
centre, :func:`raycast_camera`), so they are the exact ground truth of the distorted and resized photo, not values
borrowed from a neighbouring render pixel.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from synthleak.core.dataset import OpenCVCamera, camera_dist_coeffs
from synthleak.core.types import Camera
from synthleak.errors import ConfigError

NEWTON_STEPS = 12
UNDISTORT_TOL = 1e-9
"""Largest residual (normalised units) of :func:`undistort_normalized` before it is an error."""


def radial_fold_radius(k1: float, k2: float, k3: float) -> float:
    """Smallest undistorted radius r > 0 where ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` stops increasing (its
    derivative ``1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6`` reaches 0); ``inf`` when it never does."""
    roots = np.roots([7.0 * k3, 5.0 * k2, 3.0 * k1, 1.0]) if (k1, k2, k3) != (0.0, 0.0, 0.0) else []
    s = [float(r.real) for r in np.atleast_1d(roots) if abs(r.imag) < 1e-12 and r.real > 0]
    return math.sqrt(min(s)) if s else math.inf


def corner_radius(camera: Camera) -> float:
    """The largest normalised (pinhole) radius of ``camera``'s image: at its farthest corner."""
    xs = (np.array([0.0, camera.width]) - camera.cx) / camera.fx
    ys = (np.array([0.0, camera.height]) - camera.cy) / camera.fy
    return float(np.sqrt((xs[:, None] ** 2 + ys[None, :] ** 2).max()))


def check_no_fold(k1: float, k2: float, k3: float, camera: Camera, where: str) -> None:
    """ConfigError naming ``where`` (e.g. ``capture profile phone: distortion``) when the radial map folds
    (stops increasing) within the image's corner radius: such a lens would show the same ray twice."""
    fold, corner = radial_fold_radius(k1, k2, k3), corner_radius(camera)
    if fold <= corner * 1.05:
        raise ConfigError(f"{where}.k1/k2/k3 = {k1}, {k2}, {k3}: the radial distortion folds the image at normalised "
                          f"radius {fold:.4f}, inside the frame's corner radius {corner:.4f} (x1.05 margin)")


def distort_normalized(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's forward model on normalised coordinates (``dist``: ``[k1, k2, p1, p2, k3]``)."""
    k1, k2, p1, p2, k3 = (float(c) for c in dist)
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return (x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y)


def undistort_normalized(xd: np.ndarray, yd: np.ndarray, dist: np.ndarray, strict: bool = True
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`distort_normalized` by Newton's method (elementwise float64: the same bits on any CPU);
    a ValueError when it does not converge (``strict``), else NaN where it does not."""
    k1, k2, p1, p2, k3 = (float(c) for c in dist)
    shape = np.shape(xd)
    xd, yd = np.asarray(xd, dtype=np.float64).ravel(), np.asarray(yd, dtype=np.float64).ravel()
    x, y = xd.copy(), yd.copy()
    active: slice | np.ndarray = slice(None)
    for _ in range(NEWTON_STEPS):
        # each element steps on its own values only, so an element whose step moved nothing sits at its fixed point
        # (every further step gives the same bits): it leaves the active set, and the result is bit for bit that
        # of NEWTON_STEPS steps on every element
        xa, ya = x[active], y[active]
        fx, fy = distort_normalized(xa, ya, dist)
        ex, ey = fx - xd[active], fy - yd[active]
        r2 = xa * xa + ya * ya
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3))  # d radial / d (r^2) * 2
        jxx = radial + xa * xa * dradial + 2.0 * p1 * ya + 6.0 * p2 * xa
        jxy = xa * ya * dradial + 2.0 * p1 * xa + 2.0 * p2 * ya
        jyx = xa * ya * dradial + 2.0 * p1 * xa + 2.0 * p2 * ya
        jyy = radial + ya * ya * dradial + 6.0 * p1 * ya + 2.0 * p2 * xa
        det = jxx * jyy - jxy * jyx
        with np.errstate(all="ignore"):
            xn = xa - (jyy * ex - jxy * ey) / det
            yn = ya - (jxx * ey - jyx * ex) / det
        moving = ~(((xn == xa) | (np.isnan(xn) & np.isnan(xa))) & ((yn == ya) | (np.isnan(yn) & np.isnan(ya))))
        if isinstance(active, slice):
            x, y = xn, yn
            if moving.mean() < 0.5:  # most elements settled: step on the others only from now on
                active = np.nonzero(moving)[0]
        else:
            x[active], y[active] = xn, yn
            active = active[moving]
            if active.size == 0:
                break
    x, y, xd, yd = x.reshape(shape), y.reshape(shape), xd.reshape(shape), yd.reshape(shape)
    with np.errstate(all="ignore"):
        fx, fy = distort_normalized(x, y, dist)
    if not strict:
        bad = ~((np.abs(fx - xd) < UNDISTORT_TOL) & (np.abs(fy - yd) < UNDISTORT_TOL))
        return np.where(bad, np.nan, x), np.where(bad, np.nan, y)
    residual = float(np.max(np.abs(np.concatenate([(fx - xd).ravel(), (fy - yd).ravel()])), initial=0.0))
    if not residual < UNDISTORT_TOL:
        raise ValueError(f"lens distortion: undistortion did not converge (residual {residual:.2e})")
    return x, y


def normalized_rays(camera: Camera, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised (x, y) of pixel coordinates (u, v) (pixel centres: u + 0.5); NaN where a
    distorted camera's lens has no ray: far outside the frame, where the undistortion finds no solution or only
    one beyond the radial fold radius (past it the model's radius turns back and may rise again, so a pixel there
    would see a second, wider ring of the world: not a lens, an artefact of the polynomial)."""
    x = (np.asarray(u, dtype=np.float64) - camera.cx) / camera.fx
    y = (np.asarray(v, dtype=np.float64) - camera.cy) / camera.fy
    dist = camera_dist_coeffs(camera)
    if dist is None:
        return x, y
    x, y = undistort_normalized(x, y, dist, strict=False)
    fold = radial_fold_radius(float(dist[0]), float(dist[1]), float(dist[4]))
    if math.isfinite(fold):
        with np.errstate(invalid="ignore"):
            beyond = x * x + y * y >= fold * fold
        x, y = np.where(beyond, np.nan, x), np.where(beyond, np.nan, y)
    return x, y


def project_camera_points(camera: Camera, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Pixel coordinates of camera-frame points (z > 0) through ``camera``'s lens; ``None`` when a distorted
    camera sees one beyond its model's monotonic range (no meaningful projection: the caller must assume
    anywhere)."""
    dist = camera_dist_coeffs(camera)
    if dist is None:  # (this operation order: the bits of the pinhole projection the BOP extras always made)
        return camera.fx * pts[:, 0] / pts[:, 2] + camera.cx, camera.fy * pts[:, 1] / pts[:, 2] + camera.cy
    x, y = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    k1, k2, _, _, k3 = (float(c) for c in dist)
    if np.any(x * x + y * y >= (0.95 * radial_fold_radius(k1, k2, k3)) ** 2):
        return None
    x, y = distort_normalized(x, y, dist)
    return camera.fx * x + camera.cx, camera.fy * y + camera.cy


def lens_image_bounds(camera: Camera, pts: np.ndarray, samples: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Pixel points whose box bounds every pixel whose ray passes through the normalised box of camera-frame
    points ``pts`` (z > 0), for a distorted camera that sees some of them beyond its range (where
    :func:`project_camera_points` has no answer). No pixel's ray lies beyond the radial fold radius, and within
    it the lens maps a region's boundary onto its image's boundary, so the box's edges, pulled radially onto the
    fold circle where they cross it, and the circle's arc inside the box are sampled and distorted; a caller
    pads the box for the bending between samples, as it does for projected vertices."""
    dist = camera_dist_coeffs(camera)
    k1, k2, _, _, k3 = (float(c) for c in dist)
    fold = radial_fold_radius(k1, k2, k3)
    x, y = pts[:, 0] / pts[:, 2], pts[:, 1] / pts[:, 2]
    lim = fold if math.isfinite(fold) else float(np.max(np.abs(np.concatenate([x, y]))))
    x0, x1 = float(np.clip(x.min(), -lim, lim)), float(np.clip(x.max(), -lim, lim))
    y0, y1 = float(np.clip(y.min(), -lim, lim)), float(np.clip(y.max(), -lim, lim))
    t = np.linspace(0.0, 1.0, samples)
    bx = np.concatenate([x0 + t * (x1 - x0), x0 + t * (x1 - x0), np.full(samples, x0), np.full(samples, x1)])
    by = np.concatenate([np.full(samples, y0), np.full(samples, y1), y0 + t * (y1 - y0), y0 + t * (y1 - y0)])
    if math.isfinite(fold):
        r = np.hypot(bx, by)
        scale = np.where(r > fold, fold / np.maximum(r, 1e-300), 1.0)
        a = np.linspace(0.0, 2.0 * np.pi, 4 * samples, endpoint=False)
        ax, ay = fold * np.cos(a), fold * np.sin(a)
        arc = (ax >= x0) & (ax <= x1) & (ay >= y0) & (ay <= y1)
        bx, by = np.concatenate([bx * scale, ax[arc]]), np.concatenate([by * scale, ay[arc]])
    xd, yd = distort_normalized(bx, by, dist)
    return camera.fx * xd + camera.cx, camera.fy * yd + camera.cy


def _pixel_grid(camera: Camera, border_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u + 0.5, v + 0.5): the whole image, row-major, or its border pixels."""
    w, h = camera.width, camera.height
    if not border_only:
        u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
        return u, v
    us, vs = np.arange(w) + 0.5, np.arange(h) + 0.5
    u = np.concatenate([us, us, np.full(h, 0.5), np.full(h, w - 0.5)])
    v = np.concatenate([np.full(w, 0.5), np.full(w, h - 0.5), vs, vs])
    return u, v


@lru_cache(maxsize=4)
def camera_rays(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Undistorted normalised (x, y) of every pixel centre of ``camera`` (H, W), read-only: its rays are
    (x, y, 1). The last few cameras' grids are kept, so a photo's resampling and its ground truth's ray cast
    undistort the frame once."""
    u, v = _pixel_grid(camera)
    x, y = (u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy
    dist = camera_dist_coeffs(camera)
    if dist is not None:
        x, y = undistort_normalized(x, y, dist)
    x.flags.writeable = y.flags.writeable = False
    return x, y


def sample_positions(output: Camera, render: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Where each output pixel centre lies in the pinhole ``render``, as ``cv2.remap`` maps (render pixel
    indices: centre of pixel (i, j) at (j, i)), float32 (H, W)."""
    x, y = camera_rays(output)
    return ((render.fx * x + render.cx - 0.5).astype(np.float32), (render.fy * y + render.cy - 0.5).astype(np.float32))


def distorted_camera(render: Camera, dist: np.ndarray, where: str) -> OpenCVCamera:
    """The output camera of a distorted capture of the pinhole ``render`` (see the module docstring): same size
    and principal point, focal length ``s * f`` with the smallest ``s`` keeping every sample inside the render.
    Computed once per (render camera, coefficients) in a process (:func:`focal_scale`)."""
    k1, k2, p1, p2, k3 = (float(c) for c in dist)
    check_no_fold(k1, k2, k3, render, where)
    s = focal_scale(render, (k1, k2, p1, p2, k3))
    if s is None:
        raise ConfigError(f"{where}: no focal length keeps the distorted frame inside the render")
    return OpenCVCamera(render.width, render.height, render.fx * s, render.fy * s, render.cx, render.cy,
                        k1, k2, p1, p2, k3)


BISECTION_STEPS = 60
"""Halvings of the focal scale's bracket [0.5, 4]: the scale is the bracket's top rounded up to 1e-6."""


@lru_cache(maxsize=4096)
def focal_scale(render: Camera, coeffs: tuple[float, float, float, float, float]) -> float | None:
    """The smallest focal scale (rounded up to 1e-6) for which every border pixel of a ``coeffs`` capture of
    ``render`` samples inside the render, or None when no scale up to 4 does.

    It is the top of :data:`BISECTION_STEPS` halvings of [0.5, 4], rounded up to 1e-6; the halving stops early
    once every value the bracket's top can still take rounds up to the same 1e-6 step (rounding is monotonic),
    so the scale is the same bits as after every halving, for a third of the undistortions."""
    dist = np.array(coeffs, dtype=np.float64)
    u, v = _pixel_grid(render, border_only=True)
    lo_u, hi_u, lo_v, hi_v = 0.5, render.width - 0.5, 0.5, render.height - 0.5

    def inside(s: float) -> bool:
        try:
            x, y = undistort_normalized((u - render.cx) / (s * render.fx), (v - render.cy) / (s * render.fy), dist)
        except ValueError:  # beyond the lens's range: not inside
            return False
        ur, vr = render.fx * x + render.cx, render.fy * y + render.cy
        return bool(np.all((ur >= lo_u) & (ur <= hi_u) & (vr >= lo_v) & (vr <= hi_v)))

    def rounded(s: float) -> float:
        return math.ceil(s * 1e6) / 1e6

    lo, hi = 0.5, 4.0
    if not inside(hi):
        return None
    for _ in range(BISECTION_STEPS):
        # every later top lies in (lo, hi]: the smallest is above lo, so at least its successor
        if rounded(math.nextafter(lo, math.inf)) == rounded(hi):
            break
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if inside(mid) else (mid, hi)
    return rounded(hi)


def raycast_camera(gt, camera: Camera, cam_from_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact z-depth (float32 (H, W), +inf: no hit) and instance ids (uint16) of ``camera`` (distortion included)
    by ray casting ``gt`` (a :class:`synthleak.render.raycast.RaycastGT`) through every pixel centre; a pinhole
    camera gives exactly ``gt.render``."""
    if camera_dist_coeffs(camera) is None:
        return gt.render(camera, cam_from_world)
    x, y = camera_rays(camera)
    dirs_cam = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)
    pose = np.asarray(cam_from_world, dtype=np.float64)
    rot = pose[:3, :3]
    origin = -rot.T @ pose[:3, 3]
    dirs = dirs_cam @ rot
    origins = np.broadcast_to(origin, dirs.shape)
    tri = gt._intersector.intersects_first(origins, dirs)  # RaycastGT's BVH (one ray per pixel centre)
    hit = tri >= 0
    depth = np.full(len(dirs), np.inf)
    instance = np.zeros(len(dirs), dtype=np.uint16)
    idx = tri[hit]
    normal = gt._normal[idx]
    with np.errstate(divide="ignore", invalid="ignore"):  # z of each direction is 1: t is the z-depth
        t = np.einsum("ij,ij->i", normal, gt._v0[idx] - origin) / np.einsum("ij,ij->i", normal, dirs[hit])
    bad = ~np.isfinite(t) | (t <= 0)
    if bad.any():  # degenerate triangle or grazing ray: embree's own hit point
        locs, ray_idx, _ = gt._intersector.intersects_location(origins[hit][bad], dirs[hit][bad], multiple_hits=False)
        fallback = np.full(int(bad.sum()), np.inf)
        fallback[ray_idx] = (locs - origin) @ rot[2]
        t[bad] = fallback
    depth[hit] = t
    instance[hit] = gt.face_instance[idx]
    shape = (camera.height, camera.width)
    return depth.reshape(shape).astype(np.float32), instance.reshape(shape)
