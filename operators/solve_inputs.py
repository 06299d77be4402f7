"""Solve inputs: atlas objects + their source meshes + occluders + lamps, read from bpy into plain
arrays (SolveInputs) before a solve starts, with the fingerprints the caches are keyed by."""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace

import bpy
import numpy as np

from ..ovrad_addon import names
from ..ovrad_addon.atlas import Atlas
from ..ovrad_addon.errors import OvradError
from ..ovrad_addon.lights import Lamp
from ..ovrad_addon.pipeline import SolveSettings
from ..ovrad_addon.surfaces import Surfaces
from . import attributes, properties, scene_io


@dataclass
class SolveInputs:
    """Everything the worker needs, read from bpy before it starts.

    atlas: all patches, atlas object after atlas object (atlas_names, counts); the first
    len(atlas_names) objects of surfaces are their source meshes, in the same order.
    """

    surfaces: Surfaces
    atlas: Atlas
    lamps: tuple[Lamp, ...]
    settings: SolveSettings
    atlas_names: list[str]
    counts: list[int]
    sources: list
    key: str
    warnings: list[str] = field(default_factory=list)

    def first_triangle(self, i: int) -> int:
        """Index in surfaces.triangles of receiver i's first triangle."""
        return int(np.flatnonzero(self.surfaces.object_index == i)[0])


def scene_atlases(scene) -> list[tuple]:
    """(atlas object, source mesh object) of every non-empty atlas in the scene, by atlas name."""
    found = sorted((o for o in scene.objects if attributes.is_atlas(o)), key=lambda o: o.name)
    if not found:
        raise OvradError("no atlas in the scene: select the meshes to light and press Generate Atlas first")
    pairs, seen = [], {}
    for obj in found:
        src_name = obj[names.PROP_SOURCE]
        src = bpy.data.objects.get(src_name)
        if src is None or src.type != "MESH":
            raise OvradError(
                f"the source mesh '{src_name}' of atlas '{obj.name}' is gone: generate the atlas again "
                f"or delete '{obj.name}'"
            )
        if src_name in seen:
            raise OvradError(f"'{seen[src_name]}' and '{obj.name}' are atlases of the same mesh: delete one")
        if src.name not in scene.objects:
            raise OvradError(f"the source mesh '{src_name}' of atlas '{obj.name}' is not in this scene")
        seen[src_name] = obj.name
        if attributes.patch_count(obj):
            pairs.append((obj, src))
    if not pairs:
        raise OvradError("every atlas in the scene is empty: generate the atlas again")
    return pairs


def fingerprint(surfaces: Surfaces, atlas: Atlas) -> str:
    """What the form factors depend on: world geometry, reflectances and albedo textures, receivers
    and the patches (not emission, which the engine reads at each solve, nor lamps)."""
    h = hashlib.blake2b(digest_size=20)
    arrays = (
        surfaces.vertices,
        surfaces.triangles,
        surfaces.object_index,
        surfaces.reflectance,
        surfaces.receiver,
        atlas.centers,
        atlas.normals,
        atlas.tangents,
        atlas.radii,
        atlas.shapes,
        atlas.thickness,
        atlas.min_cos,
        atlas.source_object,
    )
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
    h.update(atlas.beta.encode())
    if surfaces.albedo is not None:  # textures change the transport's rho and the first shot
        h.update(b"albedo" + surfaces.albedo.key())
    return h.hexdigest()


def light_key(surfaces: Surfaces, lamps) -> str:
    """What direct light depends on besides geometry: the lamps and every triangle's emission."""
    h = hashlib.blake2b(digest_size=20)
    h.update(repr(tuple(lamps)).encode())
    h.update(np.ascontiguousarray(surfaces.emission).tobytes())
    return h.hexdigest()


def _light_warnings(surfaces: Surfaces, lamps, scene, n_receivers: int) -> list[str]:
    """Light the engine will not see (world, emitters without atlas); raises when nothing emits."""
    out = []
    world = scene_io.read_world(scene)
    if world is None:
        out.append("the world is not a constant colour (nodes drive it): its light is ignored")
    elif world.max() > 0:
        rgb = ", ".join(f"{v:.3g}" for v in world)
        out.append(
            f"world light ({rgb}) is ignored: ovrad lights with lamps and emissive materials only "
            "(set the world's strength to 0 to compare with Cycles)"
        )
    receiver = surfaces.object_index < n_receivers
    emits = surfaces.emission.max(axis=1) > 0
    for i in np.unique(surfaces.object_index[emits & ~receiver]):
        out.append(
            f"'{surfaces.object_names[i]}' emits light but has no atlas: its light is ignored "
            "(generate an atlas on it too)"
        )
    lamp_power = sum(lamp.power * max(lamp.color) for lamp in lamps)
    if lamp_power <= 0 and not np.any(emits & receiver):
        raise OvradError(
            "no light: no lamp and no emissive material on a mesh with an atlas "
            "(add a lamp or an emissive material)"
        )
    return out


def read_inputs(context, settings: SolveSettings | None = None, need_light: bool = True) -> SolveInputs:
    """Read atlases, their source meshes (receivers), the other visible meshes (occluders) and lamps.

    Raises OvradError for anything that stops a solve; changes nothing.
    """
    scene = context.scene
    pairs = scene_atlases(scene)
    sources = [src for _, src in pairs]
    depsgraph = context.evaluated_depsgraph_get()
    meshes = scene_io.read_scene(depsgraph, sources, scene_io.default_occluders(context, sources))
    if meshes.objects[: meshes.n_receivers] != sources:
        kept = set(meshes.objects)
        lost = [s.name for s in sources if s not in kept]
        raise OvradError(f"{', '.join(map(repr, lost))} no longer has faces: generate its atlas again")
    parts = []
    for i, (obj, _) in enumerate(pairs):
        a = attributes.read_atlas(obj)
        parts.append(replace(a, source_object=np.full(len(a), i, np.int64)))
    atlas = Atlas.concatenate(parts)
    warnings = list(meshes.warnings)
    lamps = scene_io.read_lamps(depsgraph, warnings)
    if need_light:
        warnings += _light_warnings(meshes.surfaces, lamps, scene, len(sources))
    return SolveInputs(
        surfaces=meshes.surfaces,
        atlas=atlas,
        lamps=lamps,
        settings=settings or properties.solve_settings(scene.ovrad),
        atlas_names=[o.name for o, _ in pairs],
        counts=[len(p) for p in parts],
        sources=sources,
        key=fingerprint(meshes.surfaces, atlas),
        warnings=list(dict.fromkeys(warnings)),
    )
