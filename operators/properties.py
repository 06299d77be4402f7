"""ovrad's Blender properties: scene settings and per-object overrides (their conversion to the
engine's frozen settings: engine_settings.py)."""

from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ..ovrad_addon import MAX_GATHER_RAYS, AtlasSettings, ObjectSettings, SolveSettings
from . import attributes, display

# Every default that the engine's settings have is read from them (one default per setting); only
# patch_size, which the engine derives from the count when none is given, has its own here.
_ATLAS = AtlasSettings()
_OBJECT = ObjectSettings()
_SOLVE = SolveSettings()

# Quality levels (panel and batch): the settings each sets; MEDIUM is the engine's defaults. Chosen
# on the Cornell box, every vertex scored: with the final gather and its near field the error
# follows the gather rays (2 000 smooth patches, 1 M transport rays: 2.2 / 1.7 / 1.45 / 1.35 % with
# 128 / 256 / 512 / 1 024 rays), the patch count barely (3 000: 1.7 % at 256 rays) and the transport
# rays not at all above 2^19-2^20. Measured against Cycles by benchmarks/speed_vs_error.py
# (docs/benchmarks.md).
QUALITY = {
    "DRAFT": dict(patch_count=1000, gather_rays=128, min_rays=1 << 19),
    "MEDIUM": dict(patch_count=_ATLAS.patch_count, gather_rays=_SOLVE.gather_rays, min_rays=_SOLVE.min_rays),
    "HIGH": dict(patch_count=3000, gather_rays=1024, min_rays=1 << 21),
}
_LEVELS = (*QUALITY, "CUSTOM")

# The choices of a bake (the scene's settings and the bake operators' own properties).
IMAGE_SIZE = dict(default=0, min=0, max=16384)  # texels, width and height; 0: from the texel density
# Texels per metre of a lightmap: a 6 m wall gets 240 texels, a 40 cm bench 16.
TEXEL_DENSITY = dict(
    description="Lightmap texels per metre of surface (times each object's Lightmap Scale)",
    default=40.0,
    min=1e-3,
    max=1e5,
    soft_min=1.0,
    soft_max=1000.0,
)
MAX_IMAGE_SIZE = dict(
    description="Largest lightmap width and height: a mesh that needs more at the texel density is not baked",
    default=4096,
    min=4,
    max=16384,
)
IMAGE_MARGIN = 4  # texels filled around UV islands; islands of a UV map ovrad makes are this far apart
IMAGE_FORMATS = (
    ("OPEN_EXR", "OpenEXR", "32-bit float, linear values"),
    (
        "PNG",
        "PNG 16-bit",
        "16 bits per channel, linear values times 2^-exposure; the exposure is in the file's metadata "
        "(ovrad:exposure) and the image's custom property ovrad_exposure",
    ),
)
LIGHTMAP_ATLASES = (
    ("OBJECT", "Per Object", "One lightmap per mesh, through its own UV map or the one ovrad makes"),
    (
        "SHARED",
        "Shared",
        "The meshes' lightmaps packed together into as few images as Max Size allows, through UV maps "
        "ovrad makes for them together (linked duplicates get images of their own)",
    ),
)
BAKE_DOMAINS = (
    ("POINT", "Vertex", "One value per vertex: angle-weighted average of its face corners (smooth)"),
    ("CORNER", "Face Corner", "One value per face corner: keeps hard edges between faces"),
)
BAKE_QUANTITIES = (
    (
        "RADIANCE",
        "Radiance",
        "Outgoing diffuse radiance L = B/pi with the surface's own emission (a Cycles DIFFUSE bake "
        "with colour, plus emission)",
    ),
    (
        "IRRADIANCE",
        "Irradiance",
        "Light arriving, without the surface's albedo, as the radiance of a white surface (E/pi)",
    ),
)


def apply_quality(props, level: str) -> None:
    """Set the settings of a quality level (patch count by count, gather rays, min_rays)."""
    props.size_mode = "COUNT"
    for key, value in QUALITY[level].items():
        setattr(props, key, value)


def _get_quality(self) -> int:
    # The level whose settings the scene has, else Custom: never out of step with them.
    for i, q in enumerate(QUALITY.values()):
        if self.size_mode == "COUNT" and all(getattr(self, k) == v for k, v in q.items()):
            return i
    return _LEVELS.index("CUSTOM")


def _set_quality(self, value: int) -> None:
    if _LEVELS[value] in QUALITY:
        apply_quality(self, _LEVELS[value])


def _update_display(self, context) -> None:
    # Runs when the user picks another quantity: every atlas object in the scene follows.
    for obj in context.scene.objects:
        if attributes.is_atlas(obj):
            display.set_quantity(obj, self.display_quantity)


class OVRAD_PG_settings(bpy.types.PropertyGroup):
    """Scene-wide atlas settings (bpy.types.Scene.ovrad)."""

    quality: EnumProperty(
        name="Quality",
        description="Sets the patch count, gather rays and minimum rays together (each can still be changed)",
        items=(
            ("DRAFT", "Draft", "Fewer patches and 128 gather rays: a quick look", 0),
            ("MEDIUM", "Medium", "The default settings", 1),
            ("HIGH", "High", "More patches, 1024 gather rays and more transport rays: less error, slower", 2),
            ("CUSTOM", "Custom", "The settings were changed from every level's", 3),
        ),
        get=_get_quality,
        set=_set_quality,
    )

    size_mode: EnumProperty(
        name="Patch Size",
        description="How the patch size is chosen",
        items=(
            ("COUNT", "By Count", "Choose the size so the selected meshes get about this many patches"),
            ("SIZE", "By Size", "Use a fixed patch size (grid spacing) in scene units"),
        ),
        default="COUNT",
    )
    patch_count: IntProperty(
        name="Patch Count",
        description="Target number of patches over all selected meshes",
        default=_ATLAS.patch_count,
        min=1,
        soft_max=100_000,
    )
    patch_size: FloatProperty(
        name="Size",
        description="Grid spacing of patch centres, in scene units",
        default=0.1,
        min=1e-6,
        soft_min=1e-3,
        subtype="DISTANCE",
        unit="LENGTH",
    )
    overlap: FloatProperty(
        name="Overlap",
        description="Patch radius over the smallest radius that covers its grid cell (1: just covering)",
        default=_ATLAS.overlap,
        min=1.0,
        max=4.0,
    )
    beta: EnumProperty(
        name="Beta",
        description="Weight of a patch across its support",
        items=(
            ("smooth", "Smooth", "1 at the centre falling continuously to 0 at the rim: smooth blends"),
            ("box", "Box", "Constant over the patch: uniform averages where patches overlap"),
        ),
        default=_ATLAS.beta,
    )
    shapes: EnumProperty(
        name="Shapes",
        description="Patch shapes",
        items=(
            ("AUTO", "Auto", "Disks inside faces, squares on cells cut by an edge"),
            ("DISKS", "Disks", "Disks everywhere"),
            ("SQUARES", "Squares", "Squares everywhere"),
        ),
        default=_ATLAS.shapes,
    )
    max_patches: IntProperty(
        name="Patch Limit",
        description="Refuse to make more patches than this (memory and time grow with the count)",
        default=_ATLAS.max_patches,
        min=1,
    )
    display_quantity: EnumProperty(
        name="Display",
        description="What the patches of atlas objects are coloured by",
        items=(
            ("OVERLAP", "Overlap Count", "How many other patches overlap each patch"),
            ("RANDOM", "Random", "A random colour per patch"),
            ("BETA", "Beta", "The beta profile across each patch"),
            ("RADIOSITY", "Radiosity", "Solved radiosity (black until solved)"),
        ),
        default="OVERLAP",
        update=_update_display,
    )
    solve_tolerance: FloatProperty(
        name="Tolerance",
        description="Stop when the light not yet shot is below this fraction of the light emitted",
        default=_SOLVE.tolerance,
        min=1e-6,
        max=0.5,
        precision=4,
        step=0.01,
    )
    solve_rule: EnumProperty(
        name="Solver",
        description="How shot light is turned back into patch radiosities",
        items=(
            (
                "exact",
                "Exact",
                "Solve the overlap system exactly: the fixed point is the paper's equation (9)",
            ),
            ("paper", "Paper", "The paper's published distribution rule (for comparison)"),
        ),
        default=_SOLVE.rule,
    )
    rays_per_point: IntProperty(
        name="Rays per Point",
        description="Hemisphere rays cast from each surface sample for the form factors (more: less noise)",
        default=_SOLVE.rays_per_point,
        min=1,
        max=4096,
        soft_max=1024,
    )
    min_rays: IntProperty(
        name="Minimum Rays",
        description=(
            "Transport rays cast at least, in all: a small atlas gets more surface samples and "
            "rays per sample until it reaches this many (0: exactly Rays per Point)"
        ),
        default=_SOLVE.min_rays,
        min=0,
        max=1 << 28,
        soft_max=1 << 26,
    )
    max_rays: IntProperty(
        name="Maximum Rays",
        description=(
            "Transport rays cast at most, in all (0: no limit): a very large atlas gets fewer "
            "surface samples and rays per sample, so time and memory stop growing with the patch "
            "count (the light of bakes comes mostly from their own final gather)"
        ),
        default=_SOLVE.max_rays,
        min=0,
        max=1 << 30,
        soft_max=1 << 26,
    )
    cluster_angle: FloatProperty(
        name="Far Clusters",
        description=(
            "Transport rays that land far away read the mean light of a cluster of patches whose "
            "size is under this fraction of the distance, instead of each patch there: a faster "
            "transport and a smaller matrix (0: every patch at every hit)"
        ),
        default=_SOLVE.cluster_angle,
        min=0.0,
        max=2.0,
        step=10,
    )
    bake_direct: BoolProperty(
        name="Sharp Direct Light",
        description=(
            "Compute the direct light of lamps and small emitters at every baked vertex or texel "
            "(shadow rays), and take only the indirect light from the patches: sharp shadows and "
            "fall-off. Off: everything from the patches, as the paper reconstructs it"
        ),
        default=True,
    )
    gather_rays: IntProperty(
        name="Gather Rays",
        description=(
            "Rays cast from every baked vertex or texel to gather its indirect light from the solved "
            "patches (sharper near objects, no light leaking under them); 0: the indirect light is "
            "reconstructed from the patches, as in the paper. Needs Sharp Direct Light"
        ),
        default=_SOLVE.gather_rays,
        min=0,
        max=MAX_GATHER_RAYS,
        soft_max=1024,
    )
    bake_target: EnumProperty(
        name="Bake To",
        description="Where the solved light is baked",
        items=(
            ("VERTEX", "Vertex Colors", "A colour attribute on the receiving meshes"),
            ("IMAGE", "Image Texture", "An image texture over a UV map"),
        ),
        default="VERTEX",
    )
    bake_attribute: StringProperty(
        name="Attribute",
        description="Name of the colour attribute the bake writes (replaced only if ovrad made it)",
        default="ovrad_radiance",
        maxlen=63,
    )
    bake_uv_map: StringProperty(
        name="UV Map",
        description=(
            "UV map of an image bake (empty: each mesh's active render UV map when it is fit for a "
            "lightmap, else the UV map 'ovrad_lightmap' that ovrad makes)"
        ),
        default="",
        maxlen=63,
    )
    bake_image_size: IntProperty(
        name="Image Size",
        description="Width and height of a baked image, in texels (0: from the texel density)",
        soft_max=8192,
        **IMAGE_SIZE,
    )
    bake_texel_density: FloatProperty(name="Texel Density", **TEXEL_DENSITY)
    bake_max_size: IntProperty(name="Max Size", **MAX_IMAGE_SIZE)
    bake_image_format: EnumProperty(name="Format", items=IMAGE_FORMATS, default="OPEN_EXR")
    bake_atlas: EnumProperty(name="Atlas", items=LIGHTMAP_ATLASES, default="OBJECT")
    bake_image_path: StringProperty(
        name="File",
        description=(
            "Image file of an image bake; {object} is replaced by the object's name, a path without "
            "an extension gets the format's"
        ),
        default="//ovrad/{object}.exr",
        subtype="FILE_PATH",
    )
    bake_domain: EnumProperty(
        name="Domain",
        description="Where the colour attribute stores its values",
        items=BAKE_DOMAINS,
        default="POINT",
    )
    bake_quantity: EnumProperty(
        name="Quantity",
        description="What is baked",
        items=BAKE_QUANTITIES,
        default="RADIANCE",
    )


class OVRAD_PG_object(bpy.types.PropertyGroup):
    """Per-object overrides (bpy.types.Object.ovrad)."""

    density: FloatProperty(
        name="Density",
        description="Patch density multiplier on this object (2: patches half the size)",
        default=_OBJECT.density,
        min=1e-3,
        max=999.0,
        soft_min=0.1,
        soft_max=10.0,
    )
    sides: EnumProperty(
        name="Sides",
        description="Which sides of the faces get patches",
        items=(
            (
                "AUTO",
                "Auto",
                "Front only on closed meshes; open meshes also on the back when it sees the scene",
            ),
            ("FRONT", "Front", "Only the side the normals point to"),
            ("BOTH", "Both", "Both sides (a two-sided card or wall)"),
        ),
        default=_OBJECT.sides,
    )
    lightmap_scale: FloatProperty(
        name="Lightmap Scale",
        description="Texel density multiplier of this object's lightmap (2: twice the texels per metre)",
        default=1.0,
        min=1e-3,
        max=1000.0,
        soft_min=0.1,
        soft_max=10.0,
    )


classes = (OVRAD_PG_settings, OVRAD_PG_object)
