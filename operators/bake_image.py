"""Bake Image: the solved lighting of the selected meshes into lightmaps, saved as 32-bit linear
OpenEXR or 16-bit PNG (png16.py).

The solution is solution.load_solution(): B = pi x the POINT attribute ovrad_radiosity that Solve
wrote on the atlas objects (float32), with the Solve operator's cached problem when the scene still
matches it, else the patches located again on the surfaces (cheap: no form factors). Values are
reconstructed at texel centres on the surface by the engine (bake.lightmap.texel_values; texel
centres just outside a UV island bake at the island's nearest point: lightmap.REACH), dilated
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

from ..ovrad_addon import OvradError, lightmap, names
from ..ovrad_addon import texels as bake
from . import attributes, lightmap_uv, png16, polls, properties, scene_model
from .solution import load_solution

IMAGE_MARK = "ovrad_bake"  # custom property on images this operator made (only those are replaced)
DEFAULT_PATH = "//ovrad/{object}.exr"
EXTENSIONS = {"OPEN_EXR": ".exr", "PNG": ".png"}  # the file format of an image bake, by its extension
FORMAT_NAMES = {"OPEN_EXR": "OpenEXR", "PNG": "16-bit PNG"}
_LISTENERS: list = []
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
                texels, values, step, _ = lightmap.bake_lightmap(
                    problem,
                    radiosity,
                    uv,
                    world,
                    ids,
                    size,
                    self.quantity,
                    solution.first_shot,
                    solution.light,
                )
                if len(texels) == 0:
                    why = (
                        f"its UV map covers no texel centre at {size} px (unwrap it, or bake a larger image)"
                    )
                    not_baked.append(dict(object=obj.name, why=why))
                    continue
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
