"""Atlas placement: no leaks, scale and tessellation independence, sides, and clear errors."""

import numpy as np
import pytest

import scenes
from ovrad_addon.atlas.index import index_surfaces
from ovrad_addon.errors import OvradError
from ovrad_addon.generate.build import build_atlas
from ovrad_addon.overlap.contacts import contacts
from ovrad_addon.overlap.contacts import contacts as find_contacts
from ovrad_addon.overlap.quadrature import patch_quadrature
from ovrad_addon.overlap.queries import alpha_at
from ovrad_addon.scene.surfaces import Surfaces
from ovrad_addon.settings import AtlasSettings, ObjectSettings


def covering(atlas, index, surfaces, side, count=20_000, seed=5):
    """Sample points on every triangle, with the patches covering each (sparse alpha)."""
    pts, tri = scenes.sample_surface(surfaces, count, seed)
    return pts, tri, alpha_at(atlas, index, find_contacts(atlas, index), pts, tri, np.full(len(tri), side))


def test_patches_never_cross_a_thin_wall_or_a_crease():
    s = scenes.thin_wall_rooms(gap=0.01)
    settings = AtlasSettings(patch_size=0.15, overlap=2.0)  # large patches: 15 x the wall gap
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    pts, tri, a = covering(atlas, index, s, side=1)
    rows, cols = a.nonzero()
    # every covering patch lies on the same object and the same chart (face) as the point
    assert np.all(atlas.source_object[cols] == s.object_index[tri[rows]])
    assert np.all(index.sheet_chart[atlas.sheet[cols]] == index.charts.chart[tri[rows]])
    # and the patch normal is the face's normal: no patch bends around an edge
    np.testing.assert_allclose(
        np.einsum("ij,ij->i", atlas.normals[cols], index.charts.normals[tri[rows]]), 1.0
    )
    # quadrature points of every patch stay on that patch's own face
    ids = np.arange(len(atlas))
    q = patch_quadrature(
        atlas, index, ids, settings.rule_order(len(atlas)), visibility=contacts(atlas, index)
    )
    on = q.triangle >= 0
    assert np.all(index.charts.chart[q.triangle[on]] == index.sheet_chart[atlas.sheet[q.owner[on]]])


def test_front_patches_do_not_cover_the_back_of_a_two_sided_sheet():
    v, t = scenes.plane(1.0)
    v2, t2 = scenes.plane(1.0, z=0.5)
    s = Surfaces.from_arrays(np.concatenate([v, v2]), np.concatenate([t, t2[:, ::-1] + len(v)]), [0, 0, 1, 1])
    settings = AtlasSettings(
        patch_count=200, objects=(ObjectSettings(sides="BOTH"), ObjectSettings(sides="BOTH"))
    )
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    assert len(index.sheet_chart) == 4
    for side in (1, -1):
        pts, tri, a = covering(atlas, index, s, side)
        rows, cols = a.nonzero()
        assert np.all(index.sheet_side[atlas.sheet[cols]] == side)
        facing = index.charts.normals[tri[rows]] * side
        assert np.all(np.einsum("ij,ij->i", atlas.normals[cols], facing) > 0.99)


def test_auto_sides_skip_back_faces_that_see_nothing():
    # two facing planes: each one's front sees the other, its back sees only empty space
    v, t = scenes.plane(1.0)
    v2, t2 = scenes.plane(1.0, z=0.5)
    s = Surfaces.from_arrays(np.concatenate([v, v2]), np.concatenate([t, t2[:, ::-1] + len(v)]), [0, 0, 1, 1])
    index = index_surfaces(s, AtlasSettings())
    assert sorted(index.sheet_side.tolist()) == [1, 1]
    # a closed cube gets its outside only
    assert index_surfaces(scenes.cube(), AtlasSettings()).sheet_side.tolist() == [1] * 6
    # an open box (no lid) seen from inside: the inner (back) sides see each other
    parts = scenes.box_faces((0, 0, 0), (1, 1, 1))[:1] + scenes.box_faces((0, 0, 0), (1, 1, 1))[2:]
    v3, t3, _ = scenes.merge(parts, obj=[0] * 5)
    idx = index_surfaces(Surfaces.from_arrays(v3, t3), AtlasSettings())
    assert sorted(idx.sheet_side.tolist()) == [-1] * 5 + [1] * 5


# Powers of two: the atlas is integrated as a file keeps it (float32), whose rounding is exactly
# scaled along only by them (a rule point on a contact line rounded to one side at one scale and to
# the other at 1000x would move that patch's area by up to 1 %, which is rounding, not scale).
@pytest.mark.parametrize("scale", [2.0**-10, 2.0**10])
def test_atlas_is_unchanged_by_scene_scale(scale):
    base = scenes.cornell()
    scaled = Surfaces.from_arrays(
        base.vertices * scale,
        base.triangles,
        base.object_index,
        base.reflectance,
        base.emission,
        base.object_names,
    )
    a = build_atlas(base, AtlasSettings(patch_count=500))
    b = build_atlas(scaled, AtlasSettings(patch_count=500))
    assert len(a) == len(b)
    np.testing.assert_allclose(b.centers / scale, a.centers, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(b.radii / scale, a.radii, rtol=1e-6)
    np.testing.assert_allclose(b.effective_area / scale**2, a.effective_area, rtol=1e-6)
    np.testing.assert_array_equal(b.overlap_count, a.overlap_count)


def test_placement_does_not_depend_on_tessellation():
    coarse = Surfaces.from_arrays(*scenes.plane(2.0, n=1))
    fine = Surfaces.from_arrays(*scenes.plane(2.0, n=40))  # 3200 triangles
    a = build_atlas(coarse, AtlasSettings(patch_size=0.25))
    b = build_atlas(fine, AtlasSettings(patch_size=0.25))
    assert len(a) == len(b) == 64
    np.testing.assert_allclose(np.sort(b.effective_area), np.sort(a.effective_area), rtol=1e-6)


def test_degenerate_triangles_are_ignored_and_the_rest_covered():
    s0 = scenes.cube()
    v = np.concatenate([s0.vertices, [[0.5, 0.5, 1.0], [0.5, 0.5, 1.0]]])
    t = np.concatenate([s0.triangles, [[8, 9, 9], [0, 1, 1]]])  # zero-area triangles
    s = Surfaces.from_arrays(v, t)
    settings = AtlasSettings(patch_count=300)
    atlas = build_atlas(s, settings)
    index = index_surfaces(s, settings)
    assert np.all(index.charts.chart[-2:] == -1)
    pts, tri, a = covering(atlas, index, s, side=1, count=100_000)
    assert np.asarray(a.sum(axis=1)).min() == pytest.approx(1.0)


def test_curved_surface_patches_follow_the_sphere():
    s = scenes.sphere(radius=1.0, subdivisions=4)
    atlas = build_atlas(s, AtlasSettings(patch_count=400))
    np.testing.assert_allclose(np.linalg.norm(atlas.centers, axis=1), 1.0, atol=0.01)
    cos = np.einsum(
        "ij,ij->i", atlas.normals, atlas.centers / np.linalg.norm(atlas.centers, axis=1, keepdims=True)
    )
    assert cos.min() > 0.99
    assert 300 < len(atlas) < 700


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: Surfaces.from_arrays(np.full((3, 3), np.nan), [[0, 1, 2]]), "NaN"),
        (lambda: Surfaces.from_arrays(np.zeros((0, 3)), np.zeros((0, 3))), "no triangles"),
        (
            lambda: build_atlas(Surfaces.from_arrays(np.zeros((3, 3)), [[0, 1, 2]]), AtlasSettings()),
            "zero area",
        ),
        (
            lambda: build_atlas(scenes.cube(), AtlasSettings(patch_size=0.001, max_patches=10_000)),
            "6,000,000",
        ),
        (lambda: AtlasSettings(overlap=0.8), "overlap"),
        (lambda: Surfaces.from_arrays(*scenes.plane(), reflectance=[1.5, 0, 0]), "reflectance"),
    ],
)
def test_unusable_input_gives_a_clear_error(make, message):
    with pytest.raises(OvradError, match=message):
        make()


def test_too_many_patches_is_refused_before_building_them():
    with pytest.raises(OvradError, match="patches, more than the limit of 200,000"):
        build_atlas(scenes.cube(), AtlasSettings(patch_size=1e-4))


def test_a_curved_piece_smaller_than_a_patch_gets_one(monkeypatch):
    """A bent piece under ONE_PATCH_AREA of a patch's disk spans several placement voxels, each of
    which gave it a nearly coincident patch (C's block nearly singular); it now gets one patch whose
    disk reaches all of it. A piece twice the disk's area still gets several."""
    from ovrad_addon.generate import curved
    from ovrad_addon.scene.surfaces import triangle_geometry

    spacing, overlap = 0.06, 1.3
    disk = np.pi * (overlap * spacing / np.sqrt(2.0)) ** 2

    def piece(size):
        v, t = scenes.bent_leaf(np.random.default_rng(2), size, 0.5, 6)
        c = v[t]
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        return c, n / np.linalg.norm(n, axis=1, keepdims=True)

    small, n_small = piece(0.035)
    assert triangle_geometry(small)[0].sum() < curved.ONE_PATCH_AREA * disk
    one = curved.place_curved(small, n_small, spacing, overlap, 1.0, seed=1)
    assert len(one.radii) == 1
    pts = small.reshape(-1, 3)
    assert np.all(np.linalg.norm(pts - one.centers[0], axis=1) <= one.radii[0] * 1.0001 + 1e-9)
    monkeypatch.setattr(curved, "ONE_PATCH_AREA", 0.0)
    assert len(curved.place_curved(small, n_small, spacing, overlap, 1.0, seed=1).radii) > 1
    monkeypatch.undo()
    large, n_large = piece(0.1)
    assert triangle_geometry(large)[0].sum() > 2 * disk
    assert len(curved.place_curved(large, n_large, spacing, overlap, 1.0, seed=1).radii) > 2


def bent_pieces_in_a_room(count: int = 30, seed: int = 11) -> Surfaces:
    """A closed 2 m room holding `count` bent leaves of 5-10 cm: curved pieces of one or two patch
    disks at a 9 cm patch size, the voxel grid cutting slivers off many of them."""
    room, where = ((-1, -1, 0), (1, 1, 2)), ([-0.7, -0.7, 0.3], [0.7, 0.7, 1.6])
    v, t, o = scenes.leaves_in_a_room(room, count, (0.05, 0.1), 0.6, 6, where, seed)
    return Surfaces.from_arrays(v, t, o, reflectance=[0.5] * 3, object_names=["room", "leaves"])


def test_voxel_slivers_join_a_neighbour_so_no_two_patches_nearly_coincide(monkeypatch):
    """A voxel holding a sliver of a curved piece would give it a patch sitting almost on its neighbour's,
    and such a pair makes C's block nearly singular: c_hj c_jh / (c_hh c_jj) near 1 (at 1 the pair
    is one patch twice). Measured on these leaves (patch size 9 cm, pieces of 0.4-2.5 patch disks):
    36 pairs above 0.9 on 452 leaf patches without the rule, 2 on 234 with it (the production room
    at 8 759 patches rang there: three patches on one piece solved to B of -8.4, -4.9 and +9.9)."""
    from ovrad_addon.generate import curved
    from ovrad_addon.generate.build import build_atlas_and_overlaps

    s = bent_pieces_in_a_room()

    def nearly_coincident():
        atlas, C, _, _ = build_atlas_and_overlaps(s, AtlasSettings(patch_size=0.09))
        coo, csr = C.tocoo(), C.tocsr()
        d = csr.diagonal()
        pair = (coo.row != coo.col) & (atlas.source_object[coo.row] == 1)
        h, j = coo.row[pair], coo.col[pair]
        product = coo.data[pair] * np.asarray(csr[j, h]).ravel() / (d[h] * d[j])
        return int(np.sum(product > 0.9)), int(np.sum(atlas.source_object == 1))

    with_rule, patches = nearly_coincident()
    monkeypatch.setattr(curved, "SLIVER_AREA", 0.0)
    without, more = nearly_coincident()
    assert with_rule * 4 < without
    assert patches < more  # the slivers' patches are gone, not moved


def test_counting_a_placement_gives_the_count_placing_makes():
    """Generate's first placement only counts (count_only): on every sheet of a room of bent leaves
    (curved pieces, slivers merged) and of the Cornell box (planar, boundary squares), at three
    spacings, the count is the number of patches the full placement makes."""
    from ovrad_addon.atlas.index import sheet_spacing
    from ovrad_addon.generate.build import place_all

    cases = ((bent_pieces_in_a_room(), AtlasSettings(patch_size=0.09)), (scenes.cornell(), AtlasSettings()))
    for s, settings in cases:
        index = index_surfaces(s, settings)
        base = sheet_spacing(index, settings)
        angles = {}
        for f in (0.6, 1.0, 1.7):
            placed, total = place_all(index, settings, f * base, angles)
            counted = place_all(index, settings, f * base, angles, count_only=True)[1]
            assert total == sum(len(p.radii) for p in placed) == counted
        # the kept grid angles are the ones the sheets would get afresh
        fresh = {}
        place_all(index, settings, base, fresh)
        assert fresh == angles and len(angles) > 0


def test_curved_sheets_placed_together_are_placed_as_if_alone():
    """place_curved_many places each sheet as when it is the only one, to rounding (its own seeded
    samples, voxels, slivers merged within it, thickness from its own samples only), whatever
    sheets share the batch: pieces of one patch, of a few (slivers merged) and of many, two of
    them overlapping in space (both sides of a leaf are two sheets)."""
    from ovrad_addon.generate import curved

    rng = np.random.default_rng(4)
    pieces = []
    for size in (0.02, 0.05, 0.08, 0.3, 0.05):
        v, t = scenes.bent_leaf(rng, size, 0.5, 6)
        c = v[t]
        n = np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0])
        pieces.append((c, n / np.linalg.norm(n, axis=1, keepdims=True)))
    pieces.append((pieces[3][0][:, ::-1], -pieces[3][1]))  # the large leaf's other side, same place
    spacing, overlap, seeds = np.array([0.06, 0.06, 0.05, 0.04, 0.2, 0.04]), 1.3, [7, 3, 11, 5, 2, 8]
    alone = [
        curved.place_curved(c, n, sp, overlap, 1.0, s)
        for (c, n), sp, s in zip(pieces, spacing, seeds, strict=True)
    ]
    counts = [len(p.radii) for p in alone]
    assert counts[0] == 1 and counts[3] > 20 and len(set(counts)) > 3
    corners = np.concatenate([c for c, _ in pieces])
    normals = np.concatenate([n for _, n in pieces])
    sheet = np.repeat(np.arange(len(pieces)), [len(c) for c, _ in pieces])
    together, k_per = curved.place_curved_many(corners, normals, sheet, spacing, overlap, 1.0, seeds)
    assert list(k_per) == counts
    np.testing.assert_array_equal(
        curved.place_curved_many(corners, normals, sheet, spacing, overlap, 1.0, seeds, count_only=True),
        counts,
    )
    first = np.cumsum([0] + [len(c) for c, _ in pieces])
    # the same shapes, and the same numbers to rounding (1e-12: a batch goes through numpy's
    # reductions and vector loops in other shapes than one sheet alone, and those may round a
    # value otherwise as the CPU's SIMD width decides; a patch placed otherwise moves by a cell)
    np.testing.assert_array_equal(together.shapes, np.concatenate([p.shapes for p in alone]))
    for f in ("centers", "normals", "tangents", "radii", "thickness", "min_cos"):
        want_f = np.concatenate([getattr(p, f) for p in alone])
        np.testing.assert_allclose(getattr(together, f), want_f, rtol=1e-12, atol=1e-12, err_msg=f)
    want = np.concatenate([p.triangle + first[k] for k, p in enumerate(alone)])
    np.testing.assert_array_equal(together.triangle, want)


def test_planar_sheets_placed_together_are_placed_as_if_alone():
    """place_planar_many places each planar sheet as when it is the only one (to rounding), whatever
    sheets share the batch, and its grid is the one the sheet's bounding rectangle gives: a
    w x h rectangle at spacing s gets ceil(w / s) x ceil(h / s) cells, squares on the cells its
    border touches and disks inside; a frame (a square with a square hole) squares on both rims."""
    from ovrad_addon.generate import planar
    from ovrad_addon.names import SHAPE_SQUARE

    def quad(x0, y0, x1, y1, z=0.0):
        p = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
        return p[[[0, 1, 2], [0, 2, 3]]]

    rect = quad(0.0, 0.0, 2.0, 0.9)  # 10 x 5 cells at spacing 0.2 (0.9 / 0.2 = 4.5 -> 5)
    # a 1.2 m frame, 0.4 m wide, as eight quads around a 0.4 m hole: 6 x 6 cells of 0.2 m, the
    # hole's 2 x 2 left empty
    edges = (0.0, 0.4, 0.8, 1.2)
    frame = np.concatenate(
        [
            quad(edges[i], edges[j], edges[i + 1], edges[j + 1], 1.0)
            for i in range(3)
            for j in range(3)
            if (i, j) != (1, 1)
        ]
    )
    tilted = rect @ np.array([[0.8, 0.0, 0.6], [0.0, 1.0, 0.0], [-0.6, 0.0, 0.8]]).T + 5.0
    back = rect[:, ::-1]  # the rectangle's other side, same place
    tiny = quad(3.0, 3.0, 3.05, 3.02)  # smaller than one cell
    sheets = [rect, frame, tilted, back, tiny]
    normals = [np.cross(c[0, 1] - c[0, 0], c[0, 2] - c[0, 0]) for c in sheets]
    spacing, overlap = np.full(len(sheets), 0.2), 1.3
    angles = np.array([planar.grid_angle(c, n) for c, n in zip(sheets, normals, strict=True)])
    alone = [
        planar.place_planar(c, n, 0.2, overlap, "AUTO", 10.0, a)
        for c, n, a in zip(sheets, normals, angles, strict=True)
    ]
    corners = np.concatenate(sheets)
    owner = np.repeat(np.arange(len(sheets)), [len(c) for c in sheets])
    args = (corners, owner, np.array(normals), spacing, overlap, "AUTO", 10.0, angles)
    together, k_per = planar.place_planar_many(*args)
    np.testing.assert_array_equal(planar.place_planar_many(*args, count_only=True), k_per)
    assert list(k_per) == [len(p.radii) for p in alone]
    first = np.cumsum([0] + [len(c) for c in sheets])
    # the same shapes, and the same numbers to rounding (1e-12: a batch goes through numpy's
    # reductions and vector loops in other shapes than one sheet alone, and those may round a
    # value otherwise as the CPU's SIMD width decides; a patch placed otherwise moves by a cell)
    np.testing.assert_array_equal(together.shapes, np.concatenate([p.shapes for p in alone]))
    for f in ("centers", "normals", "tangents", "radii", "thickness", "min_cos"):
        want_f = np.concatenate([getattr(p, f) for p in alone])
        np.testing.assert_allclose(getattr(together, f), want_f, rtol=1e-12, atol=1e-12, err_msg=f)
    want = np.concatenate([p.triangle + first[k] for k, p in enumerate(alone)])
    np.testing.assert_array_equal(together.triangle, want)
    # the grids, from the rectangles alone
    assert list(k_per) == [50, 32, 50, 50, 1]
    square = [p.shapes == SHAPE_SQUARE for p in alone]
    assert square[0].sum() == 50 - 8 * 3 and square[2].sum() == 26 and square[3].sum() == 26
    assert square[1].all()  # every cell of a 0.4 m wide frame touches one of its rims
    assert square[4].all()
    inner = ~square[0]
    np.testing.assert_allclose(alone[0].radii[inner], overlap * 0.5 * np.hypot(0.2, 0.18))
    np.testing.assert_allclose(alone[0].radii[~inner], overlap * 0.5 * 0.2)
