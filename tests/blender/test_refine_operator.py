"""Refine Atlas (operators/refine.py) as a user drives it: after a solve, smaller patches where the
light varies, written as Generate writes atlases (their C kept), solved again; undo; refused before
a solve."""

from __future__ import annotations

import numpy as np
import pytest
from test_solve_kept_c import atlas_objects, build, patches, solve

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

ATLASES = ("Floor_ovrad_atlas", "Box_ovrad_atlas")


def radii(name):
    mesh = bpy.data.objects[name].data
    out = np.empty(len(mesh.vertices), np.float32)
    mesh.attributes["ovrad_radius"].data.foreach_get("value", out)
    return out


def centres(name):
    mesh = bpy.data.objects[name].data
    out = np.empty(3 * len(mesh.vertices), np.float32)
    mesh.vertices.foreach_get("co", out)
    return out.reshape(-1, 3)


def test_refine_before_a_solve_is_refused_and_changes_nothing(ovrad, fresh_scene):
    build()
    before = {o.name: len(o.data.vertices) for o in atlas_objects()}
    with pytest.raises(RuntimeError, match="no solution to refine from: press Solve first"):
        bpy.ops.ovrad.refine_atlas()
    assert {o.name: len(o.data.vertices) for o in atlas_objects()} == before


def test_refine_puts_smaller_patches_where_the_light_varies(ovrad, fresh_scene):
    build()  # a floor lit by a point lamp, a box standing on it: its shadow and its foot
    stats, _ = solve(ovrad)
    first = {n: len(radii(n)) for n in ATLASES}
    base = {n: float(np.median(radii(n))) for n in ATLASES}
    old = {
        tuple(np.round(np.r_[c, r], 5)) for c, r in zip(centres(ATLASES[0]), radii(ATLASES[0]), strict=True)
    }
    bpy.ops.ed.undo_push(message="Solve")
    assert bpy.ops.ovrad.refine_atlas() == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Refine Atlas")
    floor_r, floor_c = radii(ATLASES[0]), centres(ATLASES[0])
    assert len(floor_r) > first[ATLASES[0]]
    new = np.array(
        [tuple(np.round(np.r_[c, r], 5)) not in old for c, r in zip(floor_c, floor_r, strict=True)]
    )
    assert new.sum() > 20 and np.all(floor_r[new] <= 0.75 * base[ATLASES[0]])
    # the lamp at (0.5, -0.5, 2.5) throws the 1 m box's shadow from y = 0.7 to y = 1.5 behind it
    # (0.1 < x < 1.5): new, smaller patches line that far edge; the floor's lit corner x > 1.3, y < -1.2
    # (no shadow of the box or the card reaches it) keeps its patches
    edge = (np.abs(floor_c[:, 1] - 1.5) < 0.3) & (floor_c[:, 0] > 0.2) & (floor_c[:, 0] < 1.3)
    assert new[edge].sum() >= 3
    corner = (floor_c[:, 0] > 1.3) & (floor_c[:, 1] < -1.2)
    assert corner.sum() >= 3 and not new[corner].any()
    # written as Generate writes them: every attribute, C kept on the edges, the base radius kept
    for name in ATLASES:
        obj = bpy.data.objects[name]
        assert obj["ovrad_base_radius"] == pytest.approx(base[name], rel=1e-6)
        assert "ovrad_overlap_key" in obj.data and len(obj.data.edges) > 0
    # solving the refined atlas uses that C and gives light everywhere it gave it before
    again, radiosity = solve(ovrad)
    assert again["overlaps_kept"] >= patches(*ATLASES)
    assert all(np.all(np.isfinite(v)) for v in radiosity.values())
    # a second refinement goes one level deeper, never below a quarter of the generated radius
    assert bpy.ops.ovrad.refine_atlas() == {"FINISHED"}
    assert radii(ATLASES[0]).min() >= 0.25 * base[ATLASES[0]] * (1 - 1e-5)
    bpy.ops.ed.undo_push(message="Refine Atlas")
    # undo puts back the atlas as it was
    bpy.ops.ed.undo()
    bpy.ops.ed.undo()
    assert {n: len(radii(n)) for n in ATLASES} == first
