"""scenes/cornell.blend matches the published Cornell box and rebuilds identically from its script."""

from __future__ import annotations

import numpy as np
import pytest

from blender_env import ROOT, run_blender

pytestmark = pytest.mark.blender

CORNELL = ROOT / "scenes" / "cornell.blend"

# The published data (mm, Y up), typed in again here so the test does not trust the script.
CARD = {
    "floor": [(552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)],
    "ceiling": [(556, 548.8, 0), (556, 548.8, 559.2), (0, 548.8, 559.2), (0, 548.8, 0)],
    "light": [(343, 548.8, 227), (343, 548.8, 332), (213, 548.8, 332), (213, 548.8, 227)],
    "back": [(549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)],
    "right": [(0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)],
    "left": [(552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)],
    "short_top": [(130, 165, 65), (82, 165, 225), (240, 165, 272), (290, 165, 114)],
    "short_sides": [
        [(290, 0, 114), (290, 165, 114), (240, 165, 272), (240, 0, 272)],
        [(130, 0, 65), (130, 165, 65), (290, 165, 114), (290, 0, 114)],
        [(82, 0, 225), (82, 165, 225), (130, 165, 65), (130, 0, 65)],
        [(240, 0, 272), (240, 165, 272), (82, 165, 225), (82, 0, 225)],
    ],
    "tall_top": [(423, 330, 247), (265, 330, 296), (314, 330, 456), (472, 330, 406)],
    "tall_sides": [
        [(423, 0, 247), (423, 330, 247), (472, 330, 406), (472, 0, 406)],
        [(472, 0, 406), (472, 330, 406), (314, 330, 456), (314, 0, 456)],
        [(314, 0, 456), (314, 330, 456), (265, 330, 296), (265, 0, 296)],
        [(265, 0, 296), (265, 330, 296), (423, 330, 247), (423, 0, 247)],
    ],
}
WALLS = ("Floor", "Ceiling", "BackWall", "LeftWall", "RightWall")
BLOCKS = ("ShortBlock", "TallBlock")
MESHES = (*WALLS, *BLOCKS, "Light")


def quad_area_m2(quad) -> float:
    """Area of a published quad in m², as two triangles (0, 1, 2) and (0, 2, 3)."""
    p = np.asarray(quad, float) / 1000.0
    tri = lambda a, b, c: 0.5 * np.linalg.norm(np.cross(p[b] - p[a], p[c] - p[a]))  # noqa: E731
    return tri(0, 1, 2) + tri(0, 2, 3)


def expected_areas() -> dict[str, float]:
    top = {k: quad_area_m2(CARD[f"{k}_top"]) for k in ("short", "tall")}
    return {
        "Floor": quad_area_m2(CARD["floor"]),
        "Ceiling": quad_area_m2(CARD["ceiling"]) - quad_area_m2(CARD["light"]),  # the light's hole
        "BackWall": quad_area_m2(CARD["back"]),
        "LeftWall": quad_area_m2(CARD["left"]),
        "RightWall": quad_area_m2(CARD["right"]),
        "Light": quad_area_m2(CARD["light"]),
        # A closed box: top, four sides and a bottom as large as the top.
        "ShortBlock": 2 * top["short"] + sum(quad_area_m2(q) for q in CARD["short_sides"]),
        "TallBlock": 2 * top["tall"] + sum(quad_area_m2(q) for q in CARD["tall_sides"]),
    }


def read_blend(path) -> dict:
    """Open a .blend and copy out what the tests check, as plain numpy data."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(path))
    out = {"objects": {o.name: o.type for o in bpy.data.objects}}
    for name in MESHES:
        obj = bpy.data.objects[name]
        mesh = obj.data
        mw = np.array(obj.matrix_world)
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3]
        mesh.calc_loop_triangles()
        tris = np.array([t.vertices[:] for t in mesh.loop_triangles])
        out[name] = {
            "co": co,
            "faces": [tuple(p.vertices) for p in mesh.polygons],
            "tris": tris,
            "materials": [m.name for m in mesh.materials],
        }
    return out


@pytest.fixture(scope="module")
def cornell():
    assert CORNELL.is_file(), "scenes/cornell.blend is missing: run scripts/make_cornell.py"
    return read_blend(CORNELL)


def face_normals_and_centres(data):
    co, faces = data["co"], data["faces"]
    normals, centres = [], []
    for f in faces:
        p = co[list(f)]
        n = sum(np.cross(p[i] - p[0], p[i + 1] - p[0]) for i in range(1, len(p) - 1))  # Newell-like
        normals.append(n / np.linalg.norm(n))
        centres.append(p.mean(axis=0))
    return np.array(normals), np.array(centres)


def test_objects(cornell):
    meshes = {n for n, t in cornell["objects"].items() if t == "MESH"}
    assert meshes == set(MESHES)
    assert [n for n, t in cornell["objects"].items() if t == "CAMERA"] == ["Camera"]
    assert len(cornell["objects"]) == 9


def test_walls_face_into_the_box_and_blocks_face_out(cornell):
    centre = np.array([0.0, 0.2796, 0.2744])  # middle of the box in Blender metres
    for name in WALLS:
        normals, centres = face_normals_and_centres(cornell[name])
        assert np.all(np.einsum("ij,ij->i", normals, centre - centres) > 0), name
    for name in BLOCKS:
        normals, centres = face_normals_and_centres(cornell[name])
        inside = cornell[name]["co"].mean(axis=0)
        assert len(normals) == 6, f"{name} is a closed box"
        assert np.all(np.einsum("ij,ij->i", normals, centres - inside) > 0), name
    normals, _ = face_normals_and_centres(cornell["Light"])
    np.testing.assert_allclose(normals, [[0, 0, -1]], atol=1e-9)


def test_areas_match_the_published_coordinates(cornell):
    for name, area in expected_areas().items():
        p = cornell[name]["co"][cornell[name]["tris"]]  # (triangles, 3 corners, xyz)
        got = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
        assert got.sum() == pytest.approx(area, rel=1e-5), name


def test_published_vertices_map_onto_the_scene(cornell):
    def to_blender(p):
        x, y, z = p
        return ((278 - x) / 1000, z / 1000, y / 1000)

    for name, key in (("Floor", "floor"), ("BackWall", "back"), ("LeftWall", "left"), ("Light", "light")):
        np.testing.assert_allclose(cornell[name]["co"], [to_blender(p) for p in CARD[key]], atol=1e-6)


def test_light_materials_world_camera(cornell):
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(CORNELL))  # other tests may have opened another file
    light = bpy.data.materials["Light"].node_tree
    out = next(n for n in light.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    emit = out.inputs["Surface"].links[0].from_node
    assert emit.bl_idname == "ShaderNodeEmission"
    radiance = np.array(emit.inputs["Color"].default_value[:3]) * emit.inputs["Strength"].default_value
    np.testing.assert_allclose(radiance, [17, 12, 4], rtol=1e-6)

    colours = {"White": (0.725, 0.71, 0.68), "Red": (0.63, 0.065, 0.05), "Green": (0.14, 0.45, 0.091)}
    for name, colour in colours.items():
        nodes = bpy.data.materials[name].node_tree.nodes
        bsdf = next(n for n in nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
        np.testing.assert_allclose(bsdf.inputs["Base Color"].default_value[:3], colour, rtol=1e-6)
        assert bsdf.inputs["Roughness"].default_value == 1.0
        assert bsdf.inputs["Specular IOR Level"].default_value == 0.0
    assert cornell["LeftWall"]["materials"] == ["Red"] and cornell["RightWall"]["materials"] == ["Green"]

    scene = bpy.context.scene
    assert scene.render.engine == "CYCLES"
    assert (scene.render.resolution_x, scene.render.resolution_y) == (512, 512)
    bg = next(n for n in scene.world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
    assert bg.inputs["Strength"].default_value == 0.0
    assert tuple(bg.inputs["Color"].default_value[:3]) == (0, 0, 0)

    cam = scene.camera
    assert cam.name == "Camera"
    np.testing.assert_allclose(cam.matrix_world.translation, (0.0, -0.8, 0.273), atol=1e-7)
    view = np.array(cam.matrix_world.to_3x3()) @ (0, 0, -1)
    np.testing.assert_allclose(view, (0, 1, 0), atol=1e-7)
    assert (cam.data.lens, cam.data.sensor_width, cam.data.sensor_fit) == (35.0, 25.0, "AUTO")


def test_rebuild_is_identical(cornell, tmp_path):
    out = tmp_path / "cornell.blend"
    args = ["-b", "--python-exit-code", "1", "--python", "scripts/make_cornell.py", "--", "--output", out]
    proc = run_blender(args, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    rebuilt = read_blend(out)
    assert rebuilt["objects"] == cornell["objects"]
    for name in MESHES:
        np.testing.assert_array_equal(rebuilt[name]["co"], cornell[name]["co"], err_msg=name)
        assert rebuilt[name]["faces"] == cornell[name]["faces"], name
