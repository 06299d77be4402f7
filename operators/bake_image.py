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

import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from bpy.props import EnumProperty, FloatProperty, IntProperty, StringProperty

from ..ovrad_addon import OvradError, lightmap, names
from ..ovrad_addon import texels as bake
from . import attributes, image_files, lightmap_atlas, lightmap_uv, polls, properties, scene_model
from .solution import load_solution

DEFAULT_PATH = "//ovrad/{object}.exr"
_LISTENERS: list = []
# A UV map's fitness for a lightmap is checked at the image's size, at most this many texels per side.
FIT_CHECK_SIZE = 2048


def add_listener(listener) -> callable:
    """Call listener(result) after each image bake that finished, result a dict: `images`, one
    {object, path, uv_map, size, format, exposure, image} per object baked (exposure: a 16-bit
    PNG's, else None; image: the image datablock's name; the objects of a shared atlas share its
    path and image), and `not_baked`, one {object, why} per selected mesh that was not baked. Returns
    the function that removes the listener."""
    _LISTENERS.append(listener)
    return lambda: _LISTENERS.remove(listener)


@dataclass
class Job:
    """One image to bake: its objects (one, or a shared atlas's), the UV map they bake through, the
    least size their made UV maps were packed for (0: none made; a shared atlas: its size), the
    image's name and the {object} of its file path, whether it is a shared atlas; read_job() fills
    in the size and each object's UV and world triangles, bake_job() the objects baked."""

    objects: list
    uv_map: str
    least: int
    image_name: str
    file_name: str
    shared: bool = False
    size: int = 0
    triangles: list = field(default_factory=list)
    path: str = ""
    baked: list = field(default_factory=list)


class OVRAD_OT_bake_image(bpy.types.Operator):
    bl_idname = "ovrad.bake_image"
    bl_label = "Bake to Image"
    bl_description = (
        "Bake the solved lighting of the selected meshes into a lightmap per mesh through its UV map "
        "(made where it has none fit for a lightmap), or into shared atlases, saved as 32-bit linear "
        "OpenEXR or 16-bit PNG and available as the image '<object>_ovrad' (a shared atlas: 'ovrad_atlas')"
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
    atlas: EnumProperty(name="Atlas", items=properties.LIGHTMAP_ATLASES, default="OBJECT")
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

    def shared_maps(self, context, model, depsgraph, objects, not_baked, others: int = 0) -> list:
        """(objects, image size) per shared atlas, their UV maps made together (lightmap_atlas);
        others: the images baked besides (the file path must then hold {object})."""
        ok, densities, needs = [], [], []
        for obj in objects:
            try:
                data = (model.item_of(obj) or scene_model.object_item(obj, depsgraph)).data()
                density = lightmap_uv.density_per_unit(context.scene, obj, self.texel_density)
                if self.size == 0:
                    lightmap_uv.check_density(obj.name, data.corners, density, self.max_size)
                lightmap_uv.check_room(obj)  # one mesh that cannot take the map leaves the others be
            except OvradError as e:
                not_baked.append(dict(object=obj.name, why=str(e)))
                continue
            ok.append(obj)
            densities.append(density)
            needs.append(lightmap_uv.world_area(data.corners) * density**2)
        if not ok:
            return []
        groups = [list(range(len(ok)))] if self.size else lightmap_atlas.groups(needs, self.max_size)
        if "{object}" not in self.filepath and len(groups) + others > 1:  # before any UV map is made
            raise OvradError("several images would be baked: put {object} in the file path")
        out = []
        while groups:
            group = groups.pop(0)
            objs = [ok[i] for i in group]
            try:
                size = lightmap_uv.make_shared(context, objs, [densities[i] for i in group], self.margin)
                if self.size:
                    size = self.size
                elif size > self.max_size and len(group) > 1:  # packed looser than guessed: halve it
                    if "{object}" not in self.filepath:
                        raise OvradError(
                            "the meshes need more than one atlas at Max Size: put {object} in the file path"
                        )
                    groups += lightmap_atlas.halves(group, needs)
                    continue
                elif size > self.max_size:
                    raise OvradError(
                        f"'{objs[0].name}' needs {size} x {size} texels at this texel density once packed, "
                        f"more than Max Size ({self.max_size}): lower the texel density or its Lightmap "
                        "Scale, or raise Max Size"
                    )
            except OvradError as e:
                not_baked += [dict(object=o.name, why=str(e)) for o in objs]
                continue
            out.append((objs, size))
        return out

    def read_job(self, context, model, depsgraph, job: Job, not_baked) -> bool:
        """Fill in the job's objects' UV and world triangles and its image size; False (each
        object's reason in not_baked) when none of them can be baked."""
        keep = []
        for obj in job.objects:
            try:
                item = scene_model.object_item(obj, depsgraph) if job.least else model.item_of(obj)
                item = item or scene_model.object_item(obj, depsgraph)
                data = item.data()  # the evaluated mesh
                uv, world = data.bake_uvs(job.uv_map, item.name), data.corners
            except OvradError as e:
                not_baked.append(dict(object=obj.name, why=str(e)))
                continue
            keep.append(obj)
            job.triangles.append((uv, world))
        job.objects = keep
        if not keep:
            return False
        if self.size:
            job.size = self.size
        elif job.shared:
            job.size = job.least  # the size its UV maps were packed for
        else:
            obj, (uv, world) = keep[0], job.triangles[0]
            density = lightmap_uv.density_per_unit(context.scene, obj, self.texel_density)
            job.size = max(job.least, bake.density_size(uv, world, density, lightmap_uv.MULTIPLE))
            if job.size > self.max_size:
                not_baked.append(
                    dict(
                        object=obj.name,
                        why=f"'{obj.name}' needs a {job.size} x {job.size} image at this texel density, "
                        f"more than Max Size ({self.max_size}): lower the texel density or its Lightmap "
                        "Scale, or raise Max Size",
                    )
                )
                return False
        return True

    def bake_job(self, solution, job: Job, not_baked, steps) -> np.ndarray | None:
        """The job's image (size, size, 4), alpha 1 on its texels and the dilated margin; None when
        none of its objects baked (their reasons in not_baked)."""
        problem, firsts = solution.problem, solution.first_triangle
        order = [o.name for o in solution.receivers]
        size = job.size
        img, mask = np.zeros((size, size, 4)), np.zeros((size, size), bool)
        for obj, (uv, world) in zip(job.objects, job.triangles, strict=True):
            k = order.index(obj.name) if obj.name in order else -1
            if k < 0 or len(uv) != int(np.sum(problem.surfaces.object_index == k)):
                not_baked.append(dict(object=obj.name, why="it changed since the solve (press Solve again)"))
                continue
            ids = firsts[k] + np.arange(len(uv))
            texels, values, step, _ = lightmap.bake_lightmap(
                problem,
                solution.radiosity,
                uv,
                world,
                ids,
                size,
                self.quantity,
                solution.first_shot,
                solution.light,
            )
            if len(texels) == 0:
                why = f"its UV map covers no texel centre at {size} px (unwrap it, or bake a larger image)"
                not_baked.append(dict(object=obj.name, why=why))
                continue
            steps.append(step)
            part, covered = bake.to_image(texels, values, size, size)
            img[covered] = part[covered]
            mask |= covered
            job.baked.append(obj)
        if not job.baked:
            return None
        img, mask = bake.dilate(img, mask, self.margin)
        img[..., 3] = mask
        return img

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        start = time.perf_counter()
        created: list[str] = []
        not_baked: list[dict] = []
        try:
            targets = polls.selected_meshes(context)
            solved = attributes.solved_atlases(context.scene)
            for o in targets:
                if o.name not in solved:
                    not_baked.append(
                        dict(object=o.name, why="not solved: generate an atlas and run Solve first")
                    )
            targets = [o for o in targets if o.name in solved]
            shared = []
            if self.atlas == "SHARED":
                if not lightmap_uv.is_auto(self.uv_map):
                    raise OvradError(
                        "a shared atlas bakes through UV maps ovrad makes: set UV Map to auto, or bake "
                        "per object"
                    )
                shared = [o for o in targets if not lightmap_atlas.linked(o)]
            own = [o for o in targets if o not in shared]
            # the scene, read once for this bake: the targets' meshes here, the solution's inputs below
            depsgraph = context.evaluated_depsgraph_get()
            model = scene_model.read_model(depsgraph, context.scene)
            if "{object}" not in self.filepath and len(own) + bool(shared) > 1:  # before any change
                raise OvradError("several images would be baked: put {object} in the file path")
            chosen = self.choose_maps(context, model, depsgraph, own, not_baked)
            atlases = self.shared_maps(context, model, depsgraph, shared, not_baked, len(chosen))
            if any(least for *_, least in chosen) or atlases:  # made UV maps: read the updated meshes
                depsgraph = context.evaluated_depsgraph_get()
            jobs = [
                Job([obj], uv_map, least, obj.name + names.IMAGE_SUFFIX, obj.name)
                for obj, uv_map, least in chosen
            ]
            names_of = lightmap_atlas.atlas_names(len(atlases))
            jobs += [
                Job(objs, lightmap_uv.LIGHTMAP_UV, size, name, name, shared=True)
                for (objs, size), name in zip(atlases, names_of, strict=True)
            ]
            jobs = [j for j in jobs if self.read_job(context, model, depsgraph, j, not_baked)]
            if not jobs:
                raise OvradError(
                    "; ".join(n["why"] for n in not_baked) or "nothing to bake: select the meshes to bake"
                )
            for job in jobs:
                job.path = image_files.resolve_path(self.filepath, job.file_name, self.file_format)
                image_files.prepare_folder(job.path, created)
            solution = load_solution(context, model)
            results, steps = [], []
            for job in jobs:
                img = self.bake_job(solution, job, not_baked, steps)
                if img is not None:
                    results.append((job, img))
            if not results:
                raise OvradError("; ".join(n["why"] for n in not_baked))
            entries = []
            for job, img in results:
                stored = bpy.path.relpath(job.path) if self.filepath.startswith("//") else job.path
                image = image_files.write_image(job.image_name, img, job.path, stored, self.file_format)
                exposure = image.get(names.PROP_EXPOSURE) if self.file_format == "PNG" else None
                for obj in job.baked:
                    obj[names.PROP_LIGHTMAP_IMAGE], obj[names.PROP_LIGHTMAP_UV_MAP] = image.name, job.uv_map
                    entries.append(
                        dict(
                            object=obj.name,
                            path=job.path,
                            uv_map=job.uv_map,
                            size=job.size,
                            format=self.file_format,
                            exposure=exposure,
                            image=image.name,
                        )
                    )
        except OvradError as e:
            image_files.remove_created(created)
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
        if any(e["image"] != e["object"] + names.IMAGE_SUFFIX for e in entries):
            listed += " (" + ", ".join(sorted({e["image"] for e in entries})) + ")"
        sparse = max(steps, default=1)
        note = f"; indirect light gathered at every {sparse} texels and interpolated" if sparse > 1 else ""
        self.report({"INFO"}, f"ovrad: baked {listed}{note} in {seconds:.2f} s")
        for listener in list(_LISTENERS):
            listener(dict(images=entries, not_baked=not_baked))
        return {"FINISHED"}


classes = (OVRAD_OT_bake_image,)
