"""Reading the Blender scene into engine arrays: evaluated meshes in world space, material colours,
lamps and the world."""

from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.albedo import TextureAlbedo
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.lights import Lamp, lamp_area
from ..ovrad_addon.surfaces import Surfaces
from . import materials, mesh_reader


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


@dataclass
class _Mesh:
    """One object's arrays for read_scene: vertices (V, 3) world, triangles (T, 3), reflectance
    (T, 3), emission (T, 3); textures: (image name, pixels) of its albedo maps, image_of (T,) the
    map of each triangle (-1: none) and uv (T, 3, 2) (None when no triangle has a map)."""

    vertices: np.ndarray
    triangles: np.ndarray
    reflectance: np.ndarray
    emission: np.ndarray
    textures: list = field(default_factory=list)
    image_of: np.ndarray | None = None
    uv: np.ndarray | None = None


def _read_mesh(obj, depsgraph, warnings: list[str], cache: dict | None = None) -> _Mesh:
    """An object's evaluated mesh in world space with its materials' albedo and emission; the
    triangles of a material with an image texture get that map, sampled through its UV map."""
    cache = {} if cache is None else cache
    data = mesh_reader.read_object(obj, depsgraph)
    lights = [_material(mat, warnings, cache) for mat in data.materials] or [_material(None, warnings, cache)]
    slot = np.clip(data.material_index, 0, len(lights) - 1)
    rho = np.array([m.reflectance for m in lights])[slot]
    em = np.array([m.emission for m in lights])[slot]
    part = _Mesh(data.vertices, data.triangles, rho, em)
    textured = [k for k, m in enumerate(lights) if m.texture is not None and np.any(slot == k)]
    if not textured:
        return part
    part.image_of = np.full(len(slot), -1, np.int64)
    part.uv = np.zeros((len(slot), 3, 2))
    uvs: dict[str, np.ndarray | None] = {}
    for k in textured:
        tex = lights[k].texture
        if tex.uv_map not in uvs:
            try:
                uvs[tex.uv_map] = mesh_reader.read_object(obj, depsgraph, tex.uv_map).uv
            except OvradError:
                uvs[tex.uv_map] = None
        uv = uvs[tex.uv_map]
        if uv is None:
            which = f"UV map '{tex.uv_map}'" if tex.uv_map else "a UV map"
            warnings.append(
                f"'{obj.name}' has no {which} for image '{tex.image}' of material "
                f"'{data.materials[k].name}'; using the image's mean colour"
            )
            continue
        on = slot == k
        part.image_of[on] = len(part.textures)
        part.uv[on] = uv[on]
        part.textures.append((tex.image, tex.pixels))
    return part


def _material(material, warnings: list[str], cache: dict) -> materials.MaterialLight:
    """read_material once per material of a scene read (an image's pixels are read once)."""
    key = None if material is None else material.name
    if key not in cache:
        cache[key] = materials.read_material(material, warnings)
    return cache[key]


def _albedo(parts: list[_Mesh]) -> TextureAlbedo | None:
    """One TextureAlbedo over the triangles of all parts, images shared by name; None if no map."""
    if not any(p.textures for p in parts):
        return None
    images: dict[str, int] = {}
    pixels = []
    image_of, uv = [], []
    for p in parts:
        n = len(p.triangles)
        if not p.textures:
            image_of.append(np.full(n, -1, np.int64))
            uv.append(np.zeros((n, 3, 2)))
            continue
        remap = []
        for name, px in p.textures:
            if name not in images:
                images[name] = len(pixels)
                pixels.append(px)
            remap.append(images[name])
        remap = np.array(remap + [-1], np.int64)  # -1 -> -1 (the last entry)
        image_of.append(remap[p.image_of])
        uv.append(p.uv)
    image_of = np.concatenate(image_of)
    return TextureAlbedo(
        images=tuple(pixels),
        image_of=image_of,
        uv=np.concatenate(uv),
        tint=np.ones((len(image_of), 3)),
    )


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
    cache: dict = {}
    for role, group in (("receiver", kept), ("occluder", [o for o in occluders if o.type == "MESH"])):
        for obj in group:
            part = _read_mesh(obj, depsgraph, warnings, cache)
            if len(part.triangles) == 0:
                if role == "receiver":
                    warnings.append(f"'{obj.name}' has no faces; skipped")
                continue
            objects.append(obj)
            parts.append(part)
            n_receivers += role == "receiver"
    if n_receivers == 0:
        raise OvradError("the selected meshes have no faces: select at least one mesh with faces")
    base = np.cumsum([0] + [len(p.vertices) for p in parts])[:-1]
    surfaces = Surfaces.from_arrays(
        vertices=np.concatenate([p.vertices for p in parts]),
        triangles=np.concatenate([p.triangles + b for p, b in zip(parts, base, strict=True)]),
        object_index=np.concatenate([np.full(len(p.triangles), i) for i, p in enumerate(parts)]),
        reflectance=np.concatenate([p.reflectance for p in parts]),
        emission=np.concatenate([p.emission for p in parts]),
        object_names=[o.name for o in objects],
        receiver=np.arange(len(objects)) < n_receivers,
        albedo=_albedo(parts),
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
