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
        return type("Props", (), {})()

    def label(self, text="", **_):
        self.shown.append(("label", text))

    def separator(self, **_):
        pass


def draw_panel(ovrad):
    """What the main panel and all its sub-panels show (collapsed ones included)."""
    shown = []
    for cls in ovrad.ui.panel.classes:
        panel = type("P", (), {"layout": Layout(shown)})()
        cls.draw(panel, bpy.context)
    return shown


@pytest.mark.versions
def test_every_setting_is_reachable_from_the_panel(ovrad, fresh_scene):
    bpy.ops.mesh.primitive_cube_add()
    props = fresh_scene.ovrad
    shown = set()
    for size_mode in ("COUNT", "SIZE"):
        for target in ("VERTEX", "IMAGE"):
            props.size_mode, props.bake_target = size_mode, target
            shown |= {name for kind, name in draw_panel(ovrad) if kind == "prop"}
    everything = {p.identifier for p in props.bl_rna.properties}
    everything |= {p.identifier for p in bpy.context.active_object.ovrad.bl_rna.properties}
    everything -= {"rna_type", "name"}
    assert everything <= shown, sorted(everything - shown)


def test_sub_panels_sit_under_the_main_panel_with_the_expert_settings_collapsed(ovrad):
    panel = ovrad.ui.panel
    subs = [cls for cls in panel.classes if cls is not panel.OVRAD_PT_main]
    assert [cls.bl_label for cls in subs] == ["Atlas", "Solve", "Bake", "Display", "Advanced"]
    assert all(cls.bl_parent_id == "OVRAD_PT_main" for cls in subs)
    assert panel.OVRAD_PT_advanced.bl_options == {"DEFAULT_CLOSED"}
    assert all(hasattr(bpy.types, cls.bl_idname) for cls in panel.classes)
    shown = []
    advanced = type("P", (), {"layout": Layout(shown)})()
    panel.OVRAD_PT_advanced.draw(advanced, bpy.context)
    expert = (
        "solve_tolerance",
        "solve_rule",
        "rays_per_point",
        "min_rays",
        "max_rays",
        "cluster_angle",
        "max_patches",
    )
    assert [name for kind, name in shown if kind == "prop"] == list(expert)


@pytest.mark.versions
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


def test_quality_sets_its_levels_settings_and_shows_custom_once_one_is_changed(ovrad, fresh_scene):
    props = fresh_scene.ovrad
    assert props.quality == "MEDIUM"  # the defaults are the medium level
    shown = draw_panel(ovrad)
    assert ("prop", "quality") in shown and ("prop", "gather_rays") in shown
    for level, settings in ovrad.operators.properties.QUALITY.items():
        props.quality = level
        assert {k: getattr(props, k) for k in settings} == settings and props.quality == level
    props.gather_rays = 0  # an expert setting overrides the level
    assert (
        props.quality == "CUSTOM"
        and props.patch_count == ovrad.operators.properties.QUALITY["HIGH"]["patch_count"]
    )
    props.quality = "CUSTOM"  # changes nothing
    assert props.gather_rays == 0


def test_panel_is_in_the_3d_view_sidebar(ovrad):
    panel = ovrad.ui.panel.OVRAD_PT_main
    assert (panel.bl_space_type, panel.bl_region_type, panel.bl_category) == ("VIEW_3D", "UI", "ovrad")
    assert hasattr(bpy.types, "OVRAD_PT_main")


@pytest.mark.versions
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
