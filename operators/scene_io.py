"""Reading the Blender scene into engine arrays: evaluated meshes in world space, material colours,
lamps and the world."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.lights import Lamp, lamp_area
from ..ovrad_addon.surfaces import Surfaces

# What a surface gets when its material cannot be read (and what Blender renders without a material).
DEFAULT_REFLECTANCE = (0.8, 0.8, 0.8)


@dataclass
class SceneMeshes:
    """Surfaces with the scene items they came from.

    items[i] (a scene_model.MeshItem) gave surfaces.object_names[i] and objects[i] is its object
    (for an instance, the instanced object); the first n_receivers are receivers (they get
    patches), the rest are everything else that renders (they occlude and, in a solve, reflect).
    """

    surfaces: Surfaces
    objects: list
    n_receivers: int
    warnings: list[str] = field(default_factory=list)
    items: list = field(default_factory=list)


def _constant(socket, what: str, material, warnings: list[str]):
    """A socket's value if nothing is plugged into it, else None (and a warning)."""
    if socket.is_linked:
        warnings.append(f"material '{material.name}': {what} is driven by nodes; using grey 0.8 instead")
        return None
    return socket.default_value


def _surface_shader(material):
    tree = material.node_tree
    if tree is None:
        return None
    out = tree.get_output_node("CYCLES") or tree.get_output_node("ALL")
    if out is None or not out.inputs["Surface"].is_linked:
        return None
    node = out.inputs["Surface"].links[0].from_node
    while node.bl_idname == "NodeReroute" and node.inputs[0].is_linked:
        node = node.inputs[0].links[0].from_node
    return node


def material_colors(material, warnings: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """(reflectance (3,), emitted radiance (3,)) of a material, as Cycles would see its diffuse part.

    Read: Principled BSDF (Base Color; Emission Color x Strength), Diffuse BSDF (Color), Emission
    (Color x Strength, no reflection). Anything else gives grey 0.8 and a warning naming the material.
    """
    grey, black = np.array(DEFAULT_REFLECTANCE), np.zeros(3)
    if material is None:
        return grey, black
    legacy = bpy.app.version < (5, 0, 0) and not material.use_nodes
    if material.node_tree is None or legacy:
        # A material without nodes renders as a diffuse surface of its viewport colour.
        return np.array(material.diffuse_color[:3], float), black
    node = _surface_shader(material)
    kind = node.bl_idname if node is not None else None
    rho, em = grey, black
    if kind == "ShaderNodeBsdfPrincipled":
        base = _constant(node.inputs["Base Color"], "Base Color", material, warnings)
        rho = grey if base is None else np.array(base[:3], float)
        col = _constant(node.inputs["Emission Color"], "Emission Color", material, warnings)
        strength = _constant(node.inputs["Emission Strength"], "Emission Strength", material, warnings)
        if col is not None and strength is not None:
            em = np.array(col[:3], float) * float(strength)
    elif kind == "ShaderNodeBsdfDiffuse":
        base = _constant(node.inputs["Color"], "Color", material, warnings)
        rho = grey if base is None else np.array(base[:3], float)
    elif kind == "ShaderNodeEmission":
        rho = np.zeros(3)
        col = _constant(node.inputs["Color"], "Emission Color", material, warnings)
        strength = _constant(node.inputs["Strength"], "Emission Strength", material, warnings)
        if col is not None and strength is not None:
            em = np.array(col[:3], float) * float(strength)
    else:
        what = "no surface shader" if node is None else f"a {node.bl_label} shader"
        warnings.append(
            f"material '{material.name}' has {what}; using grey 0.8 (read: Principled, Diffuse, Emission)"
        )
    if rho.min() < 0.0 or rho.max() > 1.0:
        warnings.append(
            f"material '{material.name}': reflectance {tuple(np.round(rho, 3))} clamped to [0, 1]"
        )
        rho = np.clip(rho, 0.0, 1.0)
    return rho, np.maximum(em, 0.0)


def _read_mesh(data, warnings: list[str]):
    """(reflectance (T, 3), emission (T, 3)) of one mesh (MeshData) from its materials."""
    colors = []
    for mat in data.materials or (None,):
        try:
            colors.append(material_colors(mat, warnings))
        except (KeyError, AttributeError, TypeError, ValueError) as e:
            # A node setup this reader did not foresee: the mesh still takes part, in grey.
            warnings.append(
                f"material '{getattr(mat, 'name', mat)}' could not be read ({e}); using grey 0.8 "
                "(use a Principled, Diffuse or Emission shader)"
            )
            colors.append((np.array(DEFAULT_REFLECTANCE), np.zeros(3)))
    slot = np.clip(data.material_index, 0, len(colors) - 1)
    rho = np.array([c[0] for c in colors])[slot]
    em = np.array([c[1] for c in colors])[slot]
    return rho, em


def default_occluders(context, receivers, model=None) -> list:
    """Every other mesh and instance that renders (scene_model.MeshItem): it gets no patches of
    the receivers' own, but hides, bounds space and (in a solve) reflects light."""
    from . import scene_model

    if model is None:
        model = scene_model.read_model(context.evaluated_depsgraph_get(), context.scene)
    return model.others(receivers)


def read_scene(depsgraph, receivers, occluders=(), model=None) -> SceneMeshes:
    """Read receiver meshes (they get patches) and the occluders (objects or scene_model
    MeshItems) into one Surfaces; receivers are read from `model` when it holds them.

    Non-mesh objects, atlas objects and meshes without faces are skipped with a warning; raises
    OvradError when no receiver is left.
    """
    from . import scene_model

    warnings: list[str] = []
    kept = []
    for obj in receivers:
        if obj.type != "MESH":
            warnings.append(f"'{obj.name}' is not a mesh ({obj.type.lower()}); skipped")
        elif names.PROP_SOURCE in obj:
            warnings.append(f"'{obj.name}' is an ovrad atlas; skipped")
        else:
            kept.append(obj)
    if not kept:
        raise OvradError(
            "no mesh to cover with patches: select at least one mesh object"
            if not receivers
            else "none of the selected objects is a mesh: select at least one mesh object"
        )
    reader = scene_model.MeshCache()

    def item(obj):
        if isinstance(obj, scene_model.MeshItem):
            return obj
        own = model.item_of(obj) if model is not None else None
        return own or scene_model.object_item(obj, depsgraph, reader)

    occluder_items = [item(o) for o in occluders if isinstance(o, scene_model.MeshItem) or o.type == "MESH"]
    items, parts, colors = [], [], {}
    n_receivers = 0
    for role, group in (("receiver", [item(o) for o in kept]), ("occluder", occluder_items)):
        for it in group:
            if len(it.local.triangles) == 0:
                if role == "receiver":
                    warnings.append(f"'{it.name}' has no faces; skipped (give it faces or leave it out)")
                continue
            if id(it.local) not in colors:  # a shared mesh's materials are read once
                colors[id(it.local)] = _read_mesh(it.local, warnings)
            data = it.data()
            items.append(it)
            parts.append((data.vertices, data.triangles, *colors[id(it.local)]))
            n_receivers += role == "receiver"
    if n_receivers == 0:
        raise OvradError("the selected meshes have no faces: select at least one mesh with faces")
    base = np.cumsum([0] + [len(p[0]) for p in parts])[:-1]
    surfaces = Surfaces.from_arrays(
        vertices=np.concatenate([p[0] for p in parts]),
        triangles=np.concatenate([p[1] + b for p, b in zip(parts, base, strict=True)]),
        object_index=np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)]),
        reflectance=np.concatenate([p[2] for p in parts]),
        emission=np.concatenate([p[3] for p in parts]),
        object_names=[it.name for it in items],
        receiver=np.arange(len(items)) < n_receivers,
    )
    # The same material on many objects would repeat its warning.
    objects = [it.obj for it in items]
    return SceneMeshes(surfaces, objects, n_receivers, list(dict.fromkeys(warnings)), items)


def _light_power(light, world_area: float, radius_area: float) -> float:
    """Blender's power (or sun strength) as Cycles applies it: exposure, and the size factor of
    lamps whose 'Normalize' is off (their power then grows with their area)."""
    power = float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0))
    if not getattr(light, "normalize", True):
        power *= world_area if light.type == "AREA" else radius_area
    return power


def _light_color(light) -> tuple:
    color = np.array(light.color[:3], float)
    if getattr(light, "use_temperature", False):
        color = color * np.array(light.temperature_color[:3], float)
    return tuple(color)


def read_lamps(depsgraph, warnings: list[str] | None = None) -> tuple[Lamp, ...]:
    """Lamps (engine Lamp, world space, Cycles units) of every light object in the view layer that renders.

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
        light = ev.data
        m = np.array(ev.matrix_world, dtype=np.float64)
        axes = m[:3, :3]
        scale = np.linalg.norm(axes, axis=0)
        if np.any(scale <= 0):
            warnings.append(f"lamp '{obj.name}' has zero scale; skipped")
            continue
        position = tuple(m[:3, 3])
        direction = tuple(-axes[:, 2] / scale[2])
        tangent = tuple(axes[:, 0] / scale[0])
        kind = light.type
        radius = float(getattr(light, "shadow_soft_size", 0.0))
        if getattr(light, "use_nodes", False):
            warnings.append(f"lamp '{obj.name}': its node tree is ignored (only power and colour are read)")
        common = dict(position=position, direction=direction, tangent=tangent, color=_light_color(light))
        if kind in ("POINT", "SPOT"):
            power = _light_power(light, 0.0, np.pi * radius * radius if radius > 0 else 1.0)
            if kind == "POINT":
                lamps.append(Lamp("POINT", power=power, radius=radius, **common))
                continue
            if not np.isclose(scale[0], scale[1], rtol=1e-4):
                warnings.append(f"spot '{obj.name}' has a non-uniform scale: its cone is taken as round")
            lamps.append(
                Lamp(
                    "SPOT",
                    power=power,
                    spot_size=float(light.spot_size),
                    spot_blend=float(light.spot_blend),
                    radius=radius,
                    **common,
                )
            )
        elif kind == "SUN":
            angle = float(getattr(light, "angle", 0.0))
            disk = np.pi * np.tan(0.5 * angle) ** 2 if angle > 0 else 1.0
            lamps.append(Lamp("SUN", power=_light_power(light, 0.0, disk), angle=angle, **common))
        elif kind == "AREA":
            shape = light.shape
            size_x = float(light.size) * scale[0]
            size_y = float(light.size_y if shape in ("RECTANGLE", "ELLIPSE") else light.size) * scale[1]
            # Scaled objects turn squares and disks into rectangles and ellipses.
            if shape in ("SQUARE", "DISK") and not np.isclose(size_x, size_y, rtol=1e-6):
                shape = "RECTANGLE" if shape == "SQUARE" else "ELLIPSE"
            spread = float(getattr(light, "spread", np.pi))
            if spread < np.pi - 1e-4:
                warnings.append(
                    f"area lamp '{obj.name}' has spread {np.degrees(spread):.0f} degrees: taken as 180 "
                    "(a plain diffuse emitter)"
                )
            area = lamp_area(shape, size_x, size_y)
            lamps.append(
                Lamp(
                    "AREA",
                    power=_light_power(light, area, 1.0),
                    shape=shape,
                    size_x=size_x,
                    size_y=size_y,
                    **common,
                )
            )
        else:
            warnings.append(f"lamp '{obj.name}' of type {kind.lower()} is not supported; skipped")
    return tuple(lamps)


def read_world(scene) -> np.ndarray | None:
    """The world's constant light (3,) = Background colour x strength; zeros without a world.

    None when the world is not a plain Background with nothing linked into it (a sky texture,
    an HDRI, nodes driving it): then it cannot be read as one colour.
    """
    world = scene.world
    if world is None:
        return np.zeros(3)
    legacy = bpy.app.version < (5, 0, 0) and not world.use_nodes
    if world.node_tree is None or legacy:
        return np.array(world.color[:3], float)
    tree = world.node_tree
    out = tree.get_output_node("CYCLES") or tree.get_output_node("ALL")
    if out is None or not out.inputs["Surface"].is_linked:
        return np.zeros(3)
    node = out.inputs["Surface"].links[0].from_node
    if node.bl_idname != "ShaderNodeBackground" or any(s.is_linked for s in node.inputs):
        return None
    return np.array(node.inputs["Color"].default_value[:3], float) * float(
        node.inputs["Strength"].default_value
    )
