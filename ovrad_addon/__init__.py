"""ovrad engine: overlapping-radiosity atlases, transport, solving and baking on plain arrays.

numpy, scipy and embreex only, never bpy. This module is the engine's public API: the Blender glue
(operators/, ui/), scripts/ and benchmarks/ import what they use from here, by these names.
The packages, in the order they build on one another (tests/engine/test_layers.py holds it):
the foundation (errors, names, settings, geometry, parallel, progress, memory, digest), scene,
light, atlas, overlap, radiosity, bake, generate.
"""

from . import memory, names
from .atlas.index import SurfaceIndex, index_surfaces, sheet_spacing
from .atlas.patches import Atlas
from .bake import lightmap, texels
from .bake.gather import Gather, gather_unique, shared_normals
from .bake.points import (
    BakeRequest,
    bake_normals,
    bake_sides,
    irradiance_at,
    nudge,
    radiance_at,
    without_area,
)
from .digest import add_array, hasher
from .errors import OvradError
from .generate.build import build_atlas, build_atlas_and_overlaps, integrate, place_all
from .generate.refine import MIN_SCALE as REFINE_MIN_SCALE
from .generate.refine import refine, solve_adaptive
from .light.direct import DirectLight
from .light.lamps import Lamp, lamp_area
from .light.sky import Sky, sky_irradiance
from .memory import StagePeaks
from .overlap.contacts import contacts as find_contacts
from .overlap.contacts import split_corners
from .overlap.kept import KeptOverlaps, keep, object_keys
from .overlap.queries import alpha_at, reconstruct
from .radiosity.emission import bake_sky, own_emission
from .radiosity.first_shot import direct_light, solve
from .radiosity.problem import Problem, attach_sheets, both_sides_index, locate, overlaps, prepare
from .radiosity.solver import SolveProgress, SolveState
from .radiosity.transport import cosine_directions
from .scene.albedo import TextureAlbedo, triangle_means
from .scene.coverage import Coverage
from .scene.rays import has_embree, make_rays, surface_rays
from .scene.surfaces import Surfaces, triangle_geometry
from .settings import FINE_QUADRATURE, MAX_GATHER_RAYS, AtlasSettings, ObjectSettings, SolveSettings

__all__ = [
    "Coverage",
    "FINE_QUADRATURE",
    "MAX_GATHER_RAYS",
    "REFINE_MIN_SCALE",
    "Atlas",
    "AtlasSettings",
    "BakeRequest",
    "DirectLight",
    "Gather",
    "KeptOverlaps",
    "Lamp",
    "ObjectSettings",
    "OvradError",
    "Problem",
    "Sky",
    "SolveProgress",
    "SolveSettings",
    "SolveState",
    "StagePeaks",
    "SurfaceIndex",
    "Surfaces",
    "TextureAlbedo",
    "add_array",
    "alpha_at",
    "attach_sheets",
    "bake_normals",
    "bake_sides",
    "bake_sky",
    "both_sides_index",
    "build_atlas",
    "build_atlas_and_overlaps",
    "cosine_directions",
    "direct_light",
    "find_contacts",
    "gather_unique",
    "has_embree",
    "hasher",
    "index_surfaces",
    "integrate",
    "irradiance_at",
    "keep",
    "lamp_area",
    "lightmap",
    "locate",
    "make_rays",
    "surface_rays",
    "memory",
    "names",
    "nudge",
    "object_keys",
    "overlaps",
    "own_emission",
    "place_all",
    "prepare",
    "radiance_at",
    "reconstruct",
    "refine",
    "shared_normals",
    "sheet_spacing",
    "sky_irradiance",
    "solve",
    "solve_adaptive",
    "split_corners",
    "texels",
    "triangle_geometry",
    "triangle_means",
    "without_area",
]
