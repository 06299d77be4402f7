"""Registration and the sidebar panel: what the extension adds to Blender, and that it all goes away again."""

from __future__ import annotations

import pytest

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender


class Layout:
    """Stands in for a UILayout: records what draw() shows and checks every property it names exists."""

    def __init__(self, shown):
        self.shown = shown
        self.use_property_split = self.use_property_decorate = False

    def column(self, **_):
        return self

    box = row = column

    def prop(self, data, name, **_):
        assert name in data.bl_rna.properties, name
        self.shown.append(("prop", name))

    def operator(self, idname, **_):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        self.shown.append(("operator", idname))

    def label(self, text="", **_):
        self.shown.append(("label", text))

    def separator(self, **_):
        pass


def draw_panel(ovrad):
    shown = []
    panel = type("P", (), {"layout": Layout(shown)})()
    ovrad.ui.panel.OVRAD_PT_main.draw(panel, bpy.context)
    return shown


def test_panel_shows_settings_generate_and_the_active_objects_overrides(ovrad, fresh_scene):
    bpy.ops.mesh.primitive_cube_add()
    shown = draw_panel(ovrad)
    assert ("operator", "ovrad.generate_atlas") in shown
    for name in ("size_mode", "patch_count", "overlap", "beta", "shapes", "max_patches", "display_quantity"):
        assert ("prop", name) in shown
    assert ("prop", "density") in shown and ("prop", "sides") in shown
    fresh_scene.ovrad.patch_count = 100
    bpy.ops.ovrad.generate_atlas()
    (atlas,) = [o for o in bpy.data.objects if "ovrad_source" in o]
    atlas.select_set(True)
    labels = [text for kind, text in draw_panel(ovrad) if kind == "label"]
    n = len(atlas.data.vertices)
    assert f"{n:,} patches in 1 atlas object(s)" in labels
    assert f"{atlas.name}: {n:,} patches, beta smooth" in labels


def test_panel_is_in_the_3d_view_sidebar(ovrad):
    panel = ovrad.ui.panel.OVRAD_PT_main
    assert (panel.bl_space_type, panel.bl_region_type, panel.bl_category) == ("VIEW_3D", "UI", "ovrad")
    assert hasattr(bpy.types, "OVRAD_PT_main")


def test_disabling_removes_everything_the_extension_registered(ovrad):
    import addon_utils

    name = ovrad.__name__
    try:
        addon_utils.disable(name, default_set=False)
        assert not hasattr(bpy.types.Scene, "ovrad") and not hasattr(bpy.types.Object, "ovrad")
        for cls in ("OVRAD_OT_generate_atlas", "OVRAD_OT_set_display", "OVRAD_PT_main", "OVRAD_PG_settings"):
            assert not hasattr(bpy.types, cls), cls
    finally:
        addon_utils.enable(name, default_set=False)
    assert (
        hasattr(bpy.types.Scene, "ovrad")
        and bpy.ops.ovrad.generate_atlas.idname() == "OVRAD_OT_generate_atlas"
    )
