"""Reading the Blender scene into engine arrays: evaluated meshes in world space, material colours
and lamps (the world: world.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.lights import Lamp, lamp_area
from ..ovrad_addon.surfaces import Surfaces
from . import mesh_reader

# What a surface gets when its material cannot be read (and what Blender renders without a material).
DEFAULT_REFLECTANCE = (0.8, 0.8, 0.8)


@dataclass
class SceneMeshes:
    """Surfaces with the Blender objects they came from.

    objects[i] is the object of surfaces.object_names[i]; the first n_receivers are receivers
    (they get patches), the rest only occlude.
    """

    surfaces: Surfaces
    objects: list
    n_receivers: int
    warnings: list[str] = field(default_factory=list)


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


def _read_mesh(obj, depsgraph, warnings: list[str]):
    """(vertices (V, 3) world, triangles (T, 3), reflectance (T, 3), emission (T, 3)) of one object."""
    data = mesh_reader.read_object(obj, depsgraph)
    colors = [material_colors(mat, warnings) for mat in data.materials] or [material_colors(None, warnings)]
    slot = np.clip(data.material_index, 0, len(colors) - 1)
    rho = np.array([c[0] for c in colors])[slot]
    em = np.array([c[1] for c in colors])[slot]
    return data.vertices, data.triangles, rho, em


def default_occluders(context, receivers) -> list:
    """Every other mesh that renders in the view layer: it gets no patches, but hides and bounds space."""
    chosen = {o.name for o in receivers}
    return [
        o
        for o in context.view_layer.objects
        if o.type == "MESH" and o.name not in chosen and names.PROP_SOURCE not in o and not o.hide_render
    ]


def read_scene(depsgraph, receivers, occluders=()) -> SceneMeshes:
    """Read receiver meshes (they get patches) and occluder meshes into one Surfaces.

    Non-mesh objects, atlas objects and meshes without faces are skipped with a warning; raises
    OvradError when no receiver is left.
    """
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
    objects, parts = [], []
    n_receivers = 0
    for role, group in (("receiver", kept), ("occluder", [o for o in occluders if o.type == "MESH"])):
        for obj in group:
            part = _read_mesh(obj, depsgraph, warnings)
            if len(part[1]) == 0:
                if role == "receiver":
                    warnings.append(f"'{obj.name}' has no faces; skipped")
                continue
            objects.append(obj)
            parts.append(part)
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
        object_names=[o.name for o in objects],
        receiver=np.arange(len(objects)) < n_receivers,
    )
    # The same material on many objects would repeat its warning.
    return SceneMeshes(surfaces, objects, n_receivers, list(dict.fromkeys(warnings)))


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
