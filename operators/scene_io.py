"""The scene's meshes as engine arrays: the scene model's items (scene_model.py: meshes, lamps,
world) in world space with their material colours and albedo textures, as one Surfaces."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..ovrad_addon import OvradError, Surfaces, names
from . import materials, scene_model
from .surface_tables import ColourTable, albedo_table, coverage_table, merged_colours


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
    (T, 3), emission (T, 3); textures: (image name, pixels, whether sRGB-encoded) of its albedo
    maps, image_of (T,) the map of each triangle (-1: none) and uv (T, 3, 2) (None when no triangle
    has a map); corners (T, 3, 3) the painted colour at each triangle corner, NaN where not painted
    (None: nowhere); opacity (T,), alpha_maps (image name, alpha (h, w)), alpha_of (T,), alpha_uv
    (T, 3, 2): its alpha, as textures; emitted: its emitted colour where that varies, as
    ColourTable (None: constant everywhere)."""

    vertices: np.ndarray
    triangles: np.ndarray
    reflectance: np.ndarray
    emission: np.ndarray
    textures: list = field(default_factory=list)
    image_of: np.ndarray | None = None
    uv: np.ndarray | None = None
    tint: np.ndarray | None = None
    corners: np.ndarray | None = None
    opacity: np.ndarray | None = None
    alpha_maps: list = field(default_factory=list)
    alpha_of: np.ndarray | None = None
    alpha_uv: np.ndarray | None = None
    bake_weight: np.ndarray | None = None  # (T,) the share of its diffuse light a bake reports
    emitted: ColourTable | None = None


def _read_mesh(data, warnings: list[str], cache: dict) -> _Colors:
    """Albedo and emission of one mesh (MeshData, in its own space) from its materials; the
    triangles of a material with an image texture get that map."""
    lights = [_material(mat, warnings, cache) for mat in data.materials] or [_material(None, warnings, cache)]
    slot = np.clip(data.material_index, 0, len(lights) - 1)
    out = _Colors(
        np.array([m.reflectance for m in lights])[slot], np.array([m.emission for m in lights])[slot]
    )
    out.bake_weight = np.array([m.bake_weight for m in lights], np.float64)[slot]
    out.opacity_of = {k: m.alpha.constant for k, m in enumerate(lights)}
    for k, m in enumerate(lights):
        if not np.any(slot == k):
            continue
        name = getattr(data.materials[k], "name", "?") if k < len(data.materials) else "?"
        if m.emitted is not None:
            lacks = _lacks(data, m.emitted.texture, m.emitted.paint)
            if lacks is None:
                out.emitting.append((k, m.emitted))
            else:  # its material's mean emission stands
                warnings.append(
                    f"a mesh with material '{name}' has no {lacks} for its emission; "
                    "it emits its material's mean"
                )
        # the texture's tint where its map is used, else on the paint; the map's mean where unusable
        no_uv = None if m.texture is None else _lacks(data, m.texture, None)
        textured = m.texture is not None and no_uv is None
        if textured:
            out.tints[k] = m.tint
            out.textured.append((k, m.texture))
        elif no_uv is not None:
            warnings.append(
                f"a mesh with material '{name}' has no {no_uv} for image '{m.texture.image}'; "
                "using the image's mean colour"
            )
        if m.paint is not None:
            lacks = _lacks(data, None, m.paint)
            if lacks is not None:
                warnings.append(
                    f"a mesh with material '{name}' has no {lacks}: its Base Color reads black there, as "
                    "Cycles renders it"
                )
            else:
                factor = np.ones(3) if textured else m.tint
                if m.texture is not None and not textured:
                    factor = m.reflectance  # tint x the image's mean colour
                out.painted.append((k, m.paint, factor))
        if m.alpha.pixels is not None:
            no_uv = _lacks(data, m.alpha, None)
            if no_uv is None:
                out.alpha_maps.append((k, m.alpha))
            else:  # its mean alpha, everywhere on the slot
                warnings.append(
                    f"a mesh with material '{name}' has no {no_uv} for alpha image '{m.alpha.image}'; "
                    "using the image's mean alpha"
                )
                out.opacity_of[k] = m.alpha.constant * float(np.mean(m.alpha.pixels))
    out.slot = slot
    return out


def _lacks(data, texture, paint) -> str | None:
    """What a mesh lacks to read a material's texture (its UV map) or paint (its colour attribute),
    as the warning names it; None where it has both."""
    if texture is not None and not data.has_uv_map(texture.uv_map):
        return f"UV map '{texture.uv_map}'" if texture.uv_map else "UV map"
    if paint is not None and data.triangle_colors(paint.attribute) is None:
        return f"colour attribute '{paint.attribute}'" if paint.attribute else "colour attribute"
    return None


def _emitted_table(data, colors: _Colors) -> ColourTable:
    """The emitted colour of a mesh's slots whose emission varies (colors.emitting), over all its
    triangles (image_of -1 and no paint elsewhere): the light's pieces are cut from it."""
    n = len(data.triangles)
    table = ColourTable([], np.full(n, -1, np.int64), np.zeros((n, 3, 2)), np.ones((n, 3)))
    for k, term in colors.emitting:
        on = colors.slot == k
        table.tint[on] = term.tint
        if term.texture is not None:
            table.image_of[on] = len(table.textures)
            table.uv[on] = data.triangle_uvs(term.texture.uv_map)[on]
            table.textures.append((term.texture.image, *_engine_image(term.texture)))
        if term.paint is not None:
            if table.corners is None:
                table.corners = np.full((n, 3, 3), np.nan)
            table.corners[on] = term.paint.colours(data.triangle_colors(term.paint.attribute)[on])
    return table


@dataclass
class _Colors:
    """reflectance (T, 3) and emission (T, 3) of a mesh's triangles; textured: (material slot,
    MaterialTexture) of its image-textured slots that have UVs; painted: (material slot, colour
    MaterialPaint, factor (3,)) of its painted slots whose mesh has that attribute; tints: the
    factor on the map of each textured slot; emitting: (material slot, ColourTerm) of its slots
    whose emission colour varies; slot (T,) each triangle's slot."""

    reflectance: np.ndarray
    emission: np.ndarray
    textured: list = field(default_factory=list)
    painted: list = field(default_factory=list)
    tints: dict = field(default_factory=dict)
    emitting: list = field(default_factory=list)
    slot: np.ndarray | None = None
    opacity_of: dict = field(default_factory=dict)  # slot -> constant alpha (1 where absent)
    alpha_maps: list = field(default_factory=list)  # (material slot, MaterialAlpha) with a usable map
    bake_weight: np.ndarray | None = None  # (T,) materials.MaterialLight.bake_weight


def _part(data, colors: _Colors) -> _Mesh:
    """A placed mesh (world space) with its colours and, for textured slots, its UVs."""
    part = _Mesh(data.vertices, data.triangles, colors.reflectance, colors.emission)
    part.bake_weight = colors.bake_weight
    _alpha_part(part, data, colors)
    if colors.emitting:  # the engine takes their triangles' means from it (Surfaces.from_arrays)
        part.emitted = _emitted_table(data, colors)
    if colors.painted:
        part.corners = np.full((len(data.triangles), 3, 3), np.nan)
        for k, paint, factor in colors.painted:
            on = colors.slot == k
            part.corners[on] = paint.colours(data.triangle_colors(paint.attribute)[on]) * factor
    if not colors.textured:
        return part
    part.image_of = np.full(len(data.triangles), -1, np.int64)
    part.uv = np.zeros((len(data.triangles), 3, 2))
    part.tint = np.ones((len(data.triangles), 3))
    uvs = {}  # per UV map: slots sharing a map read it once
    for k, tex in colors.textured:
        on = colors.slot == k
        if tex.uv_map not in uvs:
            uvs[tex.uv_map] = data.triangle_uvs(tex.uv_map)
        part.image_of[on] = len(part.textures)
        part.uv[on] = uvs[tex.uv_map][on]
        part.tint[on] = colors.tints.get(k, 1.0)
        part.textures.append((tex.image, *_engine_image(tex)))
    return part


def _alpha_part(part: _Mesh, data, colors: _Colors) -> None:
    """A placed mesh's alpha: each triangle's constant, and its map and UVs where it has one."""
    part.opacity = np.array([colors.opacity_of[k] for k in range(len(colors.opacity_of))])[colors.slot]
    if not colors.alpha_maps:
        return
    part.alpha_of = np.full(len(data.triangles), -1, np.int64)
    part.alpha_uv = np.zeros((len(data.triangles), 3, 2))
    for k, alpha in colors.alpha_maps:
        on = colors.slot == k
        part.alpha_of[on] = len(part.alpha_maps)
        part.alpha_uv[on] = data.triangle_uvs(alpha.uv_map)[on]
        part.alpha_maps.append((alpha.image, alpha.pixels))


def _engine_image(tex) -> tuple[np.ndarray, bool]:
    """(the pixels the engine samples, whether they are sRGB-encoded) of a MaterialTexture: an
    8-bit sRGB image's stored values, decoded after interpolation as Cycles does; else linear."""
    return (tex.pixels, False) if tex.encoded is None else (tex.encoded, True)


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


def default_occluders(context, receivers, model=None) -> list:
    """Every other mesh and instance that renders (scene_model.MeshItem): it gets no patches of
    the receivers' own, but hides, bounds space and (in a solve) reflects light."""
    if model is None:
        model = scene_model.read_model(context.evaluated_depsgraph_get(), context.scene)
    return model.others(receivers)


def read_scene(depsgraph, receivers, occluders=(), model=None) -> SceneMeshes:
    """Read receiver meshes (they get patches) and the occluders (objects or scene_model
    MeshItems) into one Surfaces; receivers are read from `model` when it holds them.

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
            part = _part(it.data(), colors[id(it.local)])
            if not np.all(np.isfinite(part.vertices)):
                # one broken object never stops the others: it neither gets light nor blocks it
                warnings.append(
                    f"'{it.name}' has NaN or infinite vertex coordinates; skipped as "
                    f"{'a receiver' if role == 'receiver' else 'an occluder'} (fix the mesh or leave it out)"
                )
                continue
            items.append(it)
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
        object_names=[it.name for it in items],
        receiver=np.arange(len(items)) < n_receivers,
        albedo=albedo_table(parts),
        coverage=coverage_table(parts),
        emitted=merged_colours([p.emitted for p in parts], parts),
        bake_weight=np.concatenate(
            [np.ones(len(p.triangles)) if p.bake_weight is None else p.bake_weight for p in parts]
        ),
    )
    # The same material on many objects would repeat its warning.
    objects = [it.obj for it in items]
    return SceneMeshes(surfaces, objects, n_receivers, list(dict.fromkeys(warnings)), items)
