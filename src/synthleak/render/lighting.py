"""Lights a stage does not state as lights: stand-ins for emissive meshes, and the default light of a stage
that has no light at all (docs/renderers.md, "Lights").

* :func:`emissive_lights`: a backend whose lights cannot be meshes (pyrender) lights the scene from each
  emissive mesh through a stand-in of the same power: a flat emitter (its area-weighted normals agree) becomes
  a ``rect`` light of its projected area facing along its normal, 1 cm in front of its centroid; any other
  shape a ``sphere`` light at its centroid radiating the mesh's power evenly (intensity = radiance x area / 4).
  mitsuba samples emissive meshes as area emitters and Cycles as emissive surfaces, so they need none.
* :func:`with_default_light`: a stage with no UsdLux light, no dome light and no emissive mesh would render
  black; it gets a default light, and a warning. A walk-through stage gets one ``sphere`` light above the
  centre of the stage's bounds, at 80 % of their height (in a room: below the ceiling) or at a quarter of
  their horizontal diagonal when that is higher (an open, flat stage), with the intensity that gives an
  irradiance of 2 W/m^2 at the floor centre straight below it (a grey 0.7 floor renders at about sRGB 178).
  An attacker stage (one with a target instance, seen from all around) gets an ambient environment of radiance
  0.6 (``RenderScene.ambient``: mitsuba's fill lights, pyrender's ambient term, Blender's world colour), which
  lights every side of the object.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from synthleak.core.types import Light, RenderMesh, RenderScene
from synthleak.geometry.poses import look_at, make_pose

FLAT = 0.9
"""An emitter is flat when the length of its summed area-weighted normals is at least this share of its area."""
MIN_SHARE = 0.01
"""Stand-ins radiating less than this share of the power of the stage's sphere and rect lights are left out
(a glowing bulb inside a lamp that has its own light): pyrender draws at most 4 lights of each type."""
DEFAULT_IRRADIANCE = 2.0
"""W/m^2 the default light of a walk-through stage gives at the floor straight below it."""
DEFAULT_AMBIENT = 0.6
"""Radiance of the default ambient environment of an attacker stage."""
DEFAULT_LIGHT_NAME = "synthleak_default_light"


def _emitter(mesh: RenderMesh) -> tuple[float, np.ndarray, np.ndarray]:
    """(area, area-weighted normal sum / 2-vector, area-weighted centroid) of a mesh's triangles."""
    verts, faces = mesh.checked_arrays()
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    area = float(areas.sum())
    centroid = (areas[:, None] * tri.mean(axis=1)).sum(axis=0) / max(area, 1e-12)
    return area, 0.5 * cross.sum(axis=0), centroid


def light_power(light: Light) -> float:
    """Radiant power (W, mean over RGB) of a sphere or rect light; 0 for other kinds (distant lights)."""
    colour = float(np.mean(np.clip(light.color, 0.0, None)))
    if light.kind == "sphere":
        return 4.0 * np.pi * float(light.intensity) * colour
    if light.kind == "rect":
        return np.pi * float(light.intensity) * float(light.size[0]) * float(light.size[1]) * colour
    return 0.0


def emissive_lights(scene: RenderScene) -> list[Light]:
    """Stand-in lights for the emissive meshes of ``scene`` (see the module docstring)."""
    out: list[Light] = []
    for mesh in scene.meshes:
        if mesh.emissive is None or max(mesh.emissive) <= 0:
            continue
        area, normal_sum, centroid = _emitter(mesh)
        if area <= 0:
            continue
        radiance = np.clip(np.asarray(mesh.emissive, dtype=np.float64), 0.0, None)
        peak = float(radiance.max())
        colour = tuple(float(c) for c in radiance / peak)
        projected = float(np.linalg.norm(normal_sum))
        name = f"emissive_{mesh.instance_id}_{len(out)}"
        if projected >= FLAT * area:
            normal = normal_sum / projected
            side = float(np.sqrt(projected))
            position = centroid + 0.01 * normal
            # our rect lights face -z of their frame: look along the normal (a camera looks along its +z)
            up = (0.0, 0.0, 1.0) if abs(normal[2]) < 0.9 else (0.0, 1.0, 0.0)
            cam_from_world = look_at(position, position + normal, up)
            rot = cam_from_world[:3, :3].T @ np.diag([1.0, -1.0, -1.0])  # +z of the light = -normal
            out.append(Light(name, "rect", make_pose(rot, position), peak, colour, size=(side, side)))
        else:
            out.append(Light(name, "sphere", make_pose(np.eye(3), centroid), peak * area / 4.0, colour,
                             radius=float(np.sqrt(area / (4.0 * np.pi)))))
    total = sum(light_power(light) for light in scene.lights)
    return [light for light in out if light_power(light) >= MIN_SHARE * total]


def has_light(scene: RenderScene) -> bool:
    """Whether anything lights ``scene``: a light, an ambient (dome) term or an emissive mesh."""
    return (
        any(light.intensity > 0 for light in scene.lights)
        or scene.ambient > 0
        or any(m.emissive is not None and max(m.emissive) > 0 for m in scene.meshes)
    )


def default_light(scene: RenderScene) -> Light:
    """The default light of a walk-through stage (placement and intensity in the module docstring)."""
    if not scene.meshes:
        raise ValueError(f"{scene.source or 'scene'}: no meshes to place a default light by")
    verts = np.concatenate([np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in scene.meshes])
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = 0.5 * (lo + hi)
    height = max(0.8 * (hi[2] - lo[2]), 0.25 * float(np.linalg.norm(hi[:2] - lo[:2])), 0.1)
    position = np.array([centre[0], centre[1], lo[2] + height])
    return Light(DEFAULT_LIGHT_NAME, "sphere", make_pose(np.eye(3), position), DEFAULT_IRRADIANCE * height**2)


def with_default_light(scene: RenderScene) -> RenderScene:
    """``scene`` itself when anything lights it; else a copy with the default light, and a warning."""
    if has_light(scene):
        return scene
    if scene.target_instance_id is not None:
        lit = dataclasses.replace(scene, ambient=DEFAULT_AMBIENT)
        what = f"an ambient environment of radiance {DEFAULT_AMBIENT:g}"
    else:
        light = default_light(scene)
        lit = dataclasses.replace(scene, lights=[light])
        where = ", ".join(f"{v:.2f}" for v in light.world_from_light[:3, 3])
        what = f"a point light of {light.intensity:.3g} W/sr at ({where}) m"
    warnings.warn(
        f"{scene.source or 'scene'}: the stage has no light (no UsdLux light, dome light or emissive mesh); "
        f"rendering it with the default light: {what} (see docs/renderers.md, 'Lights')",
        UserWarning,
        stacklevel=2,
    )
    return lit
