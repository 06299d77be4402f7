"""An atlas finds its sheets again: from the triangle and side each patch stores, through Blender's
float32 attributes, on a doorway partition and on a messy production-like mesh; every receiver
gets patches."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

import scenes
from ovrad_addon import names
from ovrad_addon.atlas.clutter import chart_objects
from ovrad_addon.atlas.index import index_surfaces
from ovrad_addon.atlas.patches import Atlas
from ovrad_addon.errors import OvradError
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.radiosity.problem import attach_sheets, both_sides_index, located_sheets
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings


def _ring(outer, inner, axis_u, axis_v, origin, flip):
    """A rectangle with a rectangular hole as 8 triangles, in the plane origin + u axis_u + v axis_v.
    outer, inner: (u0, v0, u1, v1)."""
    o, a, b = (np.asarray(x, float) for x in (origin, axis_u, axis_v))
    (U0, V0, U1, V1), (u0, v0, u1, v1) = outer, inner
    uv = [(U0, V0), (U1, V0), (U1, V1), (U0, V1), (u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    v = np.array([o + p * a + q * b for p, q in uv])
    t = []
    for i in range(4):
        j = (i + 1) % 4
        t += [(i, j, 4 + j), (i, 4 + j, 4 + i)]
    t = np.array(t)
    return v, (t[:, ::-1] if flip else t)


def doorway() -> Surfaces:
    """A 4 x 3 m partition 0.2 m thick (two parallel faces with the same 1 x 2 m hole, four
    reveal faces between) standing on a floor."""
    outer, hole = (-2.0, 0.0, 2.0, 3.0), (-0.5, 0.0, 0.5, 2.0)
    hole = (-0.5, 0.3, 0.5, 2.0)  # a sill: the hole is closed on all four sides
    front = _ring(outer, hole, (1, 0, 0), (0, 0, 1), (0, 0, 0), flip=False)  # normal -y
    back = _ring(outer, hole, (1, 0, 0), (0, 0, 1), (0, 0.2, 0), flip=True)  # normal +y
    u0, v0, u1, v1 = hole
    reveals = [
        scenes.quad((u0, 0, v0), (u1, 0, v0), (u1, 0.2, v0), (u0, 0.2, v0)),  # sill, up
        scenes.quad((u0, 0, v1), (u0, 0.2, v1), (u1, 0.2, v1), (u1, 0, v1)),  # lintel, down
        scenes.quad((u0, 0, v0), (u0, 0.2, v0), (u0, 0.2, v1), (u0, 0, v1)),  # left jamb, +x
        scenes.quad((u1, 0, v0), (u1, 0, v1), (u1, 0.2, v1), (u1, 0.2, v0)),  # right jamb, -x
    ]
    floor = scenes.quad((-3, -2, -0.001), (3, -2, -0.001), (3, 2, -0.001), (-3, 2, -0.001))
    v, t, o = scenes.merge([front, back, *reveals, floor], obj=[0] * 6 + [1])
    return Surfaces.from_arrays(v, t, o, object_names=["partition", "floor"])


def messy(seed: int = 3) -> Surfaces:
    """What real models bring, in numpy: hundreds of tiny separate pieces (bent open leaves,
    tiny cubes, intersecting), thin open shells, non-manifold fins, zero-area triangles, a
    sphere through a box, in a room; four objects."""
    rng = np.random.default_rng(seed)
    parts, objs = [], []
    room = scenes.box_faces((-1.5, -1.5, 0), (1.5, 1.5, 2), inward=True)
    parts += room
    objs += [0] * len(room)
    for _ in range(300):  # leaves: open, curved, tiny next to the patch spacing
        size, bend = rng.uniform(0.01, 0.06), rng.uniform(0.1, 0.6)
        v, t = scenes.bent_leaf(rng, size, bend / 2, 3)
        parts.append((v + [rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.05, 1)], t))
        objs.append(1)
    for _ in range(200):  # tiny cubes, closed, some intersecting each other
        lo = np.array([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.uniform(0.0, 0.5)])
        cube = scenes.box_faces(lo, lo + rng.uniform(0.005, 0.05))
        parts += cube
        objs += [2] * len(cube)
    # thin open shells: tubes without caps, one inside the other 1 mm apart
    th = np.linspace(0, 2 * np.pi, 25)[:-1]
    for r in (0.2, 0.201):
        ring = np.stack([r * np.cos(th), r * np.sin(th)], 1)
        v = np.concatenate([np.column_stack([ring, np.zeros(24)]), np.column_stack([ring, np.full(24, 0.6)])])
        i = np.arange(24)
        j = (i + 1) % 24
        t = np.concatenate([np.stack([i, j, 24 + j], 1), np.stack([i, 24 + j, 24 + i], 1)])
        parts.append((v + [0.8, 0.8, 0], t))
        objs.append(3)
    sph = scenes.sphere(0.3, 2)
    parts.append((sph.vertices + [-0.8, 0.8, 0.3], sph.triangles))
    objs.append(3)
    box = scenes.box_faces((-1.0, 0.6, 0.0), (-0.6, 1.0, 0.4))
    parts += box
    objs += [3] * len(box)
    # non-manifold fins on leaf edges, and zero-area triangles (collinear, coincident)
    fins = []
    for k in range(20):
        v, t = parts[len(room) + k]
        e0, e1 = v[t[0, 0]], v[t[0, 1]]
        fins.append((np.array([e0, e1, (e0 + e1) / 2 + [0, 0, 0.02]]), np.array([[0, 1, 2]])))
    p = np.array([0.1, 0.2, 0.3])
    fins += [
        (np.array([p, p + 0.01, p + 0.02]), np.array([[0, 1, 2]])),
        (np.array([p, p, p]), np.array([[0, 1, 2]])),
    ]
    parts += fins
    objs += [1] * len(fins)
    v, t, o = scenes.merge(parts, obj=objs)
    em = np.zeros((len(t), 3))
    em[o == 0] = 0.0
    return Surfaces.from_arrays(v, t, o, emission=em, object_names=["room", "leaves", "cubes", "shells"])


def blender_round_trip(atlas: Atlas, source_object=None) -> Atlas:
    """What writing the atlas as a Blender point cloud and reading it back does: float32
    positions and FLOAT attributes, int32 INT attributes; sheets are not trusted afterwards."""
    attrs = {}
    for name, (a, kind) in atlas.point_attributes().items():
        attrs[name] = np.asarray(a, np.float32 if kind.startswith("FLOAT") else np.int32)
    attrs[names.SHEET] = np.full(len(atlas), -7, np.int32)
    return Atlas.from_point_attributes(
        atlas.centers.astype(np.float32),
        attrs,
        atlas.beta,
        atlas.source_object if source_object is None else source_object,
    )


def solve_index(surfaces: Surfaces, atlas: Atlas | None = None):
    """The index prepare() builds: every side of every object has a sheet, and the clutter
    charts are those the atlas was made with."""
    return both_sides_index(surfaces, atlas=atlas)


def sheet_keys(index, sheet):
    """(chart, side) of sheets, (-1 - object, side) for clutter sheets: what stays the same
    between indexes of the same surfaces."""
    obj = chart_objects(index.surfaces, index.charts)[index.sheet_chart[sheet]]
    key = np.where(index.sheet_clutter[sheet], -1 - obj, index.sheet_chart[sheet])
    return np.stack([key, index.sheet_side[sheet]], 1)


def check_reattached(surfaces: Surfaces, settings: AtlasSettings):
    atlas = build_atlas(surfaces, settings)
    built = index_surfaces(surfaces, settings)
    assert atlas.triangle is not None and atlas.side is not None
    index = solve_index(surfaces, atlas)
    back = attach_sheets(blender_round_trip(atlas), index)
    np.testing.assert_array_equal(sheet_keys(index, back.sheet), sheet_keys(built, atlas.sheet))
    return atlas, built, index


def test_doorway_border_squares_find_their_sheet():
    s = doorway()
    settings = AtlasSettings(patch_size=0.3, shapes="AUTO")
    atlas, built, index = check_reattached(s, settings)
    # Border squares whose centres lie in the doorway exist: no surface under their centre.
    n = atlas.normals
    lift = atlas.thickness * 1.0001 + 1e-9 * s.extent
    _, tri = built.rays.closest_hit(atlas.centers + lift[:, None] * n, -n, 2.0 * lift)
    in_hole = (
        (np.abs(atlas.centers[:, 0]) < 0.5)
        & (atlas.centers[:, 2] > 0.3)
        & (atlas.centers[:, 2] < 2.0)
        & (atlas.centers[:, 1] > -1e-6)
        & (atlas.centers[:, 1] < 0.2 + 1e-6)
    )
    in_hole &= np.abs(atlas.normals[:, 1]) > 0.99  # on the partition's faces, not the reveals
    assert in_hole.sum() >= 4
    assert np.all(tri[in_hole] < 0)
    assert np.all(atlas.shapes[in_hole] == names.SHAPE_SQUARE)


def test_doorway_legacy_search_agrees_where_it_finds_a_sheet():
    s = doorway()
    atlas = build_atlas(s, AtlasSettings(patch_size=0.3))
    index = solve_index(s)
    legacy = replace(blender_round_trip(atlas), triangle=None, side=None)
    found = located_sheets(legacy, index)
    stored = attach_sheets(blender_round_trip(atlas), index).sheet
    ok = found >= 0
    assert ok.mean() > 0.9
    np.testing.assert_array_equal(found[ok], stored[ok])
    # and an old atlas (no triangle attribute) still attaches through the search
    attrs = {k: v for k, (v, _) in atlas.point_attributes().items() if k not in (names.TRIANGLE, names.SIDE)}
    old = Atlas.from_point_attributes(atlas.centers, attrs, atlas.beta, atlas.source_object)
    assert old.triangle is None
    if ok.all():
        np.testing.assert_array_equal(attach_sheets(old, index).sheet, stored)


def test_messy_mesh_every_receiver_gets_patches_and_every_patch_is_found_again():
    s = messy()
    atlas, built, index = check_reattached(s, AtlasSettings(patch_count=600))
    got = np.bincount(atlas.source_object, minlength=len(s.object_names))
    assert np.all(got > 0), dict(zip(s.object_names, got, strict=True))
    assert np.all(atlas.support_area > 0)


def test_stored_triangles_survive_other_objects_changing():
    s = messy()
    atlas = build_atlas(s, AtlasSettings(patch_count=400))
    built = index_surfaces(s, AtlasSettings(patch_count=400))
    # The scene read again with an extra object first and the objects in another order.
    extra_v, extra_t = scenes.quad((5, 5, 5), (6, 5, 5), (6, 6, 5), (5, 6, 5))
    perm = np.array([2, 0, 3, 1])  # old object k is new object perm[k] + 1
    parts_v, parts_t, parts_o = [extra_v], [extra_t], [np.zeros(2, np.int64)]
    base = len(extra_v)
    for new in range(4):
        old = int(np.flatnonzero(perm == new)[0])
        mask = s.object_index == old
        parts_v.append(s.vertices)
        parts_t.append(s.triangles[mask] + base)
        parts_o.append(np.full(mask.sum(), new + 1))
        base += len(s.vertices)
    s2 = Surfaces.from_arrays(
        np.concatenate(parts_v),
        np.concatenate(parts_t),
        np.concatenate(parts_o),
        object_names=["extra", *"abcd"],
    )
    read = blender_round_trip(atlas, perm[atlas.source_object] + 1)
    index = solve_index(s2, read)
    back = attach_sheets(read, index)
    # the same triangles, seen from the same side, as when the atlas was built
    tri_old = built.sheet_chart[atlas.sheet]
    tri_new = index.sheet_chart[back.sheet]
    area_old = np.bincount(tri_old, minlength=built.charts.count)
    area_new = np.bincount(tri_new, minlength=index.charts.count)
    assert sorted(area_old[area_old > 0]) == sorted(area_new[area_new > 0])
    np.testing.assert_array_equal(index.sheet_side[back.sheet], built.sheet_side[atlas.sheet])
    # each patch's stored triangle, seen from its side, is on its new sheet
    t = s2.global_triangle(back.source_object, back.triangle)
    np.testing.assert_array_equal(index.sheet_of(t, back.side), back.sheet)
    assert np.any(index.sheet_clutter[back.sheet])  # the leaves and tiny cubes are clutter


def test_a_changed_mesh_is_still_reported():
    s = doorway()
    atlas = build_atlas(s, AtlasSettings(patch_size=0.3))
    moved = Surfaces.from_arrays(
        s.vertices + [0, 0, 10.0], s.triangles, s.object_index, object_names=s.object_names
    )
    with pytest.raises(OvradError, match="no longer lie on any surface"):
        attach_sheets(blender_round_trip(atlas), solve_index(moved))
