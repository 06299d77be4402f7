"""Lightmaps on the solved Cornell box: UV maps ovrad makes where a mesh has none fit, the user's
UV maps untouched, image sizes from a texel density, 16-bit PNG output and the glTF round trip."""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

import blender_env

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
CORNELL = blender_env.cornell_blend()
REFERENCE = ROOT / "benchmarks" / "reference" / "cornell_4096.npz"
RECEIVERS = ("Floor", "Ceiling", "BackWall", "LeftWall", "RightWall", "ShortBlock", "TallBlock")
DENSITY = 120.0  # texels per metre: the 0.55 m box gets images of about 70-110 texels
MARGIN = 3


def planar_uv(obj, name, scale=1.0):
    """A UV map projecting the mesh onto the bounding box of its two widest axes, times scale
    (above 1 it tiles: unfit for a lightmap)."""
    mesh = obj.data
    co = np.array([v.co[:] for v in mesh.vertices])
    lo, hi = co.min(axis=0), co.max(axis=0)
    axes = np.sort(np.argsort(hi - lo)[1:])
    layer = mesh.uv_layers.new(name=name)
    vi = np.array([loop.vertex_index for loop in mesh.loops])
    layer.data.foreach_set("uv", (scale * (co[vi][:, axes] - lo[axes]) / (hi - lo)[axes]).ravel())
    return layer


@pytest.fixture(scope="module")
def solved(ovrad, tmp_path_factory):
    """The Cornell box solved (600 patches, 64 gather rays): the floor with a fit UV map 'UVMap',
    the back wall with a tiling one 'Tiles' (UVs up to 3: unfit), the others with none."""
    bpy.ops.wm.open_mainfile(filepath=str(CORNELL))
    scene = bpy.context.scene
    planar_uv(scene.objects["Floor"], "UVMap")
    planar_uv(scene.objects["BackWall"], "Tiles", scale=3.0)
    scene.ovrad.size_mode, scene.ovrad.patch_count, scene.ovrad.gather_rays = "COUNT", 600, 64
    for obj in scene.objects:
        obj.select_set(obj.type == "MESH")
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    path = tmp_path_factory.mktemp("solved") / "cornell_lightmap.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path


@pytest.fixture
def scene(solved):
    bpy.ops.wm.open_mainfile(filepath=str(solved))
    sc = bpy.context.scene
    for obj in sc.objects:
        obj.select_set(obj.name in RECEIVERS)
    bpy.context.view_layer.objects.active = sc.objects["Floor"]
    return sc


def bake(tmp_path, **kw):
    kw.setdefault("filepath", str(tmp_path / "{object}"))
    kw.setdefault("texel_density", DENSITY)
    return bpy.ops.ovrad.bake_image(margin=kw.pop("margin", MARGIN), **kw)


def uv_state():
    """Every mesh's UV maps: name -> (uv bytes, active, active render)."""
    out = {}
    for mesh in bpy.data.meshes:
        for lay in mesh.uv_layers:
            a = np.empty(2 * len(lay.data), np.float32)
            lay.data.foreach_get("uv", a)
            out[mesh.name, lay.name] = (a.tobytes(), lay.active, lay.active_render)
    return out


def user_maps(state):
    return {k: v for k, v in state.items() if k[1] != "ovrad_lightmap"}


def pixels(image) -> np.ndarray:
    a = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(a)
    return a.reshape(image.size[1], image.size[0], 4)


def triangles(obj, uv_name):
    """(T, 3, 2) UVs and (T, 3, 3) world corners of the object's loop triangles."""
    mesh = obj.data
    mesh.calc_loop_triangles()
    loops = np.array([t.loops[:] for t in mesh.loop_triangles])
    verts = np.array([lp.vertex_index for lp in mesh.loops])
    m = np.array(obj.matrix_world)
    co = np.array([v.co[:] for v in mesh.vertices]) @ m[:3, :3].T + m[:3, 3]
    uv = np.array([d.uv[:] for d in mesh.uv_layers[uv_name].data])
    return uv[loops], co[verts[loops]]


def area(tri):
    if tri.shape[-1] == 2:
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def islands(uv):
    """Island index per triangle: triangles sharing a UV corner (to 1e-6) are one island."""
    keys = np.round(uv.reshape(-1, 2) * 1e6).astype(np.int64)
    _, corner = np.unique(keys, axis=0, return_inverse=True)
    corner = corner.reshape(-1, 3)
    parent = list(range(corner.max() + 1))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b, c in corner:
        for x in (b, c):
            parent[find(x)] = find(a)
    roots = [find(c[0]) for c in corner]
    return np.unique(roots, return_inverse=True)[1]


def segment_distance(p, q, r, s):
    """Least distance between 2-d segments pq and rs that do not cross: the least distance of an
    end point to the other segment (crossing edges are overlapping triangles, tested apart)."""

    def to_segment(x, a, b):
        t = np.clip(np.dot(x - a, b - a) / max(np.dot(b - a, b - a), 1e-300), 0.0, 1.0)
        return np.linalg.norm(x - (a + t * (b - a)))

    return min(to_segment(p, r, s), to_segment(q, r, s), to_segment(r, p, q), to_segment(s, p, q))


def island_gap(uv):
    """Least UV distance between triangles of different islands (their edges' distance)."""
    isl = islands(uv)
    best = np.inf
    for i in range(len(uv)):
        for j in range(i + 1, len(uv)):
            if isl[i] == isl[j]:
                continue
            for e in range(3):
                for f in range(3):
                    d = segment_distance(uv[i, e], uv[i, (e + 1) % 3], uv[j, f], uv[j, (f + 1) % 3])
                    best = min(best, d)
    return best


@pytest.mark.versions
def test_every_receiver_gets_a_lightmap_and_the_users_uv_maps_are_unchanged(scene, tmp_path):
    before = uv_state()
    assert bake(tmp_path) == {"FINISHED"}
    after = uv_state()
    # The user's maps: bit for bit, and which is active and renders, as they were.
    assert user_maps(after) == user_maps(before)
    for name in RECEIVERS:
        assert bpy.data.images.get(name + "_ovrad") is not None, name
        assert (tmp_path / f"{name}.exr").is_file()
    made = {m for m, lay in after if lay == "ovrad_lightmap"}
    # the floor's planar map is fit; the back wall's tiles reach 3 (unfit), the rest have none
    assert made == {scene.objects[n].data.name for n in RECEIVERS if n != "Floor"}


def test_made_maps_are_inside_the_square_without_overlap_padded_and_at_the_density(ovrad, scene, tmp_path):
    results = []
    remove = ovrad.operators.bake_image.add_listener(results.append)
    try:
        assert bake(tmp_path) == {"FINISHED"}
    finally:
        remove()
    sizes = {e["object"]: e["size"] for e in results[-1]["images"]}
    for name in RECEIVERS:
        obj = scene.objects[name]
        uv_name = "UVMap" if name == "Floor" else "ovrad_lightmap"
        assert {e["uv_map"] for e in results[-1]["images"] if e["object"] == name} == {uv_name}
        uv, world = triangles(obj, uv_name)
        n = sizes[name]
        assert n % 4 == 0 and tuple(bpy.data.images[name + "_ovrad"].size) == (n, n)
        # the density: n x sqrt(UV area / world area) texels per metre, at least DENSITY and less
        # than one rounding step (4 texels) above it, or the padding's own growth
        per_metre = n * np.sqrt(area(uv).sum() / area(world).sum())
        assert per_metre >= DENSITY * (1 - 1e-9), (name, per_metre)
        if uv_name == "UVMap":
            assert per_metre < DENSITY + 4 * np.sqrt(area(uv).sum() / area(world).sum()), name
            continue
        assert uv.min() >= 0 and uv.max() <= 1
        # no overlap: the islands' UV areas add up to their union's, measured on a fine grid
        grid = (np.arange(1024) + 0.5) / 1024
        gx, gy = np.meshgrid(grid, grid)
        pts = np.column_stack([gx.ravel(), gy.ravel()])
        cover = np.zeros(len(pts), int)
        for a, b, c in uv:
            d = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
            if abs(d) < 1e-15:
                continue
            wa = ((b[0] - pts[:, 0]) * (c[1] - pts[:, 1]) - (b[1] - pts[:, 1]) * (c[0] - pts[:, 0])) / d
            wb = ((c[0] - pts[:, 0]) * (a[1] - pts[:, 1]) - (c[1] - pts[:, 1]) * (a[0] - pts[:, 0])) / d
            cover += (wa > 1e-9) & (wb > 1e-9) & (1 - wa - wb > 1e-9)
        assert cover.max() == 1, name
        # padding: islands at least MARGIN texels apart at the image's size
        if len(set(islands(uv))) > 1:
            assert island_gap(uv) * n >= MARGIN * (1 - 1e-3), (name, island_gap(uv) * n)


def test_baking_again_replaces_only_the_map_ovrad_made(scene, tmp_path):
    assert bake(tmp_path) == {"FINISHED"}
    wall = scene.objects["LeftWall"].data
    count = len(wall.uv_layers)
    assert bake(tmp_path, texel_density=1.5 * DENSITY) == {"FINISHED"}
    assert len(wall.uv_layers) == count  # made again in place, not added
    # a map of that name the user changed is theirs: never replaced, that mesh not baked
    lay = wall.uv_layers["ovrad_lightmap"]
    lay.data[0].uv = (0.5, 0.5)
    before = uv_state()
    assert bake(tmp_path) == {"FINISHED"}
    assert uv_state()[wall.name, "ovrad_lightmap"] == before[wall.name, "ovrad_lightmap"]
    # ... nor in a shared atlas, which the other receivers still go into
    assert bake(tmp_path, atlas="SHARED") == {"FINISHED"}
    assert uv_state()[wall.name, "ovrad_lightmap"] == before[wall.name, "ovrad_lightmap"]
    assert scene.objects["LeftWall"].get("ovrad_lightmap_image") == "LeftWall_ovrad"  # its own bake's
    assert all(
        scene.objects[n]["ovrad_lightmap_image"] == "ovrad_atlas" for n in RECEIVERS if n != "LeftWall"
    )


def test_undo_removes_the_made_maps_and_images(scene, tmp_path):
    # Background bpy.ops push no undo step: the test pushes the ones the UI pushes around it.
    before = uv_state()
    bpy.ops.ed.undo_push(message="before")
    assert bake(tmp_path) == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Bake to Image")
    assert uv_state() != before and bpy.data.images.get("LeftWall_ovrad") is not None
    bpy.ops.ed.undo()
    assert uv_state() == before
    assert not any(i.name.endswith("_ovrad") for i in bpy.data.images)
    # a shared atlas, and the preview of it, the same
    bpy.ops.ed.undo_push(message="again")
    assert bake(tmp_path, atlas="SHARED") == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Bake to Image")
    assert bpy.ops.ovrad.preview(source="IMAGE") == {"FINISHED"}
    bpy.ops.ed.undo_push(message="Preview")
    assert bpy.data.images.get("ovrad_atlas") is not None
    assert any(m.name.startswith("ovrad preview") for m in bpy.data.materials)
    bpy.ops.ed.undo()
    assert not any(m.name.startswith("ovrad preview") for m in bpy.data.materials)
    assert all(s.link == "DATA" for s in bpy.context.scene.objects["Floor"].material_slots)
    bpy.ops.ed.undo()
    assert uv_state() == before and bpy.data.images.get("ovrad_atlas") is None


def test_a_named_uv_map_is_used_as_it_is(scene, tmp_path):
    for obj in scene.objects:
        obj.select_set(obj.name == "BackWall")
    before = uv_state()
    assert bake(tmp_path, uv_map="Tiles", size=32) == {"FINISHED"}
    assert uv_state() == before  # nothing made
    assert tuple(bpy.data.images["BackWall_ovrad"].size) == (32, 32)


def test_too_small_or_too_large_at_the_density_is_not_baked_and_the_rest_is(scene, tmp_path):
    scene.objects["ShortBlock"].ovrad.lightmap_scale = 1e-3  # 0.12 texels per metre
    scene.objects["TallBlock"].ovrad.lightmap_scale = 100.0  # 12 000 texels per metre
    before = uv_state()
    assert bake(tmp_path, max_size=512) == {"FINISHED"}
    assert bpy.data.images.get("ShortBlock_ovrad") is None and bpy.data.images.get("TallBlock_ovrad") is None
    assert bpy.data.images.get("Ceiling_ovrad") is not None
    after = uv_state()
    for block in ("ShortBlock", "TallBlock"):  # refused before anything was made on them
        mesh = scene.objects[block].data.name
        assert {k: v for k, v in after.items() if k[0] == mesh} == {
            k: v for k, v in before.items() if k[0] == mesh
        }


def read_png(path):
    """(H, W, 4) uint16 in Blender's row order and the tEXt entries of a 16-bit RGBA PNG, decoded
    here with zlib (no filter but 'none' is expected from ovrad's writer; others are refused)."""
    data = Path(path).read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, idat, text = 8, b"", {}
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos : pos + 4])
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        assert zlib.crc32(kind + body) == struct.unpack(">I", data[pos + 8 + n : pos + 12 + n])[0]
        if kind == b"IHDR":
            w, h, depth, colour = struct.unpack(">IIBB", body[:10])
            assert (depth, colour) == (16, 6)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"tEXt":
            key, value = body.split(b"\0", 1)
            text[key.decode()] = value.decode()
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + 8 * w)
    assert np.all(raw[:, 0] == 0)
    return raw[:, 1:].copy().view(">u2").reshape(h, w, 4)[::-1].astype(np.int64), text


def test_png16_holds_the_values_times_two_to_the_minus_exposure(scene, tmp_path):
    for obj in scene.objects:
        obj.select_set(obj.name in ("Floor", "Light"))  # the lamp's radiance is far above 1
    assert bake(tmp_path / "exr") == {"FINISHED"}
    want = {n: pixels(bpy.data.images[n + "_ovrad"]).astype(np.float64) for n in ("Floor", "Light")}
    assert bake(tmp_path / "png", file_format="PNG") == {"FINISHED"}
    for name, exr in want.items():
        got, text = read_png(tmp_path / "png" / f"{name}.png")
        e = int(text["ovrad:exposure"])
        top = exr[..., :3].max()
        assert 2.0 ** (e - 1) < top <= 2.0**e  # the smallest power of two holding every value
        assert bpy.data.images[name + "_ovrad"]["ovrad_exposure"] == e
        # each value rounded to the nearest of 65 536 steps of 2^e
        np.testing.assert_allclose(got[..., :3] / 65535 * 2.0**e, exr[..., :3], rtol=0, atol=2.0**e / 65535)
        assert np.array_equal(got[..., 3] > 0, exr[..., 3] > 0)
    assert bpy.data.images["Light_ovrad"]["ovrad_exposure"] > 0  # brighter than 1: a positive exposure


def read_gltf(path):
    """The glTF JSON and a function reading an accessor as a numpy array."""
    doc = json.loads(Path(path).read_text())
    blobs = [(Path(path).parent / b["uri"]).read_bytes() for b in doc["buffers"]]
    kinds = {5126: np.float32, 5123: np.uint16, 5125: np.uint32}
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}

    def accessor(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        dtype = np.dtype(kinds[acc["componentType"]]).newbyteorder("<")
        k = width[acc["type"]]
        a = np.frombuffer(blobs[view["buffer"]], dtype, count=acc["count"] * k, offset=start)
        return a.reshape(acc["count"], k)

    return doc, accessor


# not marked `versions`: after a glTF export the bpy 4.5 module never exits (its threads wait at
# interpreter shutdown), so this runs in the development Blender only
def test_gltf_carries_the_lightmap_uv_as_texcoord_1_and_unclamped_radiance(scene, tmp_path):
    # The back wall has a UV map of its own ('Tiles', unfit): ovrad's map comes second.
    for obj in scene.objects:
        obj.select_set(obj.name in ("BackWall", "Light"))
    assert bake(tmp_path) == {"FINISHED"}
    assert bpy.ops.ovrad.bake_vertex(attribute="_ovrad_radiance") == {"FINISHED"}
    out = tmp_path / "scene.gltf"
    result = bpy.ops.export_scene.gltf(
        filepath=str(out), export_format="GLTF_SEPARATE", use_selection=True, export_attributes=True
    )
    assert result == {"FINISHED"}
    doc, accessor = read_gltf(out)
    by_name = {n["name"]: n for n in doc["nodes"] if "mesh" in n}
    for name in ("BackWall", "Light"):
        obj = scene.objects[name]
        mesh = obj.data
        prim = doc["meshes"][by_name[name]["mesh"]]["primitives"][0]["attributes"]
        index = [lay.name for lay in mesh.uv_layers].index("ovrad_lightmap")
        assert f"TEXCOORD_{index}" in prim
        if name == "BackWall":
            assert index == 1  # the second UV set
        pos = accessor(prim["POSITION"]).astype(np.float64)
        uv = accessor(prim[f"TEXCOORD_{index}"]).astype(np.float64)
        rad = accessor(prim["_OVRAD_RADIANCE"]).astype(np.float64)
        # Blender's data at each loop: position (z up -> glTF y up), lightmap UV (v -> 1 - v), value
        co = np.array([v.co[:] for v in mesh.vertices])
        vi = np.array([lp.vertex_index for lp in mesh.loops])
        lm = np.array([d.uv[:] for d in mesh.uv_layers["ovrad_lightmap"].data])
        val = np.array([d.color[:] for d in mesh.attributes["_ovrad_radiance"].data])
        want_pos = co[vi][:, [0, 2, 1]] * [1, 1, -1]
        want_uv = np.column_stack([lm[:, 0], 1 - lm[:, 1]])
        for p, t, r in zip(pos, uv, rad, strict=True):
            k = np.flatnonzero(
                np.all(np.abs(want_pos - p) < 1e-6, axis=1) & np.all(np.abs(want_uv - t) < 1e-6, axis=1)
            )
            assert len(k), (name, p, t)
            np.testing.assert_array_equal(r.astype(np.float32), val[vi[k[0]]].astype(np.float32))
        if name == "Light":
            assert rad[:, :3].max() > 1.0  # radiance above 1 is kept, not clamped


def test_a_shared_atlas_packs_every_receiver_into_one_image_at_the_density(ovrad, scene, tmp_path):
    results = []
    remove = ovrad.operators.bake_image.add_listener(results.append)
    try:
        before = uv_state()
        assert bake(tmp_path / "own") == {"FINISHED"}
        own = {e["object"]: e for e in results[-1]["images"]}
        # the own bakes' UVs and images, before the shared atlas makes 'ovrad_lightmap' again
        own_uv = {n: triangles(scene.objects[n], own[n]["uv_map"])[0] for n in RECEIVERS}
        own_img = {n: pixels(bpy.data.images[n + "_ovrad"]) for n in RECEIVERS}
        assert bake(tmp_path / "shared", atlas="SHARED") == {"FINISHED"}
        shared = {e["object"]: e for e in results[-1]["images"]}
    finally:
        remove()
    assert user_maps(uv_state()) == user_maps(before)  # the floor's own map too
    assert set(shared) == set(RECEIVERS)
    assert {(e["image"], e["path"], e["size"], e["uv_map"]) for e in shared.values()} == {
        (
            "ovrad_atlas",
            str(tmp_path / "shared" / "ovrad_atlas.exr"),
            shared["Floor"]["size"],
            "ovrad_lightmap",
        )
    }
    assert (tmp_path / "shared" / "ovrad_atlas.exr").is_file()
    n = shared["Floor"]["size"]
    img = pixels(bpy.data.images["ovrad_atlas"])
    assert img.shape[:2] == (n, n)
    grid = (np.arange(1024) + 0.5) / 1024
    gx, gy = np.meshgrid(grid, grid)
    cover = np.zeros(gx.shape, int)
    for name in RECEIVERS:
        uv, world = triangles(scene.objects[name], "ovrad_lightmap")
        assert uv.min() >= 0 and uv.max() <= 1
        # every receiver at the density or above, at the atlas's size
        assert n * np.sqrt(area(uv).sum() / area(world).sum()) >= DENSITY * (1 - 1e-9), name
        for t in uv:
            (ax, ay), (bx, by), (cx, cy) = t
            d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
            if d == 0:
                continue
            w1 = ((gx - ax) * (cy - ay) - (gy - ay) * (cx - ax)) / d
            w2 = ((bx - ax) * (gy - ay) - (by - ay) * (gx - ax)) / d
            cover += (w1 > 0) & (w2 > 0) & (w1 + w2 < 1)
        # its light, averaged over the texels its islands cover, is what its own lightmap holds
        # (the same surface at other texels: within 3 %, measured 1.7 % at most; the receivers'
        # means differ by up to 4x)
        m_shared = texel_mean(img, uv)
        m_own = texel_mean(own_img[name], own_uv[name])
        assert np.allclose(m_shared, m_own, rtol=0.03), (name, m_shared, m_own)
    assert cover.max() == 1  # no two triangles of any receivers share a place in the atlas


def texel_mean(img, uv) -> np.ndarray:
    """(3,) mean RGB of the image's texels whose centres lie inside the UV triangles (T, 3, 2)."""
    n = img.shape[0]
    c = (np.arange(n) + 0.5) / n
    gx, gy = np.meshgrid(c, c)
    inside = np.zeros(gx.shape, bool)
    for (ax, ay), (bx, by), (cx, cy) in uv:
        d = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)
        if d == 0:
            continue
        w1 = ((gx - ax) * (cy - ay) - (gy - ay) * (cx - ax)) / d
        w2 = ((bx - ax) * (gy - ay) - (by - ay) * (gx - ax)) / d
        inside |= (w1 >= 0) & (w2 >= 0) & (w1 + w2 <= 1)
    return img[inside][:, :3].mean(axis=0)


def test_shared_atlas_groups_fill_at_most_the_largest_image(ovrad):
    groups = ovrad.operators.lightmap_atlas.groups
    # 0.6 x 100^2 = 6000 texels per atlas: largest first, each into the first with room
    assert groups([5000, 1000, 3000, 2500, 9000], 100) == [[4], [0, 1], [2, 3]]
    assert groups([], 100) == []
    halves = ovrad.operators.lightmap_atlas.halves
    assert halves([0, 1, 2, 3], [5.0, 1.0, 3.0, 2.5]) == [[0, 1], [2, 3]]
    assert halves([7], [0, 0, 0, 0, 0, 0, 0, 1.0]) == [[7]]
    names = ovrad.operators.lightmap_atlas.atlas_names
    assert names(1) == ["ovrad_atlas"] and names(2) == ["ovrad_atlas_1", "ovrad_atlas_2"]


def test_a_linked_duplicate_is_no_part_of_a_shared_atlas(ovrad, scene):
    linked = ovrad.operators.lightmap_atlas.linked
    block = scene.objects["ShortBlock"]
    assert not linked(block)
    twin = block.copy()  # shares the mesh
    scene.collection.objects.link(twin)
    assert linked(block) and linked(twin)
    bpy.data.objects.remove(twin)
    assert not linked(block)


def slots_state():
    """Per object: its slots' (link, material shown) and its mesh's own materials."""
    return {
        o.name: (
            [(s.link, s.material.name if s.material else None) for s in o.material_slots],
            [m.name if m else None for m in o.data.materials],
        )
        for o in bpy.data.objects
        if o.type == "MESH"
    }


@pytest.mark.versions
def test_preview_shows_each_lightmap_through_its_uv_map_and_restores_the_slots(ovrad, scene, tmp_path):
    preview = ovrad.operators.preview
    floor, block = scene.objects["Floor"], scene.objects["ShortBlock"]
    mine = bpy.data.materials.new("Mine")
    floor.material_slots[0].link = "OBJECT"  # the user's own object-linked material stays theirs
    floor.material_slots[0].material = mine
    block.data.materials.clear()  # a receiver without slots
    assert bake(tmp_path) == {"FINISHED"}
    before = slots_state()
    assert bpy.ops.ovrad.preview(source="IMAGE") == {"FINISHED"}
    assert preview.is_active()
    for name in RECEIVERS:
        obj = scene.objects[name]
        assert obj.material_slots and all(s.link == "OBJECT" for s in obj.material_slots)
        tree = obj.material_slots[0].material.node_tree
        tex = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeTexImage")
        uv = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeUVMap")
        assert tex.image == bpy.data.images[name + "_ovrad"]
        assert uv.uv_map == ("UVMap" if name == "Floor" else "ovrad_lightmap")
        # the meshes' own materials (which other objects may share) are untouched; a mesh without
        # any gets one empty slot for the preview
        want = before[name][1] or [None]
        assert [m.name if m else None for m in obj.data.materials] == want
    assert bpy.ops.ovrad.preview() == {"FINISHED"}
    assert not preview.is_active()
    assert slots_state() == before
    assert floor.material_slots[0].material == mine and len(block.material_slots) == 0
    assert not [m for m in bpy.data.materials if m.name.startswith("ovrad preview")]
    # a shared atlas: every receiver shows the one atlas image
    assert bake(tmp_path, atlas="SHARED") == {"FINISHED"}
    assert bpy.ops.ovrad.preview(source="IMAGE") == {"FINISHED"}
    shown = {
        next(
            n
            for n in scene.objects[r].material_slots[0].material.node_tree.nodes
            if n.bl_idname == "ShaderNodeTexImage"
        ).image.name
        for r in RECEIVERS
    }
    assert shown == {"ovrad_atlas"}
    assert bpy.ops.ovrad.preview() == {"FINISHED"}
    assert slots_state() == before


def test_preview_of_lightmaps_before_any_image_bake_is_refused(ovrad, scene):
    before = slots_state()
    with pytest.raises(RuntimeError, match="bake to images first"):
        bpy.ops.ovrad.preview(source="IMAGE")
    assert slots_state() == before and not ovrad.operators.preview.is_active()


def test_shared_atlases_split_under_max_size_and_say_what_to_change(ovrad, scene, tmp_path):
    # At 120 texels per metre each receiver needs 60-100 texels a side: a 128 px Max Size holds
    # one or two of them per atlas (groups that pack larger than guessed are halved).
    results = []
    remove = ovrad.operators.bake_image.add_listener(results.append)
    try:
        assert bake(tmp_path, atlas="SHARED", max_size=128) == {"FINISHED"}
    finally:
        remove()
    images, not_baked = results[-1]["images"], results[-1]["not_baked"]
    names = {e["image"] for e in images}
    assert len(names) >= 2 and all(n.startswith("ovrad_atlas_") for n in names)
    assert all(e["size"] <= 128 for e in images)
    for n in names:
        assert (tmp_path / f"{n}.exr").is_file()
        assert tuple(bpy.data.images[n].size) == ({e["size"] for e in images if e["image"] == n}.pop(),) * 2
    # every receiver is in one atlas (none needs more than 128 texels a side on its own)
    assert sorted(e["object"] for e in images) == sorted(RECEIVERS) and not not_baked
    # at 90 the tall block (96 texels a side once packed) is not baked, with what to change, and
    # the others are
    results.clear()
    remove = ovrad.operators.bake_image.add_listener(results.append)
    try:
        assert bake(tmp_path / "small", atlas="SHARED", max_size=90) == {"FINISHED"}
    finally:
        remove()
    left = results[-1]["not_baked"]
    assert [n["object"] for n in left] == ["TallBlock"] and "raise Max Size" in left[0]["why"]
    assert sorted(e["object"] for e in results[-1]["images"]) == sorted(set(RECEIVERS) - {"TallBlock"})


def test_a_shared_atlas_with_a_named_uv_map_is_refused_and_changes_nothing(scene, tmp_path):
    before = uv_state()
    with pytest.raises(RuntimeError, match="shared atlas bakes through UV maps ovrad makes"):
        bake(tmp_path, atlas="SHARED", uv_map="UVMap")
    assert uv_state() == before and not list(tmp_path.iterdir())
    # several atlases (at a 128 px Max Size) into one file path: refused before a UV map is made
    with pytest.raises(RuntimeError, match="put {object} in the file path"):
        bake(tmp_path, atlas="SHARED", max_size=128, filepath=str(tmp_path / "one.exr"))
    assert uv_state() == before and not list(tmp_path.iterdir())


def test_a_small_curved_mesh_gets_a_lightmap_at_least_at_the_density(ovrad):
    """A 12 cm sphere (32 x 16 segments) at 40 texels per metre, 4 texels of padding: Smart UV
    Project cuts it into a few islands, and their padding needs more than its 17 x 17 texels of
    density. Pack Islands with a margin of a fifth of the square packed them into nothing (an
    image of 2 million texels a side was asked); the margin now stays at most a tenth and the
    image grows to the padding instead."""
    import bmesh

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)  # the data only, not the add-ons
    mesh = bpy.data.meshes.new("Ball")
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16, radius=0.12)
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new("Ball", mesh)
    bpy.context.scene.collection.objects.link(obj)
    size = ovrad.operators.lightmap_uv.make(bpy.context, obj, 40.0, 4.0)
    uv, world = triangles(obj, "ovrad_lightmap")
    assert 4 <= size <= 128 and size % 4 == 0
    assert uv.min() >= 0 and uv.max() <= 1
    assert area(uv).sum() > 0.05  # the islands keep a share of the square
    assert size * np.sqrt(area(uv).sum() / area(world).sum()) >= 40.0 * (1 - 1e-9)
