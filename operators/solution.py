"""The cached solution: the last prepared problem (form factors), and a solved scene read back
for reconstruction (Solution, load_solution), which is what the bakes import."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import bpy
import numpy as np

from ..ovrad_addon import DirectLight, OvradError, Problem, direct_light, locate, names
from . import attributes
from .solve_inputs import SolveInputs, light_key, read_inputs

# The last prepared problem: {"key": fingerprint of the geometry, reflectances and atlases it was
# prepared for (not emission or lamps, which each solve reads again), "transport": the ray
# settings it was computed with, "problem"}. One entry only, as a problem holds C and R. Kept
# across file loads: the key is the content, so an entry is only used for the same content.
_CACHE: dict = {}


def transport_key(settings) -> tuple:
    """The solve settings the transport depends on: a cached problem is reused only if they match."""
    return settings.rays_per_point, settings.min_rays, settings.max_rays, settings.cluster_angle


def cached_problem(inputs: SolveInputs, transport: tuple | None = None) -> Problem | None:
    """The cached problem of these inputs (any ray counts if transport is None), with the
    current surfaces: their emission may differ, the engine reads it at each solve."""
    if _CACHE.get("key") != inputs.key:
        return None
    if transport is not None and _CACHE["transport"] != transport:
        return None
    return replace(_CACHE["problem"], surfaces=inputs.surfaces)


def remember(inputs: SolveInputs, problem: Problem) -> None:
    _CACHE.clear()
    _CACHE.update(key=inputs.key, transport=transport_key(inputs.settings), problem=problem)


def clear_cache() -> None:
    """Forget the prepared problem (frees its memory)."""
    _CACHE.clear()


@dataclass
class Solution:
    """A solved scene, ready for reconstruction at surface points (bakes).

    problem: surfaces, index and atlas with sheets (C and transport may be None); radiosity
    (n, 3) B per patch, read back from the atlas objects; receivers: the source mesh objects,
    receiver i's triangles start at first_triangle[i] in problem.surfaces.triangles, in the
    order of its evaluated mesh's loop_triangles. first_shot (n, 3) and light: the solve's direct
    light, which bakes compute at their own points (None: everything from the patches). items:
    receiver i's scene_model.MeshItem (its evaluated mesh, as the scene model read it).
    """

    problem: Problem
    radiosity: np.ndarray
    receivers: list
    first_triangle: list[int]
    first_shot: np.ndarray | None = None
    light: DirectLight | None = None
    items: list = field(default_factory=list)


def load_solution(context, model=None) -> Solution:
    """The stored solve of the scene's atlases; raises OvradError if there is none (press Solve).
    model: the scene_model.SceneModel the caller read for this operation (None: read it here)."""
    inputs = read_inputs(context, need_light=False, model=model)
    parts = []
    for name, count in zip(inputs.atlas_names, inputs.counts, strict=True):
        mesh = bpy.data.objects[name].data
        if names.RADIOSITY not in mesh.attributes:
            raise OvradError(f"'{name}' has no solved light: press Solve first")
        parts.append(attributes.read_point_attribute(mesh, names.RADIOSITY)[:count, :3])
    radiosity = np.pi * np.concatenate(parts).astype(np.float64)
    problem = cached_problem(inputs) or locate(inputs.surfaces, inputs.atlas, kept=inputs.kept)
    firsts = [inputs.first_triangle(i) for i in range(len(inputs.sources))]
    first_shot, light = None, None
    if context.scene.ovrad.bake_direct:
        first_shot, light = _stored_direct(inputs, problem)
    return Solution(problem, radiosity, inputs.sources, firsts, first_shot, light, inputs.items)


def _stored_direct(inputs: SolveInputs, problem: Problem) -> tuple[np.ndarray | None, DirectLight | None]:
    """The first shot stored by the last solve and the direct light to compute at bake points;
    raises OvradError when the lamps, emission or world changed since (the split would not match)."""
    parts, sky, escaped = [], [], []
    key = light_key(inputs.surfaces, inputs.lamps, inputs.sky)
    for name, count in zip(inputs.atlas_names, inputs.counts, strict=True):
        obj = bpy.data.objects[name]
        if names.DIRECT not in obj.data.attributes:
            return None, None  # solved by an older version: reconstruct everything from the patches
        if obj.get(names.PROP_LIGHT_KEY) != key:
            raise OvradError(
                "the lamps, emissive materials or world changed since the last solve: press Solve again "
                "before baking"
            )
        parts.append(attributes.read_point_attribute(obj.data, names.DIRECT)[:count, :3])
        if names.SKY in obj.data.attributes:
            sky.append(attributes.read_point_attribute(obj.data, names.SKY)[:count] != 0)
        escaped.append(obj.get(names.PROP_ESCAPED))
    first_shot = np.pi * np.concatenate(parts).astype(np.float64)
    # What the solve's transport knew of the sky, stored with the atlases (one solve wrote them
    # all): the bakes cast sky rays where it did, also after the file was reopened.
    stored = escaped[0] if len(set(escaped)) == 1 and isinstance(escaped[0], int) else None
    where = np.concatenate(sky) if len(sky) == len(parts) else None
    light = direct_light(
        problem, inputs.lamps, inputs.settings, sky=inputs.sky, escaped=stored, sky_patches=where
    )
    return first_shot, light
