"""Tiny USD stages written with usd-core as another tool would: a Cornell-box-like room (2 x 2 x 2 m, z up,
metres, no synthleak attributes) with a red left wall, a green right wall and a grey box, lit by an emissive
ceiling patch, a UsdLux sphere light, or nothing."""

from __future__ import annotations

from pathlib import Path

from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade

HALF = 1.0
HEIGHT = 2.0


def _material(stage: Usd.Stage, path: str, colour: tuple[float, float, float],
              emissive: tuple[float, float, float] | None = None) -> UsdShade.Material:
    material = UsdShade.Material.Define(stage, path)
    shader = UsdShade.Shader.Define(stage, f"{path}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*colour))
    if emissive is not None:
        shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*emissive))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return material


def _quad(stage: Usd.Stage, path: str, corners: list[tuple[float, float, float]], material: UsdShade.Material) -> None:
    """A quad whose front (right-handed winding) faces the viewer of ``corners`` listed counter-clockwise."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    mesh.CreatePointsAttr([Gf.Vec3f(*c) for c in corners])
    mesh.CreateFaceVertexCountsAttr([4])
    mesh.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(mesh.GetPrim()).Bind(material)


def write_cornell_box(path: Path, light: str = "emissive") -> Path:
    """The box at ``path``; ``light``: ``emissive`` (a 0.6 x 0.6 m ceiling patch of radiance 15, the only
    light), ``sphere`` (a UsdLux sphere light under the ceiling) or ``none``."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetDefaultPrim(stage.DefinePrim("/Box", "Xform"))
    h, top = HALF, HEIGHT
    grey = _material(stage, "/Box/Looks/Grey", (0.7, 0.7, 0.7))
    _quad(stage, "/Box/Floor", [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], grey)
    _quad(stage, "/Box/Ceiling", [(-h, -h, top), (-h, h, top), (h, h, top), (h, -h, top)], grey)
    _quad(stage, "/Box/Back", [(-h, h, 0), (h, h, 0), (h, h, top), (-h, h, top)], grey)
    _quad(stage, "/Box/Left", [(-h, -h, 0), (-h, h, 0), (-h, h, top), (-h, -h, top)],
          _material(stage, "/Box/Looks/Red", (0.7, 0.1, 0.1)))
    _quad(stage, "/Box/Right", [(h, -h, 0), (h, -h, top), (h, h, top), (h, h, 0)],
          _material(stage, "/Box/Looks/Green", (0.1, 0.7, 0.1)))
    b = 0.3
    cube = UsdGeom.Mesh.Define(stage, "/Box/Cube")
    cube.CreatePointsAttr([Gf.Vec3f(x, y, z) for x in (-b, b) for y in (-b, b) for z in (0.0, 2 * b)])
    cube.CreateFaceVertexCountsAttr([4] * 6)
    cube.CreateFaceVertexIndicesAttr([0, 1, 3, 2, 4, 6, 7, 5, 0, 4, 5, 1, 2, 3, 7, 6, 0, 2, 6, 4, 1, 5, 7, 3])
    UsdShade.MaterialBindingAPI.Apply(cube.GetPrim()).Bind(grey)
    if light == "emissive":
        s, z = 0.3, top - 0.01
        lamp = _material(stage, "/Box/Looks/Lamp", (0.8, 0.8, 0.8), emissive=(15.0, 15.0, 15.0))
        _quad(stage, "/Box/Lamp", [(-s, -s, z), (-s, s, z), (s, s, z), (s, -s, z)], lamp)  # faces down
    elif light == "sphere":
        sphere = UsdLux.SphereLight.Define(stage, "/Box/Bulb")
        sphere.CreateIntensityAttr(3.0)
        sphere.CreateRadiusAttr(0.05)
        UsdGeom.Xformable(sphere.GetPrim()).AddTranslateOp().Set(Gf.Vec3d(0.0, 0.0, top - 0.3))
    elif light != "none":
        raise ValueError(f"light: {light!r} is not emissive, sphere or none")
    stage.GetRootLayer().Save()
    return Path(path)


def write_config(path: Path, **render: object) -> Path:
    """A study config extending ci-tiny with a tiny render (64 x 48, 4 walk-through and 2 orbit frames)."""
    values = {"width": 64, "height": 48, "spp": 2, "scene_frames": 4, "attacker_frames": 2, "query_every": 2,
              **render}
    lines = ['extends = "ci-tiny"', f'name = "{Path(path).stem}"', "", "[render]"]
    lines += [f"{k} = {_toml(v)}" for k, v in values.items()]
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)


def _toml(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)
