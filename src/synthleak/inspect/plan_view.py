"""Top-down plan of a stage: walls, object footprints with ids and front arrows, optionally a camera path.

Any stage :func:`synthleak.core.usd_read.read_render_scene` reads works (foreign stages included): footprints
are the convex hulls of each instance's world-space vertices seen from above (metres, +z up). Shell pieces
are drawn grey (a thin horizontal piece low in the room is the floor, one high up the ceiling, left out);
objects in their palette colour (:func:`synthleak.inspect.contact_sheet.id_colour`) with their id and an
arrow along their canonical front (+y); distractors (look-alikes that are never attacker objects) dashed,
clutter props lighter with their id only. With ``dataset_sequence`` the camera centres of that sequence are
drawn as a path with viewing directions (attacker sequences are mapped from the target's frame to the
world). Rendering is matplotlib Agg with fixed size and no timestamp metadata (deterministic bytes).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from synthleak.atomic_io import atomic_write_bytes
from synthleak.core.dataset import DatasetError, load_sequence
from synthleak.core.types import RenderScene
from synthleak.geometry.poses import invert

FIG_INCHES = 7.0
DPI = 100


def _hull(points: np.ndarray) -> np.ndarray:
    """Convex hull (K, 2) of 2D points, counter-clockwise (monotone chain; tolerant of degenerate sets)."""
    pts = np.unique(np.round(np.asarray(points, dtype=np.float64), 9), axis=0)
    if len(pts) < 3:
        return pts

    def half(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for p in seq:
            while len(out) >= 2 and np.cross(out[-1] - out[-2], p - out[-2]) <= 0:
                out.pop()
            out.append(p)
        return out

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])


def footprints(scene: RenderScene) -> dict[int, tuple[np.ndarray, float, float]]:
    """``{instance_id: (hull (K, 2) in world x/y, z_min, z_max)}``."""
    grouped: dict[int, list[np.ndarray]] = {}
    for mesh in scene.meshes:
        grouped.setdefault(int(mesh.instance_id), []).append(np.asarray(mesh.vertices, dtype=np.float64))
    out = {}
    for iid, verts in grouped.items():
        v = np.concatenate(verts)
        out[iid] = (_hull(v[:, :2]), float(v[:, 2].min()), float(v[:, 2].max()))
    return out


def camera_path(scene: RenderScene, sequence_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) camera centres and (N, 3) viewing directions of a sequence, in the stage's world frame."""
    seq = load_sequence(Path(sequence_dir))
    world_from_frame = np.eye(4)
    if seq.frame == "object":
        target = seq.target_instance_id
        if target is None or target not in scene.instances:
            raise DatasetError(
                f"{seq.root / 'objects.json'}: attacker sequence target {target} is not an instance of {scene.source}"
            )
        world_from_frame = np.asarray(scene.instances[target].world_from_object, dtype=np.float64)
    centres, views = [], []
    for f in seq.frames:
        world_from_cam = world_from_frame @ invert(seq.pose(f))
        centres.append(world_from_cam[:3, 3])
        views.append(world_from_cam[:3, 2])
    return np.array(centres).reshape(-1, 3), np.array(views).reshape(-1, 3)


def plan_view(stage_path: Path, out: Path, dataset_sequence: Path | None = None) -> Path:
    """Write the plan PNG of ``stage_path`` (optionally with the camera path of a sequence folder) to ``out``."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon

    from synthleak.inspect.contact_sheet import id_colour
    from synthleak.render.pipeline import load_stage
    from synthleak.scene.plan import FIRST_DISTRACTOR_ID, FIRST_PROP_ID

    stage_path = Path(stage_path)
    scene = load_stage(stage_path)
    prints = footprints(scene)
    if not prints:
        raise DatasetError(f"{stage_path}: the stage has no meshes to draw")
    top = max(z1 for _, _, z1 in prints.values())
    fig = Figure(figsize=(FIG_INCHES, FIG_INCHES), dpi=DPI)
    ax = fig.add_subplot(1, 1, 1)
    shell = [i for i in sorted(prints) if scene.instances.get(i) is not None and scene.instances[i].role == "shell"]
    objects = [i for i in sorted(prints) if i not in shell]
    for iid in shell:
        hull, z0, z1 = prints[iid]
        name = scene.instances[iid].name.lower()
        span = float(np.ptp(hull, axis=0).min()) if len(hull) else 0.0
        flat = "floor" in name or "ceiling" in name or (z1 - z0) < 0.2 * span
        if flat and z0 > 0.5 * top:  # ceiling: would hide everything
            continue
        face = (0.93, 0.93, 0.93) if flat else (0.35, 0.35, 0.35)
        ax.add_patch(
            Polygon(hull, closed=True, facecolor=face, edgecolor=(0.2, 0.2, 0.2), lw=0.8, zorder=1 if flat else 3)
        )
    for iid in objects:
        hull, _, _ = prints[iid]
        info = scene.instances.get(iid)
        prop = info is not None and info.role == "prop"
        colour = tuple(c / 255 for c in id_colour(iid))
        ax.add_patch(Polygon(hull, closed=True, facecolor=(*colour, 0.3 if prop else 0.55), edgecolor=colour,
                             lw=0.6 if prop else 1.2, zorder=4, ls="--" if FIRST_DISTRACTOR_ID <= iid < FIRST_PROP_ID
                             else "-"))
        centre = hull.mean(axis=0)
        if prop:  # clutter: the id only, small, so the furniture labels stay readable
            ax.text(*centre, str(iid), fontsize=4, ha="center", va="center", zorder=6, color=(0.3, 0.3, 0.3))
            continue
        label = f"{iid}" + (f" {info.model_id}" if info is not None and info.model_id else "")
        ax.text(*centre, label, fontsize=7, ha="center", va="center", zorder=6)
        if info is not None:
            pose = np.asarray(info.world_from_object, dtype=np.float64)
            front = pose[:2, 1]
            if np.linalg.norm(front) > 1e-6:
                size = 0.25 * float(np.ptp(hull, axis=0).max() if len(hull) else 0.2) + 0.05
                d = front / np.linalg.norm(front) * size
                ax.annotate(
                    "",
                    xy=pose[:2, 3] + d,
                    xytext=pose[:2, 3],
                    zorder=5,
                    arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.2},
                )
    if dataset_sequence is not None:
        centres, views = camera_path(scene, Path(dataset_sequence))
        ax.plot(centres[:, 0], centres[:, 1], "-", color="black", lw=0.8, zorder=7)
        ax.plot(centres[:, 0], centres[:, 1], "o", color="black", ms=2, zorder=7)
        step = max(1, len(centres) // 40)
        v = views[::step, :2]
        norms = np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        ax.quiver(
            centres[::step, 0], centres[::step, 1], *(v / norms).T, color="tab:red", scale=25, width=0.004, zorder=8
        )
        ax.plot(*centres[0, :2], "s", color="tab:green", ms=5, zorder=9)
    pts = np.concatenate([h for h, _, _ in prints.values() if len(h)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = 0.05 * float(max(hi - lo)) + 0.1
    ax.set_xlim(lo[0] - pad, hi[0] + pad)
    ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"{stage_path.name}" + (f" + {Path(dataset_sequence).name}" if dataset_sequence else ""), fontsize=9)
    ax.grid(True, lw=0.3, alpha=0.5)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", metadata={"Software": None})
    out = Path(out)
    atomic_write_bytes(out, buf.getvalue())
    return out
