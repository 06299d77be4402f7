"""What a scene holds, read once per operation: every mesh that renders (scene objects, collection
and geometry-nodes instances, each with its own world matrix, a shared mesh read once), the lamps
and the world."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ovrad_addon import names
from . import mesh_reader, scene_io, world

_IDENTITY = np.eye(4)


@dataclass(frozen=True)
class MeshItem:
    """One mesh as it renders.

    name: the object's name, or "instancer > object #k" for an instance (messages, Surfaces);
    obj: the original object (for an instance: the instanced object, whose settings it takes);
    instance: True when it exists only as an instance (it can have no atlas of its own);
    local: its evaluated mesh in its own space, one MeshData shared by every instance of it;
    matrix (4, 4) float64: where this instance puts it.
    """

    name: str
    obj: object
    instance: bool
    local: mesh_reader.MeshData
    matrix: np.ndarray

    def data(self) -> mesh_reader.MeshData:
        """The mesh in world space."""
        return mesh_reader.placed(self.local, self.matrix)


@dataclass
class SceneModel:
    """Everything of a scene that takes part in the light (what Cycles renders).

    items: meshes and instances; lamps: engine Lamps; world: the world's light (ovrad_addon.Sky,
    None: none); warnings: what was read approximately.
    """

    items: list[MeshItem]
    lamps: tuple
    world: object
    warnings: list[str] = field(default_factory=list)

    def item_of(self, obj) -> MeshItem | None:
        """The scene object's own (non-instance) item, None if it does not render."""
        return next((it for it in self.items if not it.instance and it.obj == obj), None)

    def others(self, objects) -> list[MeshItem]:
        """Every item but the own ones of `objects` (instances of them included)."""
        chosen = {o.name for o in objects}
        return [it for it in self.items if it.instance or it.obj.name not in chosen]


def renders(obj) -> bool:
    """Whether Cycles renders the object: not disabled for renders, itself or in every collection
    holding it (the viewport's eye and monitor icons do not matter to a render)."""
    if obj.hide_render:
        return False
    colls = obj.users_collection
    return not colls or any(not c.hide_render for c in colls)


def _is_atlas(obj) -> bool:
    return obj is not None and names.PROP_SOURCE in obj


class MeshCache:
    """Reads each evaluated mesh once (keyed by its data and material slots)."""

    def __init__(self):
        self.cache: dict = {}

    def local(self, ev) -> mesh_reader.MeshData:
        slots = tuple(s.material.name if s.material else "" for s in ev.material_slots)
        key = (ev.data.as_pointer(), slots)
        if key not in self.cache:
            self.cache[key] = mesh_reader.read_evaluated(ev, matrix_world=_IDENTITY, all_uvs=True)
        return self.cache[key]


def object_item(obj, depsgraph, reader: MeshCache | None = None) -> MeshItem:
    """A scene object's own item, read through the depsgraph whether it renders or not."""
    ev = obj.evaluated_get(depsgraph)
    local = (reader or MeshCache()).local(ev)
    return MeshItem(obj.name, obj, False, local, np.array(ev.matrix_world, np.float64))


def rendered_meshes(depsgraph) -> list[MeshItem]:
    """Every mesh that renders: the depsgraph's object instances (scene objects, collection
    instances, geometry-nodes instances) whose object and instancer render, and the scene's
    meshes the viewport depsgraph drops because they are hidden in the viewport only (Cycles
    renders them). Atlas objects are left out."""
    reader, items, seen, counts = MeshCache(), [], set(), {}
    for inst in depsgraph.object_instances:
        ev = inst.object
        if ev.type != "MESH":
            continue
        orig = ev.original
        if inst.is_instance:
            parent = inst.parent.original if inst.parent is not None else None
            if _is_atlas(orig) or _is_atlas(parent) or orig.hide_render or (parent and not renders(parent)):
                continue
            label = f"{parent.name if parent else '?'} > {orig.name}"
            k = counts[label] = counts.get(label, -1) + 1
            # Instance objects are only valid during the iteration: read (or reuse) the mesh now.
            items.append(MeshItem(f"{label} #{k}", orig, True, reader.local(ev), np.array(inst.matrix_world)))
            continue
        seen.add(orig.name)
        if _is_atlas(orig) or not renders(orig):
            continue
        if orig.instance_type in ("VERTS", "FACES") and not orig.show_instancer_for_render:
            continue
        items.append(MeshItem(orig.name, orig, False, reader.local(ev), np.array(ev.matrix_world)))
    for obj in depsgraph.view_layer.objects:
        if obj.type == "MESH" and obj.name not in seen and not _is_atlas(obj) and renders(obj):
            items.append(object_item(obj, depsgraph, reader))
    return items


def read_model(depsgraph, scene) -> SceneModel:
    """The scene's model (meshes and instances, lamps, world), read once."""
    warnings: list[str] = []
    lamps = scene_io.read_lamps(depsgraph, warnings)
    sky = world.read_world(scene, warnings)
    return SceneModel(rendered_meshes(depsgraph), lamps, sky, warnings)
