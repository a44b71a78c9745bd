"""Light that changes between captures: the map walk-through, the genuine queries and the attacker's photos
lit as at different times of day (``[render] light_map / light_genuine / light_attacker``, docs/renderers.md
"Light that changes between captures").

``same`` (the default) renders the stage's own lights. ``varied`` draws a :class:`LightingCondition` per
capture kind (``map``, ``genuine``, ``attacker``) and per sequence from
``derive_seed(seed, "lighting", kind, sequence)`` and applies it to the :class:`RenderScene` before the
renderer is prepared (:func:`apply_condition`):

* day or night (even odds); each lamp of the stage (its ``sphere`` and ``rect`` lights) is off with
  probability 0.5 by day and 0.2 at night, and at least one stays on (the renderers have no sky light bouncing
  in through the window, so a room with every lamp off renders black but for the sun patch); the lamps
  that are on are dimmed or brightened together (log-U(0.5, 1.5)) and take one colour temperature, uniform in mired over
  2,700-6,500 K (warm-white bulbs to daylight LEDs): each lamp's colour times
  ``planckian_rgb(T) / planckian_rgb(4700 K)`` (:func:`synthleak.render.capture.planckian_rgb`, relative to the
  white the renders are balanced for, :data:`REFERENCE_K`) at the lamp's luminance; emissive meshes take the same
  dimmer and colour;
* daylight: a room with a window (its ``backdrop`` shell piece, the outdoor panel behind the window) gets by
  day a sun, a ``distant`` light entering through the window (azimuth within 35 deg of the window's outward
  normal, elevation 35-60 deg so that it clears the backdrop panel, irradiance log-U(2, 8) W/m^2 against the
  ~2 W/m^2 a ceiling lamp gives the floor, 5,000-6,500 K); the stage's own distant lights are scaled by
  log-U(0.6, 1.5) by day and U(0.2, 0.5) at night and take the daylight colour;
* the ambient (sky / environment) term is scaled by log-U(1, 2.5) by day and log-U(0.2, 0.6) at night (an
  ambient term is grey: the renderers take a scalar).

The ground truth (depth, instance ids, poses) does not depend on the light. Environment maps are not used:
the only CC0 HDR maps on the package registries come with ``bpy`` (Blender's studio lights) or npm, neither a
dependency of the default renderers.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from synthleak.core.types import Light, RenderScene
from synthleak.errors import StageError
from synthleak.portable import matmul
from synthleak.portable import norm as portable_norm
from synthleak.render.capture import LUMA, planckian_rgb

LIGHTING_CHANGES = ("same", "varied")
"""Values of ``[render] light_map / light_genuine / light_attacker``."""
SAME = "same"
LIGHTING_RECORDS = "lighting.json"
"""Per sequence: each frame's lighting condition and the conditions drawn (only when one is ``varied``)."""
SUN_NAME = "synthleak_sun"
LAMP_K = (2700.0, 6500.0)
DAYLIGHT_K = (5000.0, 6500.0)
REFERENCE_K = 4700.0
"""The light colour the renders are white-balanced for: the capture profiles' nominal illuminant (Infinigen's mean
lamp). A lamp at T shows ``planckian_rgb(T) / planckian_rgb(REFERENCE_K)``, as through a camera whose white
balance stays at 4,700 K (the capture model's white balance adds its own error on top)."""


@dataclass(frozen=True)
class LightingCondition:
    """One capture session's light (see the module docstring for the distributions)."""

    capture_kind: str
    daytime: bool
    lamps_on: tuple[bool, ...]
    """Per lamp (``sphere`` / ``rect`` light of the stage, in the stage's order)."""
    lamp_scale: float
    lamp_temperature_k: float
    ambient_scale: float
    distant_scale: float
    """Factor on the stage's own distant lights."""
    daylight_temperature_k: float
    sun_irradiance: float = 0.0
    """Irradiance (W/m^2, render units) of the sun through the window; 0: no sun."""
    sun_direction: tuple[float, float, float] = (0.0, 0.0, -1.0)
    """Unit direction the sunlight travels (world frame)."""

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _mired_uniform(lo_k: float, hi_k: float, t: float) -> float:
    lo, hi = 1e6 / hi_k, 1e6 / lo_k
    return float(1e6 / (lo + (hi - lo) * float(t)))


def _log_uniform(lo: float, hi: float, t: float) -> float:
    return float(math.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * t))


def is_lamp(light: Light) -> bool:
    return light.kind in ("sphere", "rect")


def window_normal(scene: RenderScene) -> np.ndarray | None:
    """Horizontal unit vector from the room's centre out through its window (towards the ``backdrop`` shell
    piece behind it), or ``None`` when the stage has no such piece."""
    backdrop = [i for i in scene.instances.values() if i.role == "shell" and "backdrop" in i.name.lower()]
    if not backdrop:
        return None
    ids = {i.instance_id for i in backdrop}
    inside = [np.asarray(m.vertices, dtype=np.float64).reshape(-1, 3) for m in scene.meshes if m.instance_id not in ids]
    if not inside:
        return None
    verts = np.concatenate(inside)
    centre = 0.5 * (verts.min(axis=0) + verts.max(axis=0))
    out = np.asarray(backdrop[0].world_from_object, dtype=np.float64)[:3, 3] - centre
    out[2] = 0.0
    norm = float(portable_norm(out))
    return out / norm if norm > 1e-6 else None


def draw_condition(scene: RenderScene, capture_kind: str, seed: int) -> LightingCondition:
    """The lighting condition of one capture kind of one sequence, from ``numpy.random.default_rng(seed)``:
    always 10 uniforms, then one per lamp, so the draws do not depend on the stage but for the lamp count."""
    rng = np.random.default_rng(int(seed))
    u = rng.random(10)
    lamps = [light for light in scene.lights if is_lamp(light)]
    lamp_u = rng.random(len(lamps))
    daytime = bool(u[0] < 0.5)
    on = lamp_u >= (0.5 if daytime else 0.2)
    window = window_normal(scene)
    if lamps and not on.any():  # the renderers have no sky bouncing in through a window (a direct integrator:
        on[int(np.argmax(lamp_u))] = True  # none at all), so a room with every lamp off is black: one stays on
    sun, direction = 0.0, (0.0, 0.0, -1.0)
    if daytime and window is not None:
        azimuth = math.atan2(window[1], window[0]) + math.radians(-35.0 + 70.0 * u[5])
        elevation = math.radians(35.0 + 25.0 * u[6])
        towards_sun = np.array([math.cos(azimuth) * math.cos(elevation), math.sin(azimuth) * math.cos(elevation),
                                math.sin(elevation)])
        direction = tuple(float(c) for c in -towards_sun)
        sun = _log_uniform(2.0, 8.0, u[7])
    return LightingCondition(
        capture_kind=capture_kind,
        daytime=daytime,
        lamps_on=tuple(bool(b) for b in on),
        lamp_scale=_log_uniform(0.5, 1.5, u[1]),
        lamp_temperature_k=_mired_uniform(*LAMP_K, u[2]),
        ambient_scale=_log_uniform(1.0, 2.5, u[3]) if daytime else _log_uniform(0.2, 0.6, u[3]),
        distant_scale=_log_uniform(0.6, 1.5, u[4]) if daytime else 0.2 + 0.3 * float(u[4]),
        daylight_temperature_k=_mired_uniform(*DAYLIGHT_K, u[8]),
        sun_irradiance=sun,
        sun_direction=direction,
    )


def _tinted(colour: tuple[float, float, float] | np.ndarray, temperature_k: float) -> tuple[float, float, float]:
    """``colour`` lit at ``temperature_k`` instead of the renders' white (:data:`REFERENCE_K`): times
    ``planckian_rgb(T) / planckian_rgb(REFERENCE_K)``, at ``colour``'s luminance."""
    c = np.clip(np.asarray(colour, dtype=np.float64), 0.0, None)
    rgb = c * planckian_rgb(temperature_k) / planckian_rgb(REFERENCE_K)
    rgb = rgb * float(matmul(c, LUMA)) / max(float(matmul(rgb, LUMA)), 1e-12)  # not BLAS: the same bits everywhere
    return (float(rgb[0]), float(rgb[1]), float(rgb[2]))


def _sun_light(condition: LightingCondition) -> Light:
    towards_sun = -np.asarray(condition.sun_direction, dtype=np.float64)
    helper = np.array([1.0, 0.0, 0.0]) if abs(towards_sun[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, towards_sun)
    x /= portable_norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(towards_sun, x), towards_sun])  # distant lights shine along -z
    return Light(SUN_NAME, "distant", pose, float(condition.sun_irradiance),
                 _tinted((1.0, 1.0, 1.0), condition.daylight_temperature_k))


def apply_condition(scene: RenderScene, condition: LightingCondition) -> RenderScene:
    """A copy of ``scene`` lit by ``condition``: lamps switched, dimmed and tinted, distant lights scaled and
    tinted, the sun added, the ambient term scaled; meshes, instances and everything else shared."""
    lamps = [light for light in scene.lights if is_lamp(light)]
    if len(lamps) != len(condition.lamps_on):
        raise ValueError(f"{scene.source or 'scene'}: lighting condition for {len(condition.lamps_on)} lamps, "
                         f"the stage has {len(lamps)}")
    switch = iter(condition.lamps_on)
    lights: list[Light] = []
    for light in scene.lights:
        if is_lamp(light):
            if next(switch):
                lights.append(dataclasses.replace(light, intensity=float(light.intensity) * condition.lamp_scale,
                                                  color=_tinted(light.color, condition.lamp_temperature_k)))
        elif light.kind == "distant":
            lights.append(dataclasses.replace(light, intensity=float(light.intensity) * condition.distant_scale,
                                              color=_tinted(light.color, condition.daylight_temperature_k)))
        else:
            lights.append(light)
    if condition.sun_irradiance > 0:
        lights.append(_sun_light(condition))
    meshes = [
        dataclasses.replace(m, emissive=tuple(condition.lamp_scale * c
                                              for c in _tinted(m.emissive, condition.lamp_temperature_k)))
        if m.emissive is not None and max(m.emissive) > 0 else m
        for m in scene.meshes
    ]
    return dataclasses.replace(scene, lights=lights, meshes=meshes, ambient=float(scene.ambient) *
                               condition.ambient_scale)


# ---------------------------------------------------------------------------------------------------- the plan


def lighting_kinds(render: Any, kind: str, frames: list[str], split: dict[str, list[str]] | None) -> list[str]:
    """Each frame's lighting: ``""`` for the stage's own lights (``same``), else the capture kind whose condition
    lights it (``map`` / ``genuine`` for a scene sequence's mapping and held-out query frames of ``split``,
    ``attacker`` for an orbit)."""
    if kind == "attacker":
        return ["attacker" if render.light_attacker != SAME else ""] * len(frames)
    query = set((split or {}).get("query", []))
    out = []
    for f in frames:
        label = "genuine" if f in query else "map"
        out.append(label if getattr(render, f"light_{label}") != SAME else "")
    return out


def lighting_seed(root_seed: int, capture_kind: str, sequence: str) -> int:
    from synthleak.seeding import derive_seed

    return derive_seed(root_seed, "lighting", capture_kind, sequence)


def lit_scene(scene: RenderScene, label: str, root_seed: int, sequence: str) -> RenderScene:
    """``scene`` under the condition of capture kind ``label`` of ``sequence`` (``""``: unchanged)."""
    if not label:
        return scene
    return apply_condition(scene, draw_condition(scene, label, lighting_seed(root_seed, label, sequence)))


def lighting_record(scene: RenderScene, labels: list[str], frames: list[str], root_seed: int, sequence: str
                    ) -> dict[str, Any] | None:
    """The sequence's ``lighting.json`` content (``None`` when every frame has the stage's lights)."""
    if not any(labels):
        return None
    conditions = {label: draw_condition(scene, label, lighting_seed(root_seed, label, sequence)).to_json()
                  for label in sorted(set(labels) - {""})}
    return {"frames": {f: (label or "stage") for f, label in zip(frames, labels, strict=True)},
            "conditions": conditions}


def check_lighting_plan(out_dir: Path, record: dict[str, Any] | None, any_frame_done: bool) -> None:
    """Refuse to resume a sequence rendered under other lighting (an error naming ``lighting.json``)."""
    path = Path(out_dir) / LIGHTING_RECORDS
    if path.is_file():
        try:
            old = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise StageError(f"{path}: cannot read: {exc}") from exc
        if record is None or json.loads(json.dumps(record)) != old:
            raise StageError(f"{path}: the sequence was rendered under other lighting (render.light_map / "
                             "light_genuine / light_attacker changed); render into a new folder")
    elif record is not None and any_frame_done:
        raise StageError(f"{path}: missing, but {out_dir} has frames rendered under the stage's own lights; "
                         "render the varied lighting into a new folder")
