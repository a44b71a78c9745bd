"""Scene composer: shell, placement rules, collisions, study plan, attacker hall, stage files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from synthleak.assets.builders import SupportSurface
from synthleak.assets.mesh import ObjectMesh
from synthleak.config import ConfigError, config_from_dict, config_to_dict
from synthleak.geometry.poses import transform_points
from synthleak.scene.attacker_env import CANOPY_HEIGHT, PEDESTAL_HEIGHT, _target_pose_and_props, hall_shell
from synthleak.scene.attacker_settings import SETTING_KINDS, min_room_size
from synthleak.scene.placement import Item, place_items
from synthleak.scene.plan import plan_study
from synthleak.scene.room import SHELL_IDS, build_room_shell
from synthleak.scene.shell_geometry import merge_parts, planar_box
from synthleak.scene.spec import PlacedObject
from synthleak.scene.styles import StyleError, load_styles, room_styles

TOL = 0.005  # "rests on its support within 5 mm"


# ------------------------------------------------------------------------------------------- helpers


def _world_mesh(obj_mesh: ObjectMesh, pose: np.ndarray) -> trimesh.Trimesh:
    verts, faces, off = [], [], 0
    for part in obj_mesh.parts:
        verts.append(transform_points(pose, part.vertices))
        faces.append(part.faces + off)
        off += len(part.vertices)
    return trimesh.Trimesh(np.concatenate(verts), np.concatenate(faces), process=False)


def _edges_cross(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Whether an edge of ``a`` passes through a triangle of ``b`` (embree ray cast along the edges)."""
    edges = a.vertices[a.edges_unique]
    direction = edges[:, 1] - edges[:, 0]
    length = np.linalg.norm(direction, axis=1)
    keep = length > 1e-9
    origins, direction, length = edges[keep, 0], direction[keep] / length[keep, None], length[keep]
    tri, ray, loc = b.ray.intersects_id(origins, direction, multiple_hits=False, return_locations=True)
    if len(ray) == 0:
        return False
    dist = np.einsum("ij,ij->i", loc - origins[ray], direction[ray])
    return bool(np.any((dist > 1e-7) & (dist < length[ray] - 1e-7)))


def meshes_intersect(a: trimesh.Trimesh, b: trimesh.Trimesh) -> bool:
    """Surface intersection test of two triangle meshes (an edge of one crossing a triangle of the other)."""
    lo = np.maximum(a.bounds[0], b.bounds[0])
    hi = np.minimum(a.bounds[1], b.bounds[1])
    if np.any(lo > hi):
        return False
    return _edges_cross(a, b) or _edges_cross(b, a)


def _box_mesh(ext, name="box") -> ObjectMesh:
    tex = np.full((8, 8, 3), 128, np.uint8)
    lo = np.array([-ext[0] / 2, -ext[1] / 2, 0.0])
    hi = np.array([ext[0] / 2, ext[1] / 2, ext[2]])
    return ObjectMesh([planar_box(name, lo, hi, tex, lo, hi)])


def _shelf_mesh(width=0.8, depth=0.3, height=1.2, boards=(0.0, 0.4, 0.8)) -> tuple[ObjectMesh, list]:
    tex = np.full((8, 8, 3), 90, np.uint8)
    t = 0.02
    parts, surfaces = [], []
    for x in (-width / 2, width / 2 - t):  # sides
        lo, hi = np.array([x, -depth / 2, 0.0]), np.array([x + t, depth / 2, height])
        parts.append(planar_box("side", lo, hi, tex, lo, hi))
    for z in (*boards, height - t):
        lo, hi = np.array([-width / 2 + t, -depth / 2, z]), np.array([width / 2 - t, depth / 2, z + t])
        parts.append(planar_box("board", lo, hi, tex, lo, hi))
        if z < height - t:
            surfaces.append(SupportSurface(z + t, -width / 2 + t, width / 2 - t, -depth / 2, depth / 2))
    return ObjectMesh([merge_parts("carcass", parts)]), surfaces


def _table_mesh(width=1.2, depth=0.8, height=0.75) -> tuple[ObjectMesh, list]:
    tex = np.full((8, 8, 3), 60, np.uint8)
    parts = []
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = np.array([sx * (width / 2 - 0.04), sy * (depth / 2 - 0.04)])
            lo, hi = (
                np.array([c[0] - 0.03, c[1] - 0.03, 0.0]),
                np.array([c[0] + 0.03, c[1] + 0.03, height - 0.03]),
            )
            parts.append(planar_box("leg", lo, hi, tex, lo, hi))
    lo, hi = np.array([-width / 2, -depth / 2, height - 0.03]), np.array([width / 2, depth / 2, height])
    parts.append(planar_box("top", lo, hi, tex, lo, hi))
    return ObjectMesh([merge_parts("table", parts)]), [
        SupportSurface(height, -width / 2, width / 2, -depth / 2, depth / 2)
    ]


def _check_room(objects: list[PlacedObject], size, supported_by: dict[int, int], openings=()) -> None:
    """The composer's contract: inside the room, on their supports, no intersections (furniture and clutter
    props; rugs, flat on the floor, may lie under furniture)."""
    x, y, h = size
    by_id = {o.instance_id: o for o in objects}
    furniture = [o for o in objects if o.role in ("object", "prop")]
    meshes = {o.instance_id: _world_mesh(o.mesh, o.world_from_object) for o in objects}
    for o in furniture:
        lo, hi = meshes[o.instance_id].bounds
        assert lo[0] >= -x / 2 - 1e-6 and hi[0] <= x / 2 + 1e-6, o.name
        assert lo[1] >= -y / 2 - 1e-6 and hi[1] <= y / 2 + 1e-6, o.name
        assert lo[2] >= -1e-6 and hi[2] <= h + 1e-6, o.name
        if o.support == "floor":
            assert abs(lo[2]) < TOL, o.name
        elif o.support == "ceiling":
            assert abs(hi[2] - h) < TOL, o.name
        elif o.support == "wall":
            gaps = [lo[0] + x / 2, x / 2 - hi[0], lo[1] + y / 2, y / 2 - hi[1]]
            assert min(gaps) < TOL, o.name
            centre = 0.5 * (lo[2] + hi[2])
            assert 1.2 - 1e-6 <= centre <= 1.8 + 1e-6 or hi[2] - lo[2] > 1.0, o.name
        elif o.support == "surface":
            host = by_id[supported_by[o.instance_id]]
            assert host.role == "object" and host.support == "floor"
            host_mesh = meshes[host.instance_id]
            # the object's bottom rests on some horizontal host face within 5 mm
            bottom = lo[2]
            centre = 0.5 * (lo[:2] + hi[:2])
            origins = np.array([[centre[0], centre[1], bottom + 0.003]])
            hits, _, _ = host_mesh.ray.intersects_location(origins, np.array([[0.0, 0.0, -1.0]]))
            assert len(hits) and np.max(hits[:, 2]) > bottom - TOL, (o.name, hits)
    # pairwise: furniture against furniture and shell (lifted 0.5 mm off what they touch)
    lifted = {}
    for o in furniture:
        mesh = meshes[o.instance_id].copy()
        lift = {"floor": 0.0005, "surface": 0.001, "ceiling": -0.0005}.get(o.support, 0.0)
        mesh.apply_translation([0.0, 0.0, lift])
        lifted[o.instance_id] = mesh
    ids = sorted(lifted)
    flat = {i for i in ids if meshes[i].extents[2] < 0.05}
    for i, a in enumerate(ids):
        for b in ids[i + 1 :]:
            if (a in flat) != (b in flat):
                continue
            assert not meshes_intersect(lifted[a], lifted[b]), (by_id[a].name, by_id[b].name)
        for shell in (o for o in objects if o.role == "shell"):
            assert not meshes_intersect(lifted[a], meshes[shell.instance_id]), (by_id[a].name, shell.name)


# ------------------------------------------------------------------------------------------- shell


def test_room_shell_pieces_and_opening() -> None:
    size = (5.0, 4.0, 2.6)
    shell = build_room_shell(size, room_styles()[0], np.random.default_rng(3), texture_size=128)
    ids = [p.instance_id for p in shell.pieces]
    assert len(ids) == len(set(ids)) and all(1 <= i <= 99 for i in ids)
    assert all(p.role == "shell" for p in shell.pieces)
    names = {p.name for p in shell.pieces}
    assert {"floor", "ceiling", "wall_south", "wall_north", "wall_west", "wall_east", "door"} <= names
    meshes = {p.name: _world_mesh(p.mesh, p.world_from_object) for p in shell.pieces}
    assert abs(meshes["floor"].bounds[1, 2]) < 1e-9 and abs(meshes["ceiling"].bounds[0, 2] - 2.6) < 1e-9
    # walls, door and window backdrop enclose the room: rays from the centre hit something everywhere
    enclosure = [n for n in names if n.startswith("wall") or n in ("door", "backdrop")]
    walls = trimesh.util.concatenate([meshes[n] for n in enclosure])
    angles = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    origins = np.tile([0.0, 0.0, 1.0], (len(dirs), 1))
    _, ray, _ = walls.ray.intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    assert len(set(ray.tolist())) == len(dirs)
    # a door opening is a hole in its wall (closed by the separate door piece)
    door = next(o for o in shell.openings if o.kind == "door")
    wall = shell.walls[door.wall]
    centre = transform_points(wall.world_from_wall, [[0.5 * (door.x0 + door.x1), 0.3, 1.0]])
    inward = wall.world_from_wall[:3, 1]
    only_wall = meshes[door.wall]
    assert len(only_wall.ray.intersects_id(centre, -inward[None])[0]) == 0
    assert len(meshes["door"].ray.intersects_id(centre, -inward[None])[0]) >= 1
    assert shell.keepout and shell.keepout[0].area > 0.5


# ------------------------------------------------------------------------------------------- placement


def test_placement_rules_synthetic_items() -> None:
    size = (5.0, 4.2, 2.6)
    shell = build_room_shell(size, room_styles()[1], np.random.default_rng(7), texture_size=128)
    shelf, shelf_surfaces = _shelf_mesh()
    table, table_surfaces = _table_mesh()
    items = [
        Item("shelf", "floor", shelf, surfaces=shelf_surfaces),
        Item("table", "floor", table, surfaces=table_surfaces),
        Item("chair", "floor", _box_mesh((0.45, 0.5, 0.9))),
        Item("stool", "floor", _box_mesh((0.35, 0.35, 0.45)), symmetry="z"),
        Item("picture", "wall", _box_mesh((0.6, 0.03, 0.45))),
        Item("clock", "wall", _box_mesh((0.3, 0.05, 0.3))),
        Item("pendant", "ceiling", _box_mesh((0.4, 0.4, 0.5)), symmetry="z"),
        Item("vase", "surface", _box_mesh((0.12, 0.12, 0.3)), symmetry="z"),
        Item("lamp", "surface", _box_mesh((0.2, 0.2, 0.35))),
        Item("box", "surface", _box_mesh((0.2, 0.15, 0.12))),
    ]
    placements, dropped, _ = place_items(shell, items, np.random.default_rng(1))
    assert dropped == []
    ids = {item.name: 100 + i for i, item in enumerate(items)}
    objects = list(shell.pieces)
    supported_by = {}
    for item in items:
        pl = placements[item.name]
        objects.append(
            PlacedObject(
                ids[item.name],
                item.name,
                item.name,
                "x",
                item.symmetry,
                pl.world_from_object,
                item.mesh,
                support=item.support,
            )
        )
        if item.support == "surface":
            supported_by[ids[item.name]] = ids[pl.parent]
            # the object's bottom lies on a host surface height within 5 mm
            host_item = next(i for i in items if i.name == pl.parent)
            host_pose = placements[pl.parent].world_from_object
            local = np.linalg.solve(host_pose, pl.world_from_object)
            assert min(abs(local[2, 3] - s.z) for s in host_item.surfaces) < TOL
        if item.support == "wall":  # never over an opening
            for o in shell.openings:
                if o.wall == pl.parent:
                    wall = shell.walls[o.wall]
                    local = np.linalg.solve(wall.world_from_wall, pl.world_from_object)
                    (x0, _, z0), (x1, _, z1) = item.bounds
                    assert (
                        local[0, 3] + x1 <= o.x0
                        or local[0, 3] + x0 >= o.x1
                        or local[2, 3] + z0 >= o.z1
                        or local[2, 3] + z1 <= o.z0
                    )
    _check_room(objects, size, supported_by)


def test_placement_deterministic() -> None:
    shell = build_room_shell((4.5, 4.0, 2.5), room_styles()[0], np.random.default_rng(2), texture_size=64)
    items = [Item(f"b{i}", "floor", _box_mesh((0.6, 0.5, 0.8))) for i in range(5)]
    a, _, _ = place_items(shell, items, np.random.default_rng(9))
    b, _, _ = place_items(shell, items, np.random.default_rng(9))
    c, _, _ = place_items(shell, items, np.random.default_rng(10))
    assert all(np.array_equal(a[k].world_from_object, b[k].world_from_object) for k in a)
    assert any(not np.array_equal(a[k].world_from_object, c[k].world_from_object) for k in a)


def test_floor_objects_mostly_face_into_the_room() -> None:
    shell = build_room_shell((6.0, 5.0, 2.6), room_styles()[0], np.random.default_rng(4), texture_size=64)
    facing = total = 0
    for seed in range(6):
        items = [Item(f"c{i}", "floor", _box_mesh((0.5, 0.5, 0.9))) for i in range(6)]
        placements, _, _ = place_items(shell, items, np.random.default_rng(seed))
        for pl in placements.values():
            front = pl.world_from_object[:3, 1]
            to_centre = -pl.world_from_object[:3, 3]
            facing += float(front[:2] @ to_centre[:2]) > 0
            total += 1
    assert facing / total > 0.8


# ------------------------------------------------------------------------------------------- plan


@pytest.fixture(scope="module")
def library() -> dict:
    from synthleak.assets.library import load_library

    return load_library()


def test_plan_distinct_objects_and_repeats(library: dict) -> None:
    n = min(len(library), 12)
    config = config_from_dict(
        {"seed": 5, "scenes": {"rooms": 4, "objects_per_room": [4, 6], "distinct_objects": n}}
    )
    plan = plan_study(config, library)
    again = plan_study(config, library)
    assert plan == again
    assert len(plan.rooms) == 4
    slots = sum(len(r.objects) for r in plan.rooms)
    assert len(plan.attackers) == min(n, slots)
    appearances = [len(rooms) for rooms in plan.present_in.values()]
    assert min(appearances) >= 1
    assert sum(appearances) == slots
    if slots > n:
        assert max(appearances) >= 2
    for room in plan.rooms:
        ids = [o.instance_id for o in room.objects]
        assert ids == list(range(100, 100 + len(ids)))
        assert len({o.model_id for o in room.objects}) == len(ids)  # a model at most once per room
        assert 4.0 <= room.size[0] <= 6.0 and 2.5 <= room.size[2] <= 2.8
        surface = [o for o in room.objects if library[o.model_id].support == "surface"]
        if surface:
            from synthleak.scene.plan import model_offers_support

            assert any(model_offers_support(library[o.model_id]) for o in room.objects)
    for k, a in enumerate(plan.attackers):
        assert a.object_id == f"a{k:02d}_{a.model_id}" and a.magnitude == 0.5
    other = plan_study(
        config_from_dict(
            {
                "seed": 6,
                "scenes": config_to_dict(config)["scenes"],
            }
        ),
        library,
    )
    assert other != plan


def test_plan_rejects_unknown_models(library: dict) -> None:
    config = config_from_dict({"scenes": {"models": ["no_such_model"]}})
    with pytest.raises(ConfigError, match="scenes.models"):
        plan_study(config, library)


def test_style_errors_name_file_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "styles.toml"
    bad.write_text('[[style]]\nname = "x"\nfloor = ["parquet"]\nfloor_colours = [[2.0, 0, 0]]\n')
    with pytest.raises(StyleError, match=r"styles.toml.*floor_colours\[0\]"):
        load_styles(bad)
    bad.write_text('[[style]]\nname = "x"\nfloor = ["lava"]\nfloor_colours = [[0.5, 0.5, 0.5]]\n')
    with pytest.raises(StyleError, match=r"styles.toml.*floor.*lava"):
        load_styles(bad)


# ------------------------------------------------------------------------------------------- attacker hall


@pytest.mark.parametrize("support", ["floor", "surface", "wall", "ceiling"])
def test_attacker_target_support(support: str) -> None:
    style, shell = hall_shell(seed=1)
    mesh = _box_mesh((0.4, 0.1 if support == "wall" else 0.4, 0.5))
    pose, props = _target_pose_and_props(support, mesh, style, np.random.default_rng(0))
    np.testing.assert_array_equal(pose[:3, :3], np.eye(3))
    assert pose[0, 3] == 0.0
    target = _world_mesh(mesh, pose)
    lo, hi = target.bounds
    if support == "floor":
        assert props == [] and abs(lo[2]) < 1e-9
    elif support == "surface":
        assert props[0].name == "pedestal" and abs(lo[2] - PEDESTAL_HEIGHT) < 1e-9
    elif support == "wall":
        panel = _world_mesh(props[0].mesh, props[0].world_from_object)
        assert 0 < lo[1] - panel.bounds[1, 1] < TOL and 1.2 <= 0.5 * (lo[2] + hi[2]) <= 1.8
    else:
        assert props[0].name == "canopy" and abs(hi[2] - CANOPY_HEIGHT) < 1e-9
    away = {"surface": [0, 0, 5e-4], "wall": [0, 5e-4, 0], "ceiling": [0, 0, -5e-4]}.get(support, [0, 0, 0])
    target.apply_translation(away)  # off the contact face it shares with its prop
    for prop in props:
        assert prop.role == "shell" and prop.instance_id not in SHELL_IDS.values()
        assert not meshes_intersect(target, _world_mesh(prop.mesh, prop.world_from_object))
    hall_x, hall_y, _ = shell.size
    assert hall_x >= 10 and hall_y >= 8  # a hall, larger than any room


# ------------------------------------------------------------------------------------------- study stages


def _covering_models(library: dict) -> list[str]:
    """One furniture model per placement rule (host furniture, surface, wall, ceiling, plain floor)."""
    from synthleak.scene.plan import is_prop, model_offers_support

    ids = sorted(m for m in library if not is_prop(library[m]))
    hosts = [m for m in ids if model_offers_support(library[m])]
    groups = [
        hosts,
        [m for m in ids if library[m].support == "surface"],
        [m for m in ids if library[m].support == "wall"],
        [m for m in ids if library[m].support == "ceiling"],
        [m for m in ids if library[m].support == "floor" and m not in hosts],
    ]
    picks = [g[0] for g in groups if g]
    return picks if len(picks) >= 3 else ids[:4]


@pytest.fixture(scope="module")
def tiny_config(library: dict):
    models = _covering_models(library)
    scenes = {
        "rooms": 2,
        "objects_per_room": [3, 4],
        "distinct_objects": len(models),
        "models": models,
        "lights_per_room": [2, 3],
    }
    return config_from_dict({"name": "scene-tiny", "seed": 21, "scenes": scenes})


@pytest.fixture(scope="module")
def stages(tiny_config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from synthleak.scene.generate import write_study_stages

    out = tmp_path_factory.mktemp("stages_a")
    write_study_stages(tiny_config, out, progress=False)
    return out


def test_study_stages_layout_and_contract(stages: Path) -> None:
    from synthleak.scene.usd_read import read_scene_spec

    index = json.loads((stages / "index.json").read_text())
    assert index["seed"] == 21 and len(index["rooms"]) == 2
    for room in index["rooms"]:
        assert (stages / room["stage"]).is_file() and room["name"] == Path(room["stage"]).stem
        spec = read_scene_spec(stages / room["stage"])
        assert spec.kind == "room" and spec.target_instance_id is None
        supported = {int(k): v for k, v in spec.metadata["supported_by"].items()}
        _check_room(spec.objects, spec.room_size, supported)
        placed = {o.instance_id: o.model_id for o in spec.objects if o.role == "object"}
        assert placed == {o["instance_id"]: o["model_id"] for o in room["objects"]}
        assert 2 <= len(spec.lights) <= 3 and spec.ambient > 0
        for obj in room["objects"]:
            att = next(a for a in index["attacker_objects"] if a["id"] == obj["attacker_object"])
            assert att["present_in"][room["name"]] == obj["instance_id"]
    for att in index["attacker_objects"]:
        spec = read_scene_spec(stages / att["stage"])
        assert att["stage"] == f"attacker_{att['id']}.usda"
        assert spec.kind == "attacker" and spec.target_instance_id == att["target_instance_id"] == 100
        target = next(o for o in spec.objects if o.instance_id == 100)
        assert target.model_id == att["model_id"] and target.variant_params == att["variant"]
        assert att["variant"]["magnitude"] == 0.5
        assert sorted(o.role for o in spec.objects).count("object") == 1
        room_shells = {
            o.name for o in read_scene_spec(stages / index["rooms"][0]["stage"]).objects if o.role == "shell"
        }
        assert {o.name for o in spec.objects if o.role == "shell"} >= room_shells - {"door", "backdrop"}
        # its own photo setting, large enough that the orbit stays inside its walls
        assert att["setting"] in {k.name for k in SETTING_KINDS}
        assert min(spec.room_size[:2]) >= min_room_size(np.asarray(target.extents)) - 1e-6
    for png in (stages / "textures").iterdir():
        assert png.suffix == ".png" and len(png.stem) == 16


def test_study_stages_bit_identical_and_skip(stages: Path, tiny_config, tmp_path: Path) -> None:
    from synthleak.scene.generate import write_study_stages

    write_study_stages(tiny_config, tmp_path, progress=False)
    files_a = sorted(p.relative_to(stages) for p in stages.rglob("*") if p.is_file())
    files_b = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert files_a == files_b
    for rel in files_a:
        assert (stages / rel).read_bytes() == (tmp_path / rel).read_bytes(), rel
    # re-running skips unchanged stages (same bytes, files untouched)
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*.usda")}
    write_study_stages(tiny_config, tmp_path, progress=False)
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("*.usda")} == stamps
    assert (tmp_path / "index.json").read_bytes() == (stages / "index.json").read_bytes()
    # a magnitude override changes the attacker variants only
    write_study_stages(
        tiny_config, tmp_path, attacker_magnitude=0.9, attacker_kinds=["scale"], progress=False
    )
    index = json.loads((tmp_path / "index.json").read_text())
    assert all(
        a["variant"]["magnitude"] == 0.9 and a["variant"]["kinds"] == ["scale"]
        for a in index["attacker_objects"]
    )
    for room in index["rooms"]:
        assert (tmp_path / room["stage"]).read_bytes() == (stages / room["stage"]).read_bytes()
