"""Bake Image: the solved lighting of the selected meshes into lightmaps, saved as 32-bit linear
OpenEXR or 16-bit PNG (png16.py).

The solution is solution.load_solution(): B = pi x the POINT attribute ovrad_radiosity that Solve
wrote on the atlas objects (float32), with the Solve operator's cached problem when the scene still
matches it, else the patches located again on the surfaces (cheap: no form factors). Values are
reconstructed at texel centres on the surface with the engine's radiance_at / irradiance_at (and
at the texel centres just outside a UV island, at the island's nearest point: see REACH), dilated
by `margin` texels, then written to the file first and only then to the image datablock
"<object>_ovrad", so a failure changes nothing.

Each mesh bakes through the UV map named, else its active render UV map when that is fit for a
lightmap (texels.lightmap_problem), else the UV map ovrad makes (lightmap_uv.py); the image size
is the one giving the texel density asked for (texels per metre), unless a fixed size is given.
"""

from __future__ import annotations

import os
import tempfile
import time

import bpy
import numpy as np
from bpy.props import EnumProperty, FloatProperty, IntProperty, StringProperty
from scipy.spatial import cKDTree

from ..ovrad_addon import (
    BakeRequest,
    Gather,
    OvradError,
    bake_normals,
    bake_sides,
    gather_unique,
    irradiance_at,
    names,
    own_emission,
    radiance_at,
)
from ..ovrad_addon import texels as bake
from . import attributes, bake_vertex, lightmap_uv, png16, polls, properties, scene_model
from .solution import load_solution

IMAGE_MARK = "ovrad_bake"  # custom property on images this operator made (only those are replaced)
DEFAULT_PATH = "//ovrad/{object}.exr"
EXTENSIONS = {"OPEN_EXR": ".exr", "PNG": ".png"}  # the file format of an image bake, by its extension
FORMAT_NAMES = {"OPEN_EXR": "OpenEXR", "PNG": "16-bit PNG"}
_LISTENERS: list = []
_CHUNK = 1 << 17  # texels reconstructed at once
# Texel points are moved this fraction of the way to their triangle's centroid, off the exact edge
# (a texel centre on a UV seam lies on a chart's border, where patch membership is decided).
INSET = 1e-6
# The points of texel centres outside an island (REACH), on its edge, are moved towards their
# triangle's centroid as the vertex bake moves corners (bake_vertex.nudge): a point on an island's
# edge lies on a chart's border, on the rim of the patches placed along it.
# Texel centres outside every UV triangle but within this many texels of one are baked at the
# nearest point of the island (texels.rasterize): every centre a bilinear filter reads at a point of
# an island (those less than one texel away in x and y) holds the light of the surface there.
REACH = 1.5
# The final gather (ray count x texels) runs on every step-th texel in x and y, step the smallest
# power of two keeping it under this many rays, and is interpolated in between (the direct light
# stays per texel). 2^23 rays: about 20 s on 2 cores; a 1024 px bake at 256 rays gathers at every
# 8th texel when its islands fill the image, every texel on a small bake.
GATHER_RAY_BUDGET = 1 << 23
SPREAD = 1.25  # neighbours' gathered light this far apart: the texel between them gathers itself
# A UV map's fitness for a lightmap is checked at the image's size, at most this many texels per side.
FIT_CHECK_SIZE = 2048


def solved_atlases(scene) -> dict:
    """Source object name -> its atlas object, for atlas objects in the scene holding a solution."""
    return {
        o[names.PROP_SOURCE]: o
        for o in scene.objects
        if attributes.is_atlas(o) and names.RADIOSITY in o.data.attributes
    }


def uv_triangles(item: scene_model.MeshItem, uv_map: str) -> tuple[np.ndarray, np.ndarray]:
    """UV (T, 3, 2) and world positions (T, 3, 3) of a scene model item's loop triangles (its
    evaluated mesh); OvradError when it has no such UV map."""
    data = item.data()
    return data.bake_uvs(uv_map, item.name), data.corners


def gather_step(count: int, rays: int, budget: int | None = None) -> int:
    """The texel step of the final gather: the smallest power of two with (count / step^2) x rays
    gather rays at most the budget (default GATHER_RAY_BUDGET)."""
    budget = GATHER_RAY_BUDGET if budget is None else budget
    step = 1
    while count * rays > budget * step * step:
        step *= 2
    return step


def texel_sizes(uv, world, size: int) -> np.ndarray:
    """(T,) world length of a texel's side on each triangle: sqrt(world area / area in texels)."""
    e1, e2 = world[:, 1] - world[:, 0], world[:, 2] - world[:, 0]
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    u1, u2 = (uv[:, 1] - uv[:, 0]) * size, (uv[:, 2] - uv[:, 0]) * size
    texels = 0.5 * np.abs(u1[:, 0] * u2[:, 1] - u1[:, 1] * u2[:, 0])
    return np.sqrt(area / np.maximum(texels, 1e-300))


def sparse_gather(problem, radiosity, texels, width: int, light, step: int, size) -> np.ndarray:
    """(k, 3) gathered indirect irradiance at the texels: gathered at the texels whose x and y are
    multiples of step, interpolated to the others from the (up to) 4 nearest gathered ones on the
    same plane within 2 steps (inverse distance); texels with none (a small island), or whose
    neighbours differ by more than SPREAD (an edge of the indirect light), gather themselves.
    size (k,): the world length of a texel's side at each texel (texel_sizes())."""
    tri = texels.triangle
    sides = bake_sides(problem, tri)
    normals = bake_normals(problem, tri, sides)
    own = own_emission(problem, light.emitters, light.emission_scale)

    def gather(k):
        return gather_unique(
            problem, Gather(radiosity, own, light.gather_rays), texels.points[k], normals[k], tri[k]
        )

    x, y = texels.texel % width, texels.texel // width
    coarse = np.flatnonzero((x % step == 0) & (y % step == 0))
    if len(coarse) == 0:
        return gather(np.arange(len(texels)))
    out = np.zeros((len(texels), 3))
    out[coarse] = gather(coarse)
    pts = texels.points
    dist, nb = cKDTree(pts[coarse]).query(pts, k=min(4, len(coarse)))
    dist, nb = dist.reshape(len(pts), -1), nb.reshape(len(pts), -1)
    ok = np.isfinite(dist) & (dist <= 2.0 * step * size[:, None])
    g = coarse[np.minimum(nb, len(coarse) - 1)]
    same = np.einsum("ijk,ik->ij", normals[g], normals) > 0.999
    plane = np.abs(np.einsum("ijk,ik->ij", pts[g] - pts[:, None], normals)) <= 1e-5 * problem.surfaces.extent
    ok &= same & plane
    w = np.where(ok, 1.0 / np.maximum(dist, 1e-12 * problem.surfaces.extent), 0.0)
    # Where the neighbours disagree by more than SPREAD (a contact shadow's edge, the floor under
    # a block), interpolating would blur light across the edge: those texels gather themselves.
    level = out[g].sum(axis=2)
    hi = np.where(ok, level, -np.inf).max(axis=1)
    lo = np.where(ok, level, np.inf).min(axis=1)
    has = (w.sum(axis=1) > 0) & (hi <= SPREAD * lo + 1e-9 * max(float(np.abs(out).max()), 1e-300))
    rest = np.flatnonzero(has)
    rest = rest[~np.isin(rest, coarse)]
    wn = w[rest] / w[rest].sum(axis=1, keepdims=True)
    out[rest] = np.einsum("ij,ijk->ik", wn, out[g[rest]])
    alone = np.flatnonzero(~has)
    alone = alone[~np.isin(alone, coarse)]
    if len(alone):
        out[alone] = gather(alone)
    return out


def nudged(problem, texels) -> bake.Texels:
    """The texels with the points of those outside their island (texels.outside) moved towards their
    triangle's centroid (bake_vertex.nudge)."""
    if texels.outside is None:
        return texels
    out = texels.outside
    points = texels.points.copy()
    centres = problem.surfaces.corners[texels.triangle[out]].mean(axis=1)
    points[out] = bake_vertex.nudge(problem, texels.points[out], centres)
    return bake.Texels(texels.texel, texels.triangle, points, texels.weights, texels.outside)


def subset(texels, keep) -> bake.Texels:
    """The texels where keep (k,) bool is True."""
    outside = None if texels.outside is None else texels.outside[keep]
    return bake.Texels(
        texels.texel[keep], texels.triangle[keep], texels.points[keep], texels.weights[keep], outside
    )


def bake_values(
    problem,
    radiosity,
    texels,
    quantity: str,
    first_shot=None,
    light=None,
    width: int | None = None,
    size=None,
) -> np.ndarray:
    """Radiance (or irradiance / pi) (k, 3) at texel points, seen from the side bake.points.bake_sides
    picks for their triangle (as the vertex bake does); direct light computed at the texels when
    the solve's first shot and light are given, and the final gather on a grid of every
    gather_step()-th texel when it would cast more than GATHER_RAY_BUDGET rays (width: the image's,
    size (k,): each texel's world size, texel_sizes()); returns the values and that step."""
    fn = irradiance_at if quantity == "IRRADIANCE" else radiance_at
    indirect = None
    step = 1
    if light is not None and first_shot is not None and light.gather_rays > 0 and width is not None:
        step = gather_step(len(texels), light.gather_rays)
        if step > 1:
            indirect = sparse_gather(problem, radiosity, texels, width, light, step, size)
    out = np.zeros((len(texels), 3))
    for s in range(0, len(texels), _CHUNK):
        sl = slice(s, s + _CHUNK)
        pts, tri = texels.points[sl], texels.triangle[sl]
        part = None if indirect is None else indirect[sl]
        request = BakeRequest(radiosity, first_shot, light, indirect=part)
        out[sl] = fn(problem, request, pts, tri, bake_sides(problem, tri))
    # Smooth beta rings slightly below 0 next to contact shadows; light is never negative.
    return np.maximum(out, 0.0), step


def add_listener(listener) -> callable:
    """Call listener(result) after each image bake that finished, result a dict: `images`, one
    {object, path, uv_map, size, format, exposure} per image written (exposure: a 16-bit PNG's,
    else None), and `not_baked`, one {object, why} per selected mesh that was not baked. Returns
    the function that removes the listener."""
    _LISTENERS.append(listener)
    return lambda: _LISTENERS.remove(listener)


def resolve_path(template: str, obj_name: str, file_format: str = "OPEN_EXR") -> str:
    """Absolute file path for an object; '//' needs a saved .blend file. A path without an
    extension gets the format's; one with another extension is refused."""
    path = template.replace("{object}", bpy.path.clean_name(obj_name))
    if path.startswith("//") and not bpy.data.filepath:
        raise OvradError(
            "the output path is relative ('//') but the .blend file is not saved: give a full path"
        )
    path = os.path.abspath(bpy.path.abspath(path))
    ext = EXTENSIONS[file_format]
    have = os.path.splitext(path)[1]
    if not have:
        path += ext
    elif have.lower() != ext:
        raise OvradError(f"the output must be a {FORMAT_NAMES[file_format]} file ({ext}), got '{path}'")
    return path


def prepare_folder(path: str, created: list) -> None:
    """Make the file's folder (recording what was created) and check a file can be written there."""
    folder = os.path.dirname(path)
    missing = []
    probe = folder
    while not os.path.exists(probe):
        missing.append(probe)
        probe = os.path.dirname(probe)
    try:
        for d in reversed(missing):
            os.mkdir(d)
            created.append(d)
        if os.path.isdir(path):
            raise OSError("it is a folder")
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".ovrad-probe-"):
            pass
    except OSError as e:
        raise OvradError(f"cannot write '{path}': {e.strerror or e}") from None


def _remove_created(created: list) -> None:
    for d in reversed(created):
        try:
            os.rmdir(d)
        except OSError:
            pass


def write_image(
    name: str, pixels: np.ndarray, path: str, stored_path: str, file_format: str = "OPEN_EXR"
) -> bpy.types.Image:
    """Save pixels (H, W, 4) as a 32-bit float EXR (or a 16-bit PNG, png16.py), then create or
    replace the image `name` (a PNG's holds the file's values; its exposure is the image's custom
    property names.PROP_EXPOSURE)."""
    h, w = pixels.shape[:2]
    if file_format == "PNG":
        try:
            exposure = png16.write(path, pixels)
            img = bpy.data.images.load(path, check_existing=False)
            img.colorspace_settings.name = "Non-Color"  # linear values, no view transform
            img.reload()
        except (OSError, RuntimeError) as e:
            raise OvradError(f"cannot write '{path}': {str(e).strip().splitlines()[0]}") from None
        img[names.PROP_EXPOSURE] = exposure
    else:
        img = bpy.data.images.new(name + ".tmp", w, h, alpha=True, float_buffer=True)
        try:
            img.colorspace_settings.name = "Non-Color"  # linear values, no view transform
            img.pixels.foreach_set(np.ascontiguousarray(pixels, np.float32).ravel())
            img.file_format = "OPEN_EXR"
            img.filepath_raw = path
            img.save()
        except RuntimeError as e:
            bpy.data.images.remove(img)
            raise OvradError(f"cannot write '{path}': {str(e).strip().splitlines()[0]}") from None
    img.filepath_raw = stored_path
    img[IMAGE_MARK] = True
    img.use_fake_user = True  # kept in the saved file even before a material uses it
    old = bpy.data.images.get(name)
    if old is not None and old.get(IMAGE_MARK):
        old.user_remap(img)  # materials using the earlier bake now show this one
        bpy.data.images.remove(old)
    img.name = name
    return img


class OVRAD_OT_bake_image(bpy.types.Operator):
    bl_idname = "ovrad.bake_image"
    bl_label = "Bake to Image"
    bl_description = (
        "Bake the solved lighting of the selected meshes into a lightmap per mesh through its UV map "
        "(made where it has none fit for a lightmap), saved as 32-bit linear OpenEXR or 16-bit PNG and "
        "available as the image '<object>_ovrad'"
    )
    bl_options = {"REGISTER", "UNDO"}

    uv_map: StringProperty(
        name="UV Map",
        description=(
            "UV map to bake through; empty or 'auto': the active render UV map when it is fit for a "
            "lightmap, else the UV map 'ovrad_lightmap' that ovrad makes"
        ),
    )
    size: IntProperty(
        name="Size",
        description="Image width and height in texels (0: from the texel density)",
        **properties.IMAGE_SIZE,
    )
    texel_density: FloatProperty(name="Texel Density", **properties.TEXEL_DENSITY)
    max_size: IntProperty(name="Max Size", **properties.MAX_IMAGE_SIZE)
    margin: IntProperty(
        name="Margin",
        description=(
            "Texels filled around UV islands so no seams show; the islands of a UV map ovrad makes "
            "are at least this many texels apart"
        ),
        default=properties.IMAGE_MARGIN,
        min=0,
        max=256,
    )
    quantity: EnumProperty(name="Quantity", items=properties.BAKE_QUANTITIES, default="RADIANCE")
    file_format: EnumProperty(name="Format", items=properties.IMAGE_FORMATS, default="OPEN_EXR")
    filepath: StringProperty(
        name="File",
        description=(
            "Image file per object; {object} is replaced by the object's name, a path without an "
            "extension gets the format's"
        ),
        default=DEFAULT_PATH,
        subtype="FILE_PATH",
    )

    @classmethod
    def poll(cls, context):
        checks = (
            polls.object_mode(context, "bake"),
            (bool(polls.selected_meshes(context)), "Select the meshes to bake"),
        )
        return polls.passes(cls, checks)

    def choose_maps(self, context, model, depsgraph, targets, not_baked) -> list:
        """(object, UV map name, least size or 0) per target that can be baked, making the UV maps
        an automatic choice needs (every check before any computation or image write)."""
        chosen, to_make = [], []
        for obj in targets:
            try:
                item = model.item_of(obj) or scene_model.object_item(obj, depsgraph)
                data = item.data()
                density = lightmap_uv.density_per_unit(context.scene, obj, self.texel_density)
                if self.size == 0:
                    lightmap_uv.check_density(obj.name, data.corners, density, self.max_size)
                if not lightmap_uv.is_auto(self.uv_map):
                    uv = data.bake_uvs(self.uv_map.strip(), obj.name)
                    size = self.size or bake.density_size(uv, data.corners, density, lightmap_uv.MULTIPLE)
                    why = lightmap_uv.problem(uv, data.corners, min(size, FIT_CHECK_SIZE))
                    if why:
                        self.report(
                            {"WARNING"}, f"'{obj.name}': UV map '{self.uv_map}' is baked as it is, but {why}"
                        )
                    chosen.append((obj, self.uv_map.strip(), 0))
                    continue
                mine = lightmap_uv.user_map(obj.data)
                if mine:
                    uv = data.bake_uvs(mine, obj.name)
                    size = self.size or bake.density_size(uv, data.corners, density, lightmap_uv.MULTIPLE)
                    why = lightmap_uv.problem(uv, data.corners, min(size, FIT_CHECK_SIZE))
                    if why is None:
                        chosen.append((obj, mine, 0))
                        continue
                    ours = lightmap_uv.LIGHTMAP_UV
                    self.report(
                        {"INFO"},
                        f"'{obj.name}': UV map '{mine}' is unfit for a lightmap ({why}): making '{ours}'",
                    )
                to_make.append((obj, density))
            except OvradError as e:
                not_baked.append(dict(object=obj.name, why=str(e)))
        made: dict = {}  # mesh name -> image size its made map was packed for
        for obj, density in to_make:
            try:
                if obj.data.name not in made:
                    made[obj.data.name] = lightmap_uv.make(context, obj, density, self.margin)
                chosen.append((obj, lightmap_uv.LIGHTMAP_UV, made[obj.data.name]))
            except OvradError as e:
                not_baked.append(dict(object=obj.name, why=str(e)))
        order = {o.name: i for i, o in enumerate(targets)}
        return sorted(chosen, key=lambda c: order[c[0].name])

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        start = time.perf_counter()
        created: list[str] = []
        not_baked: list[dict] = []
        try:
            targets = polls.selected_meshes(context)
            solved = solved_atlases(context.scene)
            for o in targets:
                if o.name not in solved:
                    not_baked.append(
                        dict(object=o.name, why="not solved: generate an atlas and run Solve first")
                    )
            targets = [o for o in targets if o.name in solved]
            if len(targets) > 1 and "{object}" not in self.filepath:
                raise OvradError("several objects are selected: put {object} in the file path")
            paths = {o.name: resolve_path(self.filepath, o.name, self.file_format) for o in targets}
            # the scene, read once for this bake: the targets' meshes here, the solution's inputs below
            depsgraph = context.evaluated_depsgraph_get()
            model = scene_model.read_model(depsgraph, context.scene)
            chosen = self.choose_maps(context, model, depsgraph, targets, not_baked)
            made = any(least for *_, least in chosen)
            if made:  # the UV maps ovrad made are read from the updated meshes
                depsgraph = context.evaluated_depsgraph_get()
            jobs = []
            for obj, uv_map, least in chosen:
                try:
                    item = scene_model.object_item(obj, depsgraph) if least else model.item_of(obj)
                    item = item or scene_model.object_item(obj, depsgraph)
                    uv, world = uv_triangles(item, uv_map)
                    size = self.size
                    if not size:
                        density = lightmap_uv.density_per_unit(context.scene, obj, self.texel_density)
                        size = max(least, bake.density_size(uv, world, density, lightmap_uv.MULTIPLE))
                        if size > self.max_size:
                            raise OvradError(
                                f"'{obj.name}' needs a {size} x {size} image at this texel density, more "
                                f"than Max Size ({self.max_size}): lower the texel density or its Lightmap "
                                "Scale, or raise Max Size"
                            )
                except OvradError as e:
                    not_baked.append(dict(object=obj.name, why=str(e)))
                    continue
                jobs.append((obj, uv_map, size, uv, world, paths[obj.name]))
            if not jobs:
                raise OvradError(
                    "; ".join(n["why"] for n in not_baked) or "nothing to bake: select the meshes to bake"
                )
            for *_, path in jobs:
                prepare_folder(path, created)
            solution = load_solution(context, model)
            problem, radiosity, firsts = solution.problem, solution.radiosity, solution.first_triangle
            order = [o.name for o in solution.receivers]
            results, steps = [], []
            for obj, uv_map, size, uv, world, path in jobs:
                k = order.index(obj.name) if obj.name in order else -1
                if k < 0 or len(uv) != int(np.sum(problem.surfaces.object_index == k)):
                    not_baked.append(
                        dict(object=obj.name, why="it changed since the solve (press Solve again)")
                    )
                    continue
                ids = firsts[k] + np.arange(len(uv))
                texels = bake.rasterize(uv, world, ids, size, size, inset=INSET, reach=REACH)
                if len(texels) == 0:
                    why = (
                        f"its UV map covers no texel centre at {size} px (unwrap it, or bake a larger image)"
                    )
                    not_baked.append(dict(object=obj.name, why=why))
                    continue
                sizes = texel_sizes(uv, world, size)[texels.triangle - firsts[k]]
                texels = nudged(problem, texels)
                # the centres in the islands, then those just outside (their gathers are not
                # interpolated from one another)
                outside = np.zeros(len(texels), bool) if texels.outside is None else texels.outside
                values = np.zeros((len(texels), 3))
                for part in (~outside, outside):
                    if part.any():
                        values[part], step = bake_values(
                            problem,
                            radiosity,
                            subset(texels, part),
                            self.quantity,
                            solution.first_shot,
                            solution.light,
                            size,
                            sizes[part],
                        )
                        steps.append(step)
                img, mask = bake.to_image(texels, values, size, size)
                img, mask = bake.dilate(img, mask, self.margin)
                img[..., 3] = mask
                results.append((obj, uv_map, size, img, path))
            if not results:
                raise OvradError("; ".join(n["why"] for n in not_baked))
            images, entries = [], []
            for obj, uv_map, size, img, path in results:
                stored = path
                if self.filepath.startswith("//"):
                    stored = bpy.path.relpath(path)
                image = write_image(obj.name + names.IMAGE_SUFFIX, img, path, stored, self.file_format)
                images.append(image)
                exposure = image.get(names.PROP_EXPOSURE) if self.file_format == "PNG" else None
                entries.append(
                    dict(object=obj.name, path=path, uv_map=uv_map, size=size, format=self.file_format)
                )
                entries[-1]["exposure"] = exposure
        except OvradError as e:
            _remove_created(created)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        for n in not_baked:
            why = n["why"]
            self.report(
                {"WARNING"},
                why if why.startswith(f"'{n['object']}'") else f"'{n['object']}' not baked: {why}",
            )
        seconds = time.perf_counter() - start
        listed = ", ".join(f"'{e['object']}' {e['size']} px" for e in entries)
        sparse = max(steps, default=1)
        note = f"; indirect light gathered at every {sparse} texels and interpolated" if sparse > 1 else ""
        self.report({"INFO"}, f"ovrad: baked {listed}{note} in {seconds:.2f} s")
        for listener in list(_LISTENERS):
            listener(dict(images=entries, not_baked=not_baked))
        return {"FINISHED"}


classes = (OVRAD_OT_bake_image,)
