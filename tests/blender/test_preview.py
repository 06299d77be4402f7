"""Preview of a vertex bake: materials show the baked attribute as emission, and a second press puts
every material, slot and mesh back exactly as it was."""

from __future__ import annotations

import blender_scenes
import pytest

bpy = pytest.importorskip("bpy")
bmesh = pytest.importorskip("bmesh")

pytestmark = pytest.mark.blender


def principled(name, base=(0.6, 0.6, 0.6), emission=0.0):
    return blender_scenes.principled(name, base, emission)


def mesh_object(name, make):
    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    make(bm)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def box(bm):
    bmesh.ops.create_cube(bm, size=2.0)
    bmesh.ops.subdivide_edges(bm, edges=bm.edges[:], cuts=2, use_grid_fill=True)
    bmesh.ops.reverse_faces(bm, faces=bm.faces[:])


def card(bm):
    bmesh.ops.create_grid(bm, x_segments=2, y_segments=2, size=0.3)
    bmesh.ops.translate(bm, verts=bm.verts[:], vec=(0.0, 0.0, -0.5))


select = blender_scenes.select


def snapshot():
    """Every material's nodes, links and output flags; every object's slots; every mesh's materials."""
    mats = {}
    for m in bpy.data.materials:
        tree = m.node_tree
        nodes = sorted(
            (n.name, n.bl_idname, getattr(n, "target", None), getattr(n, "is_active_output", None))
            for n in tree.nodes
        )
        links = sorted(
            (lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier)
            for lk in tree.links
        )
        mats[m.name] = (nodes, links, sorted(m.keys()))
    slots = {
        o.name: [(s.link, getattr(s.material, "name", None)) for s in o.material_slots]
        for o in bpy.data.objects
    }
    meshes = {
        me.name: ([getattr(m, "name", None) for m in me.materials], sorted(me.keys()))
        for me in bpy.data.meshes
    }
    objects = {o.name: sorted(o.keys()) for o in bpy.data.objects}
    return mats, slots, meshes, objects


@pytest.fixture
def baked(ovrad, fresh_scene):
    """A glowing box (one material), a card inside it with a second material output for EEVEE and an
    empty slot, and a bare floor card without any material: all solved and baked."""
    fresh_scene.ovrad.patch_count = 200
    room = mesh_object("Room", box)
    room.data.materials.append(principled("Walls", emission=1.0))
    inner = mesh_object("Card", card)
    mat = principled("CardMat", base=(0.2, 0.5, 0.8))
    eevee = mat.node_tree.nodes.new("ShaderNodeOutputMaterial")
    eevee.target = "EEVEE"
    mat.node_tree.links.new(mat.node_tree.nodes["Principled BSDF"].outputs[0], eevee.inputs["Surface"])
    inner.data.materials.append(mat)
    inner.data.materials.append(None)
    bare = mesh_object(
        "Bare", lambda bm: (card(bm), bmesh.ops.translate(bm, verts=bm.verts[:], vec=(0, 0, 0.8)))
    )
    select(room, inner, bare)
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex() == {"FINISHED"}
    return room, inner, bare


def surface_source(mat, output):
    return output.inputs["Surface"].links[0].from_node


@pytest.mark.versions
def test_preview_shows_the_bake_and_the_second_press_restores_everything(baked, ovrad):
    room, inner, bare = baked
    before = snapshot()
    assert bpy.ops.ovrad.preview() == {"FINISHED"}
    assert ovrad.operators.preview.is_active()
    # Every output of every receiver material (the EEVEE one too) shows Attribute -> Emission.
    for mat in (bpy.data.materials["Walls"], bpy.data.materials["CardMat"]):
        outputs = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
        assert outputs
        for out in outputs:
            emit = surface_source(mat, out)
            assert emit.bl_idname == "ShaderNodeEmission"
            attr = emit.inputs["Color"].links[0].from_node
            assert (attr.bl_idname, attr.attribute_name) == ("ShaderNodeAttribute", "ovrad_radiance")
    # The empty slot and the mesh without materials get the preview material.
    assert inner.material_slots[1].material is not None
    assert len(bare.material_slots) == 1 and bare.material_slots[0].material is not None
    assert bpy.ops.ovrad.preview() == {"FINISHED"}
    assert not ovrad.operators.preview.is_active()
    assert snapshot() == before


def test_preview_restore_survives_a_deleted_node(baked, ovrad):
    before = snapshot()
    bpy.ops.ovrad.preview()
    tree = bpy.data.materials["CardMat"].node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])  # the user deletes what was linked
    assert bpy.ops.ovrad.preview() == {"FINISHED"}
    mats, slots, meshes, _ = snapshot()
    assert slots == before[1] and meshes == before[2]
    assert mats["Walls"] == before[0]["Walls"]
    names = [n[0] for n in mats["CardMat"][0]]
    assert not any(n.startswith("ovrad preview") for n in names)


def test_preview_without_a_bake_is_refused_and_changes_nothing(ovrad, fresh_scene):
    bpy.ops.mesh.primitive_cube_add()
    before = snapshot()
    with pytest.raises(RuntimeError, match="bake vertex colours first"):
        bpy.ops.ovrad.preview()
    assert snapshot() == before


@pytest.mark.versions
def test_preview_follows_the_chosen_attribute(baked, ovrad):
    bpy.ops.ovrad.bake_vertex(attribute="irr", quantity="IRRADIANCE")
    bpy.context.scene.ovrad.bake_attribute = "irr"
    bpy.ops.ovrad.preview()
    mat = bpy.data.materials["Walls"]
    out = next(n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    assert surface_source(mat, out).inputs["Color"].links[0].from_node.attribute_name == "irr"
    bpy.ops.ovrad.preview()
