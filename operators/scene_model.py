"""What a scene holds, read once per operation: every mesh that renders (scene objects, collection
and geometry-nodes instances, each with its own world matrix, a shared mesh read once), the lamps
(read here, in Cycles' units) and the world (world.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ovrad_addon import Lamp, lamp_area, names
from . import compat, mesh_reader, world

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
    lamps = read_lamps(depsgraph, warnings)
    sky = world.read_world(scene, warnings)
    return SceneModel(rendered_meshes(depsgraph), lamps, sky, warnings)


def _light_power(light, world_area: float, radius_area: float) -> float:
    """Blender's power (or sun strength) as Cycles applies it: exposure, and the size factor of
    lamps whose 'Normalize' is off (their power then grows with their area)."""
    power = float(light.energy) * 2.0 ** compat.light_exposure(light)
    if not compat.light_normalized(light):
        power *= world_area if light.type == "AREA" else radius_area
    return power


def _light_color(light) -> tuple:
    color = np.array(light.color[:3], float)
    if (blackbody := compat.light_temperature_color(light)) is not None:
        color = color * np.array(blackbody, float)
    return tuple(color)


def read_lamps(depsgraph, warnings: list[str] | None = None) -> tuple[Lamp, ...]:
    """Lamps (engine Lamp, world space, Cycles units) of every light that renders: the view layer's
    light objects and the lights inside collection instances (each at its instance's matrix).

    Power is W (point, spot, area) or W/m^2 (sun) times 2^exposure; colour times the blackbody
    colour when Temperature is used; area sizes are scaled by the object's scale. A point or spot
    radius (a sphere) and a sun's angle (a disk) give soft shadows. What the engine does not model
    (an area lamp's spread, light node trees, non-uniform spot scale) is approximated and named in
    `warnings`.
    """
    warnings = [] if warnings is None else warnings
    lamps = []
    for obj in depsgraph.view_layer.objects:
        # As for meshes: what renders counts (a lamp hidden only in the viewport still lights the render).
        if obj.type != "LIGHT" or obj.hide_render:
            continue
        ev = obj.evaluated_get(depsgraph)
        lamps += _lamp(obj.name, ev.data, np.array(ev.matrix_world, dtype=np.float64), warnings)
    for inst in depsgraph.object_instances:
        if not inst.is_instance or inst.object.type != "LIGHT":
            continue
        orig = inst.object.original
        parent = inst.parent.original if inst.parent is not None else None
        if orig.hide_render or (parent is not None and not renders(parent)):
            continue
        name = f"{parent.name if parent else '?'} > {orig.name}"
        lamps += _lamp(name, inst.object.data, np.array(inst.matrix_world, dtype=np.float64), warnings)
    return tuple(lamps)


def _lamp(name: str, light, m: np.ndarray, warnings: list[str]) -> list[Lamp]:
    """One light at world matrix m as engine lamps (none, with a warning, if it cannot be used)."""
    axes = m[:3, :3]
    scale = np.linalg.norm(axes, axis=0)
    if np.any(scale <= 0):
        warnings.append(f"lamp '{name}' has zero scale; skipped")
        return []
    position = tuple(m[:3, 3])
    direction = tuple(-axes[:, 2] / scale[2])
    tangent = tuple(axes[:, 0] / scale[0])
    kind = light.type
    radius = float(getattr(light, "shadow_soft_size", 0.0))
    if compat.light_uses_nodes(light):
        warnings.append(f"lamp '{name}': its node tree is ignored (only power and colour are read)")
    common = dict(position=position, direction=direction, tangent=tangent, color=_light_color(light))
    if kind in ("POINT", "SPOT"):
        power = _light_power(light, 0.0, np.pi * radius * radius if radius > 0 else 1.0)
        if kind == "POINT":
            return [Lamp("POINT", power=power, radius=radius, **common)]
        if not np.isclose(scale[0], scale[1], rtol=1e-4):
            warnings.append(f"spot '{name}' has a non-uniform scale: its cone is taken as round")
        return [
            Lamp(
                "SPOT",
                power=power,
                spot_size=float(light.spot_size),
                spot_blend=float(light.spot_blend),
                radius=radius,
                **common,
            )
        ]
    if kind == "SUN":
        angle = float(getattr(light, "angle", 0.0))
        disk = np.pi * np.tan(0.5 * angle) ** 2 if angle > 0 else 1.0
        return [Lamp("SUN", power=_light_power(light, 0.0, disk), angle=angle, **common)]
    if kind == "AREA":
        shape = light.shape
        size_x = float(light.size) * scale[0]
        size_y = float(light.size_y if shape in ("RECTANGLE", "ELLIPSE") else light.size) * scale[1]
        # Scaled objects turn squares and disks into rectangles and ellipses.
        if shape in ("SQUARE", "DISK") and not np.isclose(size_x, size_y, rtol=1e-6):
            shape = "RECTANGLE" if shape == "SQUARE" else "ELLIPSE"
        spread = float(getattr(light, "spread", np.pi))
        if spread < np.pi - 1e-4:
            warnings.append(
                f"area lamp '{name}' has spread {np.degrees(spread):.0f} degrees: taken as 180 "
                "(a plain diffuse emitter)"
            )
        area = lamp_area(shape, size_x, size_y)
        return [
            Lamp(
                "AREA",
                power=_light_power(light, area, 1.0),
                shape=shape,
                size_x=size_x,
                size_y=size_y,
                **common,
            )
        ]
    warnings.append(f"lamp '{name}' of type {kind.lower()} is not supported; skipped")
    return []
