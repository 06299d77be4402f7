"""Solve inputs: atlas objects + their source meshes + occluders + lamps + world, read from bpy into plain
arrays (SolveInputs) before a solve starts, with the fingerprints the caches are keyed by."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import bpy
import numpy as np

from ..ovrad_addon import (
    Atlas,
    KeptOverlaps,
    Lamp,
    OvradError,
    Sky,
    SolveSettings,
    Surfaces,
    add_array,
    hasher,
    names,
)
from . import attributes, engine_settings, environment, scene_io, scene_model


@dataclass
class SolveInputs:
    """Everything the worker needs, read from bpy before it starts.

    atlas: all patches, atlas object after atlas object (atlas_names, counts); the first
    len(sources) objects of surfaces are the source meshes of the first len(sources) atlas
    objects, in the same order; the rest of surfaces (everything else that renders) is covered
    by the environment atlas, last in atlas_names when there is one. sky: the world's light
    (None: none). kept: the blocks of C the atlas objects keep (the engine uses those that fit).
    items: the scene model's item (scene_model.MeshItem: its evaluated mesh) of each source.
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
    environment: environment.Environment | None = None
    sky: Sky | None = None
    kept: list[KeptOverlaps] = field(default_factory=list)
    items: list = field(default_factory=list)

    def first_triangle(self, i: int) -> int:
        """Index in surfaces.triangles of receiver i's first triangle."""
        return int(np.flatnonzero(self.surfaces.object_index == i)[0])


def scene_atlases(scene, warnings: list[str]) -> list[tuple]:
    """(atlas object, source mesh object) of every non-empty atlas in the scene, by atlas name.

    An atlas that cannot be used (its source gone, not a mesh, outside the scene, or a second
    atlas of one mesh) is left out with a warning; raises OvradError when none is left.
    """
    found = sorted(
        (o for o in scene.objects if attributes.is_atlas(o) and not attributes.is_environment(o)),
        key=lambda o: o.name,
    )
    if not found:
        raise OvradError("no atlas in the scene: select the meshes to light and press Generate Atlas first")
    pairs, seen = [], {}
    for obj in found:
        src_name = obj[names.PROP_SOURCE]
        src = bpy.data.objects.get(src_name)
        if src is None or src.type != "MESH":
            warnings.append(
                f"the source mesh '{src_name}' of atlas '{obj.name}' is gone: '{obj.name}' skipped "
                f"(generate the atlas again or delete '{obj.name}')"
            )
        elif src_name in seen:
            warnings.append(
                f"'{seen[src_name]}' and '{obj.name}' are atlases of the same mesh: '{obj.name}' "
                "skipped (delete one)"
            )
        elif src.name not in scene.objects:
            warnings.append(
                f"the source mesh '{src_name}' of atlas '{obj.name}' is not in this scene: skipped"
            )
        else:
            seen[src_name] = obj.name
            if attributes.patch_count(obj):
                pairs.append((obj, src))
    if not pairs:
        why = "; ".join(warnings) or "every atlas is empty"
        raise OvradError(f"no usable atlas in the scene: {why} (generate the atlases again)")
    return pairs


def fingerprint(surfaces: Surfaces, atlas: Atlas) -> str:
    """What the form factors depend on: world geometry, reflectances and albedo textures, receivers
    and the patches (not emission, which the engine reads at each solve, nor lamps)."""
    h = hasher(20)
    arrays = (
        surfaces.vertices,
        surfaces.triangles,
        surfaces.object_index,
        surfaces.reflectance,
        surfaces.receiver,
        *atlas.placement,
        atlas.source_object,
    )
    for a in arrays:
        add_array(h, a)
    h.update(atlas.beta.encode())
    if surfaces.albedo is not None:  # textures change the transport's rho and the first shot
        h.update(b"albedo" + surfaces.albedo.key())
    if surfaces.coverage is not None:  # see-through surfaces change every ray that meets them
        h.update(b"coverage" + surfaces.coverage.key())
    return h.hexdigest()


def light_key(surfaces: Surfaces, lamps, sky: Sky | None = None) -> str:
    """What direct light depends on besides geometry: the lamps, every triangle's emission and
    the sky."""
    h = hasher(20)
    h.update(repr(tuple(lamps)).encode())
    h.update(np.ascontiguousarray(surfaces.emission).tobytes())
    if surfaces.emitted is not None:  # where an image emits, its pieces light the scene
        h.update(b"emitted" + surfaces.emitted.key())
    if sky is not None:
        h.update(sky.key().encode())
    return h.hexdigest()


def _light_warnings(surfaces: Surfaces, lamps, sky: Sky | None, receiver: np.ndarray) -> list[str]:
    """Light the engine will not see (emitters without patches); raises when nothing emits.
    receiver (T,) bool: the triangles that have patches."""
    out = []
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


def read_inputs(
    context, settings: SolveSettings | None = None, need_light: bool = True, model=None
) -> SolveInputs:
    """Read the scene once: atlases and their source meshes (receivers), everything else that
    renders (meshes, instances: the environment atlas covers them), lamps and world; from `model`
    (scene_model.SceneModel) when the caller has read it already.

    need_light: a solve (it checks there is light, and builds a new environment atlas when the
    stored one is stale); else a bake (a stale environment is an error). Raises OvradError for
    anything that stops a solve or bake; changes nothing.
    """
    scene = context.scene
    warnings: list[str] = []
    pairs = scene_atlases(scene, warnings)
    sources = [src for _, src in pairs]
    depsgraph = context.evaluated_depsgraph_get()
    if model is None:
        model = scene_model.read_model(depsgraph, scene)
    meshes = scene_io.read_scene(depsgraph, sources, model.others(sources), model)
    kept = meshes.objects[: meshes.n_receivers]
    if kept != sources:
        for obj, src in pairs:
            if src not in kept:
                warnings.append(f"'{src.name}' has no faces: its atlas '{obj.name}' is skipped")
        pairs = [p for p in pairs if p[1] in kept]
        sources = [src for _, src in pairs]
    parts, kept = [], []
    for i, (obj, _) in enumerate(pairs):
        a = attributes.read_atlas(obj)
        k = attributes.read_kept(obj, sum(len(p) for p in parts))
        if k is not None:
            kept.append(k)
        parts.append(replace(a, source_object=np.full(len(a), i, np.int64)))
    receivers = Atlas.concatenate(parts)
    warnings += meshes.warnings
    base = engine_settings.atlas_settings(scene.ovrad, meshes.objects)
    env = environment.plan(scene, meshes.surfaces, len(sources), receivers, base, need_light, warnings)
    surfaces, atlas = meshes.surfaces, receivers
    atlas_names, counts = [o.name for o, _ in pairs], [len(p) for p in parts]
    if env.atlas is not None:
        surfaces = replace(surfaces, receiver=np.ones(len(surfaces.object_names), bool))
        atlas = Atlas.concatenate([receivers, env.atlas])
        atlas_names.append(env.name)
        counts.append(len(env.atlas))
        if env.kept is not None:
            kept.append(env.kept)
    lamps, sky = model.lamps, model.world
    warnings += model.warnings
    if need_light:
        warnings += _light_warnings(surfaces, lamps, sky, surfaces.receiver[surfaces.object_index])
    return SolveInputs(
        surfaces=surfaces,
        atlas=atlas,
        lamps=lamps,
        settings=settings or engine_settings.solve_settings(scene.ovrad),
        atlas_names=atlas_names,
        counts=counts,
        sources=sources,
        key=fingerprint(surfaces, atlas),
        warnings=list(dict.fromkeys(warnings)),
        environment=env,
        sky=sky,
        kept=kept,
        items=meshes.items[: len(sources)],
    )
