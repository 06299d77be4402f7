"""Build scenes/cornell.blend, the Cornell box from the published data (run with scripts/blender -b -P)."""

# Usage: scripts/blender -b --python scripts/make_cornell.py -- --output scenes/cornell.blend
# Data: the Cornell Program of Computer Graphics' box (see shared/design/cornell.md), in mm with
# Y up; each point maps to Blender metres as (278 - x, z, y) / 1000, a proper rotation, so the
# published vertex orders keep their sense: walls face into the box, blocks face out of
# themselves, the light faces down. The build is deterministic: same input, same vertices.

import argparse
import math
import os
import sys

import bpy

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)
LIGHT_RADIANCE = (17.0, 12.0, 4.0)

FLOOR = [(552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)]
CEILING = [(556, 548.8, 0), (556, 548.8, 559.2), (0, 548.8, 559.2), (0, 548.8, 0)]
LIGHT = [(343, 548.8, 227), (343, 548.8, 332), (213, 548.8, 332), (213, 548.8, 227)]
BACK = [(549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)]
RIGHT = [(0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)]
LEFT = [(552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)]
SHORT_TOP = [(130, 165, 65), (82, 165, 225), (240, 165, 272), (290, 165, 114)]
SHORT_SIDES = [
    [(290, 0, 114), (290, 165, 114), (240, 165, 272), (240, 0, 272)],
    [(130, 0, 65), (130, 165, 65), (290, 165, 114), (290, 0, 114)],
    [(82, 0, 225), (82, 165, 225), (130, 165, 65), (130, 0, 65)],
    [(240, 0, 272), (240, 165, 272), (82, 165, 225), (82, 0, 225)],
]
TALL_TOP = [(423, 330, 247), (265, 330, 296), (314, 330, 456), (472, 330, 406)]
TALL_SIDES = [
    [(423, 0, 247), (423, 330, 247), (472, 330, 406), (472, 0, 406)],
    [(472, 0, 406), (472, 330, 406), (314, 330, 456), (314, 0, 456)],
    [(314, 0, 456), (314, 330, 456), (265, 330, 296), (265, 0, 296)],
    [(265, 0, 296), (265, 330, 296), (423, 330, 247), (423, 0, 247)],
]
CAMERA_MM = (278, 273, -800)


def to_blender(p):
    """Published mm (x, y, z), Y up -> Blender metres (278 - x, z, y) / 1000, Z up."""
    x, y, z = p
    return ((278.0 - x) / 1000.0, z / 1000.0, y / 1000.0)


def ceiling_with_hole():
    """The ceiling as four faces around the light's opening, so ceiling and light never overlap.

    Outer corners i and light corners i are in the same turning order, so each face
    (outer i, outer i+1, light i+1, light i) keeps the ceiling's facing (down).
    """
    faces = [[CEILING[i], CEILING[(i + 1) % 4], LIGHT[(i + 1) % 4], LIGHT[i]] for i in range(4)]
    return faces


def block(top, sides):
    """A closed box as a modeller's cube has it: top, four sides and a bottom on the floor."""
    bottom = [(x, 0, z) for (x, _, z) in reversed(top)]  # reversed: faces down, out of the block
    return [top, *sides, bottom]


def mesh_object(name, faces_mm, material):
    """One object whose mesh welds the faces' shared corners; object transform is identity."""
    index: dict[tuple, int] = {}
    verts, faces = [], []
    for face in faces_mm:
        loop = []
        for p in face:
            key = tuple(float(c) for c in p)
            if key not in index:  # first-seen order: the same on every run
                index[key] = len(verts)
                verts.append(to_blender(key))
            loop.append(index[key])
        faces.append(loop)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    if mesh.validate(verbose=True):
        raise RuntimeError(f"{name}: invalid mesh data")
    mesh.update()
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def node_tree(material):
    """The material's node tree (Blender 5 always has one; 4.x needs use_nodes)."""
    if material.node_tree is None:
        material.use_nodes = True
    return material.node_tree


def diffuse_material(name, colour):
    """Principled BSDF as a plain Lambert surface: base colour, roughness 1, no specular."""
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)  # viewport colour
    mat.roughness = 1.0
    mat.specular_intensity = 0.0
    bsdf = next(n for n in node_tree(mat).nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = 1.0
    # Blender 4.0 renamed "Specular" to "Specular IOR Level".
    spec = bsdf.inputs.get("Specular IOR Level") or bsdf.inputs.get("Specular")
    spec.default_value = 0.0
    return mat


def emission_material(name, radiance):
    """Emission shader with colour x strength = the published radiance (strength = largest channel)."""
    strength = max(radiance)
    colour = tuple(c / strength for c in radiance)
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)
    tree = node_tree(mat)
    for n in list(tree.nodes):
        if n.bl_idname != "ShaderNodeOutputMaterial":
            tree.nodes.remove(n)
    out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    emit = tree.nodes.new("ShaderNodeEmission")
    emit.location = (out.location.x - 250, out.location.y)
    emit.inputs["Color"].default_value = (*colour, 1.0)
    emit.inputs["Strength"].default_value = strength
    tree.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    return mat


def black_world(scene):
    """World colour black at strength 0: the light quad is the only source."""
    world = bpy.data.worlds.new("World")
    world.color = (0.0, 0.0, 0.0)
    tree = node_tree(world)
    bg = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bg.inputs["Strength"].default_value = 0.0
    scene.world = world


def camera(scene):
    """35 mm lens on 25 mm film at (278, 273, -800) mm looking along +z (Blender +Y), Z up."""
    cam = bpy.data.cameras.new("Camera")
    cam.lens = 35.0
    cam.sensor_width = 25.0
    cam.sensor_height = 25.0
    cam.sensor_fit = "AUTO"
    obj = bpy.data.objects.new("Camera", cam)
    obj.location = to_blender(CAMERA_MM)
    obj.rotation_euler = (math.pi / 2.0, 0.0, 0.0)  # local -Z (view) -> +Y, local +Y -> +Z
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def build():
    """Replace the open file's data with the Cornell box; returns the scene."""
    # A fresh factory file (not the user's startup file), preferences untouched.
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.name = "Cornell"
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.render.engine = "CYCLES"
    scene.render.resolution_x = 512
    scene.render.resolution_y = 512
    scene.render.resolution_percentage = 100

    white = diffuse_material("White", WHITE)
    red = diffuse_material("Red", RED)
    green = diffuse_material("Green", GREEN)
    light = emission_material("Light", LIGHT_RADIANCE)

    mesh_object("Floor", [FLOOR], white)
    mesh_object("Ceiling", ceiling_with_hole(), white)
    mesh_object("BackWall", [BACK], white)
    mesh_object("LeftWall", [LEFT], red)
    mesh_object("RightWall", [RIGHT], green)
    mesh_object("ShortBlock", block(SHORT_TOP, SHORT_SIDES), white)
    mesh_object("TallBlock", block(TALL_TOP, TALL_SIDES), white)
    mesh_object("Light", [LIGHT], light)
    black_world(scene)
    camera(scene)
    return scene


def main(argv):
    parser = argparse.ArgumentParser(prog="make_cornell.py", description=__doc__)
    parser.add_argument("--output", required=True, help="the .blend file to write")
    args = parser.parse_args(argv)
    build()
    out = os.path.abspath(args.output)
    os.makedirs(os.path.dirname(out), exist_ok=True)
    # compress: a smaller file to commit; no backup .blend1 next to it.
    bpy.ops.wm.save_as_mainfile(filepath=out, compress=True, check_existing=False)
    backup = out + "1"
    if os.path.exists(backup):
        os.remove(backup)
    print(f"wrote {out} ({os.path.getsize(out)} bytes, {len(bpy.data.objects)} objects)")


if __name__ == "__main__":
    # Blender passes its own arguments too; the script's follow "--".
    main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else [])
