"""Reading the Blender scene into engine arrays: evaluated meshes in world space, material colours
and lamps (the world: world.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ovrad_addon import Lamp, OvradError, Surfaces, TextureAlbedo, lamp_area, names
from . import compat, materials


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


def _read_mesh(data, warnings: list[str], cache: dict) -> _Colors:
    """Albedo and emission of one mesh (MeshData, in its own space) from its materials; the
    triangles of a material with an image texture get that map."""
    lights = [_material(mat, warnings, cache) for mat in data.materials] or [_material(None, warnings, cache)]
    slot = np.clip(data.material_index, 0, len(lights) - 1)
    out = _Colors(
        np.array([m.reflectance for m in lights])[slot], np.array([m.emission for m in lights])[slot]
    )
    for k, m in enumerate(lights):
        if m.texture is None or not np.any(slot == k):
            continue
        if not data.has_uv_map(m.texture.uv_map):
            which = f"a UV map '{m.texture.uv_map}'" if m.texture.uv_map else "a UV map"
            name = getattr(data.materials[k], "name", "?") if k < len(data.materials) else "?"
            warnings.append(
                f"a mesh with material '{name}' has no {which} for image '{m.texture.image}'; "
                "using the image's mean colour"
            )
            continue
        out.textured.append((k, m.texture))
    out.slot = slot
    return out


@dataclass
class _Colors:
    """reflectance (T, 3) and emission (T, 3) of a mesh's triangles; textured: (material slot,
    MaterialTexture) of its image-textured slots that have UVs; slot (T,) each triangle's slot."""

    reflectance: np.ndarray
    emission: np.ndarray
    textured: list = field(default_factory=list)
    slot: np.ndarray | None = None


def _part(data, colors: _Colors) -> _Mesh:
    """A placed mesh (world space) with its colours and, for textured slots, its UVs."""
    part = _Mesh(data.vertices, data.triangles, colors.reflectance, colors.emission)
    if not colors.textured:
        return part
    part.image_of = np.full(len(data.triangles), -1, np.int64)
    part.uv = np.zeros((len(data.triangles), 3, 2))
    uvs = {}  # per UV map: slots sharing a map read it once
    for k, tex in colors.textured:
        on = colors.slot == k
        if tex.uv_map not in uvs:
            uvs[tex.uv_map] = data.triangle_uvs(tex.uv_map)
        part.image_of[on] = len(part.textures)
        part.uv[on] = uvs[tex.uv_map][on]
        part.textures.append((tex.image, tex.pixels))
    return part


def _material(material, warnings: list[str], cache: dict) -> materials.MaterialLight:
    """read_material once per material of a scene read (an image's pixels are read once); a node
    setup the reader did not foresee gives the viewport colour and a warning."""
    key = None if material is None else material.name
    if key not in cache:
        try:
            cache[key] = materials.read_material(material, warnings)
        except (KeyError, AttributeError, TypeError, ValueError) as e:
            warnings.append(
                f"material '{key}' could not be read ({e}); using its viewport colour "
                "(use a Principled, Diffuse or Emission shader)"
            )
            colour = np.array(material.diffuse_color[:3], float)
            cache[key] = materials.MaterialLight(np.clip(colour, 0, 1), np.zeros(3))
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
    cache: dict = {}
    for role, group in (("receiver", [item(o) for o in kept]), ("occluder", occluder_items)):
        for it in group:
            if len(it.local.triangles) == 0:
                if role == "receiver":
                    warnings.append(f"'{it.name}' has no faces; skipped (give it faces or leave it out)")
                continue
            if id(it.local) not in colors:  # a shared mesh's materials are read once
                colors[id(it.local)] = _read_mesh(it.local, warnings, cache)
            items.append(it)
            parts.append(_part(it.data(), colors[id(it.local)]))
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
        object_names=[it.name for it in items],
        receiver=np.arange(len(items)) < n_receivers,
        albedo=_albedo(parts),
    )
    # The same material on many objects would repeat its warning.
    objects = [it.obj for it in items]
    return SceneMeshes(surfaces, objects, n_receivers, list(dict.fromkeys(warnings)), items)


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
        if orig.hide_render or (parent is not None and not _renders(parent)):
            continue
        name = f"{parent.name if parent else '?'} > {orig.name}"
        lamps += _lamp(name, inst.object.data, np.array(inst.matrix_world, dtype=np.float64), warnings)
    return tuple(lamps)


def _renders(obj) -> bool:
    """scene_model.renders (imported late: scene_model imports this module)."""
    from .scene_model import renders

    return renders(obj)


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
