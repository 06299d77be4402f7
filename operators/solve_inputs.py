"""Solve inputs: atlas objects + their source meshes + occluders + lamps + world, read from bpy into plain
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
from ..ovrad_addon.sky import Sky
from ..ovrad_addon.surfaces import Surfaces
from . import attributes, properties, scene_io, world


@dataclass
class SolveInputs:
    """Everything the worker needs, read from bpy before it starts.

    atlas: all patches, atlas object after atlas object (atlas_names, counts); the first
    len(atlas_names) objects of surfaces are their source meshes, in the same order; sky: the
    world's light (None: none).
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
    sky: Sky | None = None

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
    """What the form factors depend on: world geometry, reflectances, receivers and the patches
    (not emission, which the engine reads at each solve, nor lamps)."""
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
    return h.hexdigest()


def light_key(surfaces: Surfaces, lamps, sky: Sky | None = None) -> str:
    """What direct light depends on besides geometry: the lamps, every triangle's emission and
    the sky."""
    h = hashlib.blake2b(digest_size=20)
    h.update(repr(tuple(lamps)).encode())
    h.update(np.ascontiguousarray(surfaces.emission).tobytes())
    if sky is not None:
        h.update(sky.key().encode())
    return h.hexdigest()


def _light_warnings(surfaces: Surfaces, lamps, sky: Sky | None, n_receivers: int) -> list[str]:
    """Light the engine will not see (emitters without atlas); raises when nothing emits."""
    out = []
    receiver = surfaces.object_index < n_receivers
    emits = surfaces.emission.max(axis=1) > 0
    for i in np.unique(surfaces.object_index[emits & ~receiver]):
        out.append(
            f"'{surfaces.object_names[i]}' emits light but has no atlas: its light is ignored "
            "(generate an atlas on it too)"
        )
    lamp_power = sum(lamp.power * max(lamp.color) for lamp in lamps)
    if lamp_power <= 0 and not np.any(emits & receiver) and sky is None:
        raise OvradError(
            "no light: no lamp, no world light and no emissive material on a mesh with an atlas "
            "(add a lamp, an emissive material or world light)"
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
    sky = world.read_world(scene, warnings)
    if need_light:
        warnings += _light_warnings(meshes.surfaces, lamps, sky, len(sources))
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
        sky=sky,
    )
