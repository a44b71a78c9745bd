"""Read a stage back into a :class:`~synthleak.scene.spec.SceneSpec`: the inverse of
:func:`synthleak.scene.usd_write.write_stage` (exact transforms and attributes, object-frame meshes), built on
the stage reader :func:`synthleak.core.usd_read.read_stage`, so stages written by other tools read too."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from synthleak.assets.mesh import ObjectMesh, TexturedPart
from synthleak.core.usd_read import NS, read_stage
from synthleak.scene.spec import PlacedObject, SceneSpec


def read_scene_spec(path: Path) -> SceneSpec:
    """Read a stage back into a :class:`SceneSpec` (object-frame meshes, exact transforms and attributes)."""
    content = read_stage(path)
    objects = []
    for inst in content.instances:
        parts = []
        for p in inst.parts:
            verts = p.vertices @ p.object_from_mesh[:3, :3].T + p.object_from_mesh[:3, 3]
            texture = p.texture
            if texture is None:
                texture = np.full((1, 1, 3), np.round(np.clip(p.base_color, 0, 1) * 255), dtype=np.uint8)
            uv = p.uv if p.uv is not None else np.zeros((len(verts), 2))
            parts.append(
                TexturedPart(p.name, verts, p.faces, uv, texture, p.roughness, p.metallic, p.emissive)
            )
        objects.append(
            PlacedObject(
                instance_id=inst.instance_id,
                name=inst.text("name", inst.prim.GetName()),
                model_id=inst.text("modelId", inst.prim.GetName()),
                category=inst.text("category", "unknown"),
                symmetry=inst.text("symmetry", "none"),
                world_from_object=inst.world_from_object,
                mesh=ObjectMesh(parts),
                variant_params=inst.variant_params(content.path),
                role=inst.text("role", "object"),
                support=inst.text("support", "floor"),
                extents=inst.extents(),
            )
        )
    lights = content.lights
    data = content.data
    metadata = json.loads(data[NS + "metadata"]) if data.get(NS + "metadata") else {}
    return SceneSpec(
        name=str(data.get(NS + "name", content.path.stem)),
        kind=str(data.get(NS + "kind", "room")),
        objects=objects,
        lights=lights,
        room_size=tuple(float(v) for v in data.get(NS + "roomSize", (0.0, 0.0, 0.0))),
        seed=int(data.get(NS + "seed", 0)),
        target_instance_id=content.target_instance_id,
        ambient=content.ambient,
        metadata=metadata,
    )
