"""The reference closed forms against published numbers and against independent computations.

Each closed form in analytic.py is checked (a) against the number quoted in the literature and
issue 4, and (b) against something computed another way here: brute-force Gauss–Legendre
quadrature of the defining double integral, Monte Carlo ray casting, configuration-factor
algebra, reciprocity, closure, or 2-D limits (Hottel's crossed strings).
"""

import numpy as np
import pytest
from scipy.integrate import quad

from .analytic import (
    area_lamp_disk_irradiance,
    area_lamp_rect_irradiance,
    ff_coaxial_disks,
    ff_parallel_rectangles,
    ff_perpendicular_rectangles_common_edge,
    ff_point_to_disk,
    ff_point_to_polygon,
    ff_point_to_rectangle_corner,
    furnace_radiance,
    lens_area,
    point_lamp_irradiance,
    regular_polygon,
    spot_falloff,
    spot_lamp_irradiance,
    sun_irradiance,
)

# ----------------------------------------------------------------------------- helpers


def gauss(n, a=0.0, b=1.0):
    """Gauss–Legendre nodes and weights on [a, b]."""
    x, w = np.polynomial.legendre.leggauss(n)
    return a + (b - a) * (x + 1) / 2, w * (b - a) / 2


def rect_samples(origin, eu, ev, n):
    """Tensor Gauss–Legendre points (n², 3) and area weights on origin + s·eu + t·ev, s, t ∈ [0, 1]."""
    s, ws = gauss(n)
    o, eu, ev = (np.asarray(v, dtype=float) for v in (origin, eu, ev))
    pts = o + s[:, None, None] * eu + s[None, :, None] * ev
    area = np.linalg.norm(np.cross(eu, ev))
    return pts.reshape(-1, 3), (ws[:, None] * ws[None, :]).ravel() * area


def ff_double_area(rect1, n1, rect2, n2, n):
    """F_12 = (1/A1) ∬ cosθ1 cosθ2 / (π r²) dA2 dA1 by brute-force 4-D Gauss–Legendre."""
    p1, w1 = rect_samples(*rect1, n)
    p2, w2 = rect_samples(*rect2, n)
    d = p2[None, :, :] - p1[:, None, :]
    r2 = np.einsum("ijk,ijk->ij", d, d)
    c1 = d @ np.asarray(n1, float)
    c2 = -(d @ np.asarray(n2, float))
    k = np.maximum(c1, 0) * np.maximum(c2, 0) / (np.pi * r2 * r2)
    return float(w1 @ k @ w2 / w1.sum())


def ff_point_monte_carlo(p, n, polygon, count, seed):
    """F(point → convex polygon) as the fraction of cosine-distributed rays that hit it (Nusselt)."""
    rng = np.random.default_rng(seed)
    p, n, poly = np.asarray(p, float), np.asarray(n, float), np.asarray(polygon, float)
    n = n / np.linalg.norm(n)
    u = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    pn = np.cross(poly[1] - poly[0], poly[2] - poly[0])
    edges = np.roll(poly, -1, axis=0) - poly
    hits = 0
    for _ in range(count // 1_000_000):
        a, b = rng.random((2, 1_000_000))
        rad, phi = np.sqrt(a), 2 * np.pi * b
        dirs = (
            (rad * np.cos(phi))[:, None] * u + (rad * np.sin(phi))[:, None] * v + np.sqrt(1 - a)[:, None] * n
        )
        t = ((poly[0] - p) @ pn) / (dirs @ pn)
        x = p + t[:, None] * dirs
        side = np.stack([np.cross(edges[i], x - poly[i]) @ pn for i in range(len(poly))], axis=1)
        inside = np.all(side >= 0, axis=1) | np.all(side <= 0, axis=1)
        hits += int(np.count_nonzero(inside & (t > 0)))
    return hits / count


# ----------------------------------------------------------------------------- coaxial disks


def test_coaxial_disks_published_numbers():
    # Issue 4's 0.133931 is F from the SMALL disk (r = 0.1) to the large one (r = 0.2).
    assert ff_coaxial_disks(0.1, 0.2, 0.5) == pytest.approx(0.133931, abs=1e-6)
    assert ff_coaxial_disks(0.2, 0.1, 0.5) == pytest.approx(0.0334828, abs=1e-6)
    assert ff_coaxial_disks(1.0, 1.0, 1.0) == pytest.approx(0.381966, abs=1e-6)
    assert ff_coaxial_disks(1.0, 1.0, 2.0) == pytest.approx(0.171573, abs=1e-6)
    # Equal disks, exactly: distance r → (3 − √5)/2, distance 2r → 3 − 2√2, at any scale.
    r = np.array([1e-3, 0.37, 1.0, 1e3])
    np.testing.assert_allclose(ff_coaxial_disks(r, r, r), (3 - np.sqrt(5)) / 2, rtol=1e-13)
    np.testing.assert_allclose(ff_coaxial_disks(r, r, 2 * r), 3 - 2 * np.sqrt(2), rtol=1e-13)


def test_coaxial_disks_textbook_form_reciprocity_and_limits():
    r1, r2, h = np.meshgrid([0.05, 0.3, 1.0, 2.5], [0.1, 0.7, 1.9], [0.2, 1.0, 4.0], indexing="ij")
    R1, R2 = r1 / h, r2 / h
    X = 1 + (1 + R2**2) / R1**2
    textbook = 0.5 * (X - np.sqrt(X**2 - 4 * (R2 / R1) ** 2))  # Howell C-41 as printed
    np.testing.assert_allclose(ff_coaxial_disks(r1, r2, h), textbook, rtol=1e-9)
    np.testing.assert_allclose(
        r1**2 * ff_coaxial_disks(r1, r2, h), r2**2 * ff_coaxial_disks(r2, r1, h), rtol=1e-13
    )
    assert ff_coaxial_disks(0.3, 1e7, 1.0) == pytest.approx(1.0, abs=1e-12)  # infinite receiver
    np.testing.assert_allclose(ff_coaxial_disks(0.0, r2, h), r2**2 / (h**2 + r2**2), rtol=1e-14)


@pytest.mark.parametrize("r1, r2, h", [(0.1, 0.2, 0.5), (1.0, 1.0, 1.0), (1.0, 1.0, 2.0), (0.8, 0.3, 0.25)])
def test_coaxial_disks_equal_average_of_point_to_disk_over_disk_1(r1, r2, h):
    # F_12 = (1/πr1²) ∫_0^r1 2πa F_d1→2(a) da, with the off-axis element-to-disk factor.
    a, w = gauss(80, 0.0, r1)
    average = 2.0 / r1**2 * np.sum(w * a * ff_point_to_disk(h, r2, a))
    assert average == pytest.approx(ff_coaxial_disks(r1, r2, h), rel=1e-10)


# ----------------------------------------------------------------------------- rectangles


def test_rectangles_published_numbers_and_cube_closure():
    par = ff_parallel_rectangles(1.0, 1.0, 1.0)
    perp = ff_perpendicular_rectangles_common_edge(1.0, 1.0, 1.0)
    assert par == pytest.approx(0.199825, abs=1e-6)
    assert perp == pytest.approx(0.200044, abs=1e-6)
    # A cube face sees the opposite face and four adjacent ones, nothing else: closure.
    assert par + 4 * perp == pytest.approx(1.0, abs=1e-13)
    # Same for a 1 × 2 × 3 box, face 1 × 2 (opposite at distance 3; neighbours of depth 3).
    a, b, c = 1.0, 2.0, 3.0
    box = (
        ff_parallel_rectangles(a, b, c)
        + 2 * ff_perpendicular_rectangles_common_edge(a, c, b)
        + 2 * ff_perpendicular_rectangles_common_edge(b, c, a)
    )
    assert box == pytest.approx(1.0, abs=1e-13)


def test_perpendicular_rectangles_reciprocity():
    w, h, depth = np.meshgrid([0.1, 0.5, 1.0, 3.0], [0.2, 1.0, 2.5], [0.3, 1.0, 4.0], indexing="ij")
    np.testing.assert_allclose(
        w * ff_perpendicular_rectangles_common_edge(w, h, depth),
        h * ff_perpendicular_rectangles_common_edge(h, w, depth),
        rtol=1e-12,
    )


def test_rectangles_two_dimensional_limits_match_crossed_strings():
    # Hottel's crossed-string method for infinitely long strips (an independent 2-D result).
    a, c = np.array([0.5, 1.0, 2.0]), np.array([1.0, 0.3, 2.0])
    np.testing.assert_allclose(
        ff_parallel_rectangles(a, 1e7, c), np.sqrt(1 + (c / a) ** 2) - c / a, rtol=1e-5
    )
    w, h = np.array([1.0, 0.5, 2.0]), np.array([1.0, 2.0, 0.7])
    np.testing.assert_allclose(
        ff_perpendicular_rectangles_common_edge(w, h, 1e5), (w + h - np.hypot(w, h)) / (2 * w), rtol=1e-3
    )


@pytest.mark.parametrize("a, b, c", [(1.0, 1.0, 1.0), (2.0, 0.5, 1.0), (1.0, 1.0, 2.0), (0.6, 1.5, 0.8)])
def test_parallel_rectangles_match_4d_quadrature(a, b, c):
    rect1 = ([0, 0, 0], [a, 0, 0], [0, b, 0])
    rect2 = ([0, 0, c], [a, 0, 0], [0, b, 0])
    brute = ff_double_area(rect1, [0, 0, 1], rect2, [0, 0, -1], n=16)
    assert brute == pytest.approx(ff_parallel_rectangles(a, b, c), rel=1e-9)


@pytest.mark.parametrize("s, g", [(0.5, 0.5), (0.3, 0.8), (1.0, 0.0), (0.0, 1.0)])
def test_perpendicular_rectangles_match_4d_quadrature_with_gaps(s, g):
    # Emitter x ∈ [s, s+w] on z = 0, receiver z ∈ [g, g+h] on x = 0, common edge of length `depth` along y.
    # Configuration-factor algebra turns C-14 (common edge) into this separated case:
    # w F = (s+w)[F(s+w, g+h) − F(s+w, g)] − s[F(s, g+h) − F(s, g)], a term vanishing when s or g is 0.
    w, h, depth = 1.0, 0.7, 1.2

    def xf(x, z):
        return 0.0 if x == 0 or z == 0 else x * ff_perpendicular_rectangles_common_edge(x, z, depth)

    algebra = (xf(s + w, g + h) - xf(s + w, g) - xf(s, g + h) + xf(s, g)) / w
    rect1 = ([s, 0, 0], [w, 0, 0], [0, depth, 0])
    rect2 = ([0, 0, g], [0, 0, h], [0, depth, 0])
    brute = ff_double_area(rect1, [0, 0, 1], rect2, [1, 0, 0], n=28)
    assert brute == pytest.approx(algebra, rel=1e-9)


def test_perpendicular_common_edge_matches_quadrature_of_point_to_polygon():
    # Outer integral by Gauss–Legendre in u (x = w u², which smooths the x log x edge
    # behaviour), inner one exact by the contour formula: independent of C-14's algebra.
    w, h, depth = 1.0, 1.0, 1.0
    u, wu = gauss(48)
    y, wy = gauss(48, 0.0, depth)
    x = w * u**2
    dx = 2 * w * u * wu
    pts = np.stack(np.broadcast_arrays(x[:, None], y[None, :], 0.0), axis=-1).reshape(-1, 3)
    wall = np.array([[0, 0, 0], [0, depth, 0], [0, depth, h], [0, 0, h]], float)
    f = ff_point_to_polygon(pts, [0, 0, 1], wall).reshape(len(x), len(y))
    avg = dx @ f @ wy / (w * depth)
    assert avg == pytest.approx(ff_perpendicular_rectangles_common_edge(w, h, depth), rel=1e-6)


# ----------------------------------------------------------------------------- point to area


def test_point_to_disk_coaxial_and_polygon():
    h, r = np.array([0.1, 1.0, 3.0]), np.array([1.0, 0.5, 2.0])
    np.testing.assert_allclose(ff_point_to_disk(h, r), r**2 / (h**2 + r**2), rtol=1e-14)
    # Off the axis (including outside the disk's shadow) against a 2048-gon by the contour formula.
    for hh, rr, a in [(1.0, 0.5, 0.0), (1.0, 0.5, 0.3), (0.4, 1.0, 0.9), (0.2, 1.0, 1.5), (2.0, 0.7, 3.0)]:
        poly = regular_polygon([a, 0, hh], [0, 0, -1], rr, 2048)
        assert ff_point_to_polygon([0, 0, 0], [0, 0, 1], poly) == pytest.approx(
            ff_point_to_disk(hh, rr, a), rel=1e-5
        )
    # Element in the disk's plane: 1 under the disk, 0 beyond its rim.
    assert ff_point_to_disk(0.0, 1.0, 0.5) == pytest.approx(1.0)
    assert ff_point_to_disk(0.0, 1.0, 2.0) == pytest.approx(0.0, abs=1e-15)


def test_point_to_polygon_matches_rectangle_corner_closed_form():
    # Howell B-3 (element facing a corner), vectorised over points under different corners.
    h, a, b = 0.8, 1.3, 0.6
    rect = np.array([[0, 0, h], [a, 0, h], [a, b, h], [0, b, h]])
    assert ff_point_to_polygon([0, 0, 0], [0, 0, 1], rect) == pytest.approx(
        ff_point_to_rectangle_corner(h, a, b), rel=1e-13
    )
    centre = ff_point_to_polygon([a / 2, b / 2, 0], [0, 0, 1], rect)
    assert centre == pytest.approx(4 * ff_point_to_rectangle_corner(h, a / 2, b / 2), rel=1e-13)


def test_point_to_polygon_matches_quadrature_of_the_kernel():
    # A tilted rectangle, a tilted receiver: 2-D Gauss–Legendre of cosθ1 cosθ2 / (π r²).
    p = np.array([0.1, -0.2, 0.0])
    n = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    o, eu, ev = np.array([-0.5, -0.4, 1.0]), np.array([1.2, 0.0, 0.3]), np.array([0.1, 0.9, -0.2])
    pts, wts = rect_samples(o, eu, ev, 40)
    nq = np.cross(eu, ev)
    nq = -nq / np.linalg.norm(nq)  # facing the point
    d = pts - p
    r2 = np.einsum("ij,ij->i", d, d)
    brute = np.sum(wts * (d @ n) * (-(d @ nq)) / (np.pi * r2 * r2))
    poly = np.array([o, o + eu, o + eu + ev, o + ev])
    assert ff_point_to_polygon(p, n, poly) == pytest.approx(brute, rel=1e-10)
    assert ff_point_to_polygon(p, n, poly[::-1]) == pytest.approx(brute, rel=1e-10)  # orientation-free


@pytest.mark.parametrize(
    "normal, polygon",
    [
        ([0.3, 0.0, 1.0], [[-0.5, -0.5, 0.95], [0.8, -0.4, 1.2], [0.7, 0.6, 1.08], [-0.4, 0.5, 0.87]]),
        ([1.0, 0.0, 0.0], [[-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]]),  # clipped by the tangent plane
        ([0.0, 0.0, 1.0], [[0.2, 0.0, 0.1], [1.5, 0.3, 0.6], [0.4, 1.1, 1.4]]),
    ],
)
def test_point_to_polygon_matches_monte_carlo(normal, polygon):
    exact = ff_point_to_polygon([0, 0, 0], np.array(normal) / np.linalg.norm(normal), polygon)
    mc = ff_point_monte_carlo([0, 0, 0], normal, polygon, count=4_000_000, seed=20240604)
    assert mc == pytest.approx(exact, abs=1e-3)  # binomial σ ≤ 2.5e-4


def test_point_to_polygon_non_convex_is_additive():
    L = np.array([[0, 0, 1], [2, 0, 1], [2, 1, 1], [1, 1, 1], [1, 2, 1], [0, 2, 1]], float)
    a = np.array([[0, 0, 1], [2, 0, 1], [2, 1, 1], [0, 1, 1]], float)
    b = np.array([[0, 1, 1], [1, 1, 1], [1, 2, 1], [0, 2, 1]], float)
    p = np.array([[0.3, 0.4, 0.0], [-1.0, 2.0, 0.5], [1.5, 1.5, 0.2]])
    np.testing.assert_allclose(
        ff_point_to_polygon(p, [0, 0, 1], L),
        ff_point_to_polygon(p, [0, 0, 1], a) + ff_point_to_polygon(p, [0, 0, 1], b),
        rtol=1e-12,
    )


# ----------------------------------------------------------------------------- lens


def test_lens_area():
    r = 0.8
    d = np.array([0.0, 0.3, 1.0, 1.6, 2.0])
    equal = np.where(
        d < 2 * r,
        2 * r * r * np.arccos(np.minimum(d / (2 * r), 1)) - d / 2 * np.sqrt(np.maximum(4 * r * r - d * d, 0)),
        0,
    )
    np.testing.assert_allclose(lens_area(r, r, d), equal, rtol=1e-12, atol=1e-15)
    assert lens_area(1.0, 0.4, 0.5) == pytest.approx(np.pi * 0.16)  # small circle inside
    assert lens_area(1.0, 0.4, 1.4) == 0.0  # touching from outside
    assert lens_area(1.0, 0.6, 1.1) == pytest.approx(lens_area(0.6, 1.0, 1.1), rel=1e-14)
    # Midpoint-grid count of the intersection.
    step = 2e-4
    x = np.arange(-1.0 + step / 2, 1.0, step)
    inside = 0
    for row in np.array_split(x, 20):
        X, Y = np.meshgrid(row, x, indexing="ij")
        inside += np.count_nonzero((X**2 + Y**2 <= 1.0) & ((X - 1.1) ** 2 + Y**2 <= 0.36))
    assert inside * step * step == pytest.approx(lens_area(1.0, 0.6, 1.1), rel=1e-4)


# ----------------------------------------------------------------------------- lamps


def test_point_and_spot_lamps():
    P, h = 1000.0, 2.0
    x = np.array([0.0, 0.5, 1.0, 3.0])
    pts = np.stack([x, 0 * x, 0 * x], axis=1)
    e = point_lamp_irradiance(P, [0, 0, h], pts, [0, 0, 1])
    np.testing.assert_allclose(e, P * h / (4 * np.pi * (h * h + x * x) ** 1.5), rtol=1e-14)
    assert e[0] == pytest.approx(19.894367886486918)  # P / (4π h²)
    assert point_lamp_irradiance(P, [0, 0, h], [0, 0, 0], [0, 0, -1]) == 0.0  # facing away
    # Spot pointing down, cone 60°, no blend: the point lamp inside the cone, nothing outside.
    size = np.radians(60.0)
    edge = h * np.tan(size / 2)
    xs = np.array([0.0, edge * 0.99, edge * 1.01])
    ps = np.stack([xs, 0 * xs, 0 * xs], axis=1)
    hard = spot_lamp_irradiance(P, size, 0.0, [0, 0, h], [0, 0, -1], ps, [0, 0, 1])
    np.testing.assert_allclose(
        hard, point_lamp_irradiance(P, [0, 0, h], ps, [0, 0, 1]) * [1, 1, 0], rtol=1e-14
    )
    # Blend: smoothstep over the whole cone for blend = 1; half-way in cos θ gives 0.5.
    ch = np.cos(size / 2)
    assert spot_falloff(1.0, size, 1.0) == 1.0
    assert spot_falloff(ch, size, 1.0) == 0.0
    assert spot_falloff((1 + ch) / 2, size, 1.0) == pytest.approx(0.5)
    assert spot_falloff(ch + 0.25 * (1 - ch) * 0.4, size, 0.4) == pytest.approx(3 * 0.25**2 - 2 * 0.25**3)
    assert spot_falloff(ch + 0.5 * (1 - ch), size, 0.4) == 1.0  # past the blend zone


def test_sun():
    n = np.array([[0, 0, 1], [0, 0, -1], [1, 0, 0]], float)
    to_sun = np.array([np.sin(0.3), 0, np.cos(0.3)])
    np.testing.assert_allclose(
        sun_irradiance(3.0, to_sun, n), [3 * np.cos(0.3), 0, 3 * np.sin(0.3)], rtol=1e-14
    )


def test_rect_area_lamp():
    P, sx, sy, h = 50.0, 1.0, 0.5, 0.8
    lamp = [0.2, -0.1, h]
    # Below the centre: four corner factors (Howell B-3) times P/A.
    e0 = area_lamp_rect_irradiance(P, sx, sy, lamp, [0.2, -0.1, 0], [0, 0, 1])
    assert e0 == pytest.approx(P / (sx * sy) * 4 * ff_point_to_rectangle_corner(h, sx / 2, sy / 2), rel=1e-13)
    # Far away: a point source of intensity L·A·cosθ = P/π · cosθ (one-sided Lambertian).
    far = area_lamp_rect_irradiance(P, sx, sy, [0, 0, 100.0], [0, 0, 0], [0, 0, 1])
    assert far == pytest.approx(P / (np.pi * 100.0**2), rel=1e-4)
    # Very close: the lamp fills the hemisphere, E → π L = P / A.
    near = area_lamp_rect_irradiance(P, sx, sy, [0, 0, 1e-6], [0, 0, 0], [0, 0, 1])
    assert near == pytest.approx(P / (sx * sy), rel=1e-5)
    # One-sided: above the lamp, or with the lamp turned to face up, nothing arrives below.
    assert area_lamp_rect_irradiance(P, sx, sy, lamp, [0, 0, 2 * h], [0, 0, -1]) == 0.0
    up = np.diag([1.0, -1.0, -1.0])  # rotated 180° about x: shines along +z
    assert area_lamp_rect_irradiance(P, sx, sy, lamp, [0, 0, 0], [0, 0, 1], rotation=up) == 0.0
    # All of P reaches an infinite parallel plane: ∬ E dA = P (x = h tan u maps R onto (−π/2, π/2)).
    u, wu = gauss(160, -np.pi / 2, np.pi / 2)
    x, wx = h * np.tan(u), wu * h / np.cos(u) ** 2
    pts = np.stack(np.broadcast_arrays(x[:, None] + 0.2, x[None, :] - 0.1, 0.0), axis=-1).reshape(-1, 3)
    e = area_lamp_rect_irradiance(P, sx, sy, lamp, pts, [0, 0, 1]).reshape(len(x), len(x))
    assert wx @ e @ wx == pytest.approx(P, rel=1e-6)


def test_disk_area_lamp():
    P, r, h = 20.0, 0.3, 1.1
    assert area_lamp_disk_irradiance(P, r, h) == pytest.approx(P / (np.pi * (h * h + r * r)), rel=1e-14)
    # Off the axis: the same radiance through the contour formula on a fine polygon.
    poly = regular_polygon([0.4, 0, h], [0, 0, -1], r, 2048, equal_area=True)
    e = P / (np.pi * r * r) * ff_point_to_polygon([0, 0, 0], [0, 0, 1], poly)
    assert area_lamp_disk_irradiance(P, r, h, 0.4) == pytest.approx(e, rel=1e-6)
    # Energy: all of P lands on the infinite plane.
    total, _ = quad(
        lambda a: 2 * np.pi * a * area_lamp_disk_irradiance(P, r, h, a), 0, np.inf, epsabs=0, epsrel=1e-12
    )
    assert total == pytest.approx(P, rel=1e-8)


# ----------------------------------------------------------------------------- furnace


def test_furnace():
    np.testing.assert_allclose(furnace_radiance(1.0, [0.5, 0.9, 0.99]), [2.0, 10.0, 100.0], rtol=1e-12)
    # Classical radiosity of a closed unit cube (6 faces, closed-form F): B = E / (1 − ρ).
    par = ff_parallel_rectangles(1, 1, 1)
    perp = ff_perpendicular_rectangles_common_edge(1, 1, 1)
    F = np.full((6, 6), perp)
    np.fill_diagonal(F, 0.0)
    for i in range(6):
        F[i, i ^ 1] = par  # faces 2k and 2k+1 are opposite
    for rho in (0.5, 0.9, 0.99):
        B = np.linalg.solve(np.eye(6) - rho * F, np.full(6, np.pi))
        np.testing.assert_allclose(B / np.pi, furnace_radiance(1.0, rho), rtol=1e-10)
