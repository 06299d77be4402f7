"""A UV seam through a gradient: a plane lit by a point lamp, its UV map cut into two islands along
a line of vertices, baked to an image; the two islands agree at the seam's points, and with the
closed form of the point lamp's irradiance."""

from __future__ import annotations

import numpy as np
import pytest
from reference import analytic

import blender_env

bpy = pytest.importorskip("bpy")

pytestmark = pytest.mark.blender

SIZE = 128  # image texels per side
SCALE = 0.4  # UV units per metre: each 1 m x 2 m half of the plane is a 0.4 x 0.8 island
TEXEL = 1.0 / (SCALE * SIZE)  # world length of a texel's side: 1.95 cm
LAMP, POWER = (0.15, -0.1, 0.5), 100.0  # 0.5 m above the plane, beside the seam: a steep gradient
UP = np.array([0.0, 0.0, 1.0])


def island_uv(x, y, left: bool):
    """The UV of plane point (x, y) in the left island (x <= 0) or the right one (x >= 0)."""
    x, y = np.broadcast_arrays(np.atleast_1d(x), np.atleast_1d(y))
    u = 0.05 + SCALE * (x + 1.0) if left else 0.55 + SCALE * x
    return np.column_stack([u, 0.1 + SCALE * (y + 1.0)])


def bilinear(img, uv):
    """(m, 3) bilinear samples of img (H, W, 3) at UVs (m, 2), texel centres at (i + 0.5) / size."""
    h, w = img.shape[:2]
    x, y = uv[:, 0] * w - 0.5, uv[:, 1] * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    bottom = img[y0, x0] * (1 - fx) + img[y0, x0 + 1] * fx
    top = img[y0 + 1, x0] * (1 - fx) + img[y0 + 1, x0 + 1] * fx
    return bottom * (1 - fy) + top * fy


@pytest.fixture(scope="module")
def baked(ovrad, tmp_path_factory):
    """The 2 m plane (20 x 20 quads, a line of vertices at x = 0) lit by a point lamp of radius 0
    in an empty world, its UV map 'Seam' cut along x = 0, irradiance baked to a SIZE image."""
    scene = blender_env.reset_scene()
    scene.ovrad.patch_count = 200
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=20, y_subdivisions=20, size=2.0)
    obj = bpy.context.active_object
    mesh = obj.data
    co = np.array([v.co[:] for v in mesh.vertices])
    layer = mesh.uv_layers.new(name="Seam")
    for poly in mesh.polygons:
        left = co[list(poly.vertices), 0].mean() < 0.0
        for loop in poly.loop_indices:
            x, y = co[mesh.loops[loop].vertex_index, :2]
            layer.data[loop].uv = island_uv(x, y, left)[0]
    light = bpy.data.lights.new("Point", "POINT")
    light.energy, light.shadow_soft_size = POWER, 0.0
    lamp = bpy.data.objects.new("Point", light)
    lamp.location = LAMP
    scene.collection.objects.link(lamp)
    for o in scene.objects:
        o.select_set(o == obj)
    bpy.context.view_layer.objects.active = obj
    assert bpy.ops.ovrad.generate_atlas() == {"FINISHED"}
    assert bpy.ops.ovrad.solve() == {"FINISHED"}
    folder = tmp_path_factory.mktemp("seam")
    result = bpy.ops.ovrad.bake_image(
        uv_map="Seam", size=SIZE, quantity="IRRADIANCE", filepath=str(folder / "{object}")
    )
    assert result == {"FINISHED"}
    image = bpy.data.images[obj.name + "_ovrad"]
    a = np.empty(len(image.pixels), np.float32)
    image.pixels.foreach_get(a)
    return a.reshape(SIZE, SIZE, 4)[..., :3].astype(np.float64)


def irradiance(xy):
    """The closed form E at plane points (..., 2)."""
    xy = np.asarray(xy, np.float64)
    points = np.concatenate([xy, np.zeros(xy.shape[:-1] + (1,))], axis=-1)
    return analytic.point_lamp_irradiance(POWER, LAMP, points, UP)


def derivatives(xy, step=1e-4):
    """Gradient norm (m,) and the largest Hessian norm (m,) of E at plane points xy (m, 2), by
    central differences of the closed form."""
    ex, ey = np.array([step, 0.0]), np.array([0.0, step])
    gx = (irradiance(xy + ex) - irradiance(xy - ex)) / (2 * step)
    gy = (irradiance(xy + ey) - irradiance(xy - ey)) / (2 * step)
    f = irradiance(xy)
    hxx = (irradiance(xy + ex) - 2 * f + irradiance(xy - ex)) / step**2
    hyy = (irradiance(xy + ey) - 2 * f + irradiance(xy - ey)) / step**2
    hxy = (
        irradiance(xy + ex + ey)
        - irradiance(xy + ex - ey)
        - irradiance(xy - ex + ey)
        + irradiance(xy - ex - ey)
    )
    hxy /= 4 * step**2
    hessian = np.stack([np.stack([hxx, hxy], -1), np.stack([hxy, hyy], -1)], -2)
    return np.hypot(gx, gy), np.linalg.norm(hessian, ord=2, axis=(-2, -1))


def test_both_sides_of_a_seam_bake_the_light_of_the_seam(baked):
    # The seam's points: the 21 vertices on x = 0, at the edge of both islands.
    y = np.linspace(-1.0, 1.0, 21)
    seam = np.column_stack([np.zeros_like(y), y])
    # The bake stores E / pi; a plane alone under a point lamp has no other light.
    left = np.pi * bilinear(baked, island_uv(0.0, y, True))
    right = np.pi * bilinear(baked, island_uv(0.0, y, False))
    exact = irradiance(seam)
    # A bilinear sample at p is sum_i w_i E(q_i) (w_i >= 0, sum 1) over the 4 texel centres less
    # than a texel h from p in u and v; a centre inside the island holds E at itself, one outside at
    # the island's nearest point (rasterize's reach). By Taylor, sample - E(p) = grad E(p) . m + R,
    # m = sum_i w_i (q_i - p) and |R| <= 1/2 max|Hessian| max|q_i - p|^2 <= max|Hessian| h^2 (the
    # q_i within sqrt(2) h of p). Exact centres give m = 0 (bilinear reproduces linear functions);
    # moving an outside centre onto the edge moves m by its weight t (<= 1 - t', t' the inside
    # centre's distance in texels) times its distance, at most t (1 - t) h <= h / 4 across the edge
    # and along it at a corner of the island: |m| <= sqrt(2) h / 4.
    angle = np.linspace(0.0, 2.0 * np.pi, 36, endpoint=False)
    radius = np.sqrt(2.0) * TEXEL * np.linspace(0.0, 1.0, 6)
    r, a = (g.ravel() for g in np.meshgrid(radius, angle))
    disc = seam[:, None, :] + np.column_stack([r * np.cos(a), r * np.sin(a)])[None]
    gradient = derivatives(seam)[0]
    curvature = derivatives(disc.reshape(-1, 2))[1].reshape(len(y), -1).max(axis=1)
    bound = gradient * np.sqrt(2.0) * TEXEL / 4 + curvature * TEXEL**2
    slack = 1e-4 * exact  # float32 storage and the engine's direct light (exact to 1e-5 in test_lamps)
    assert np.all(bound / exact < 0.03)  # 1.6-2.4 % of E here (measured: within 1.1 %)
    for side in (left, right):
        assert np.all(side.max(axis=1) - side.min(axis=1) < slack)  # grey: a white lamp
        assert np.all(np.abs(side[:, 0] - exact) <= bound + slack), (side[:, 0] / exact - 1, bound / exact)
    # the two islands at each seam point: each within `bound` of E there
    assert np.all(np.abs(left[:, 0] - right[:, 0]) <= 2 * bound + slack)
