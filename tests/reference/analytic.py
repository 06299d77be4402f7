"""Independent reference values for the transport solver: closed forms only, pure numpy.

Nothing here imports or mirrors ovrad_addon; tests of the engine compare against these.
Every form factor F is the fraction of the diffuse power leaving the *first* argument's
surface that reaches the second (unoccluded), i.e. F_12 = (1/A_1) ∬ cosθ1 cosθ2 / (π r²) dA2 dA1.

Sources ("Howell" = J. R. Howell, *A Catalog of Radiation Heat Transfer Configuration
Factors*, thermalradiation.net; "Siegel & Howell" = *Thermal Radiation Heat Transfer*):

- coaxial parallel disks ............ Howell C-41 (C-40 for equal radii); Siegel & Howell App. C
- parallel opposed rectangles ....... Howell C-11
- perpendicular, common edge ........ Howell C-14
- element to parallel disk .......... Howell B-13 (on the axis); Siegel & Howell App. C (off it)
- element to rectangle, at corner ... Howell B-3
- element to polygon ................ Lambert's contour formula (Siegel & Howell, "contour
                                      integration"; Baum, Rushmeier & Winget, SIGGRAPH 1989)
- lamps in Blender/Cycles units ..... the project's blender.md, "Light and units"

All functions broadcast over array arguments (numpy rules) unless stated otherwise.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "area_lamp_disk_irradiance",
    "area_lamp_rect_irradiance",
    "ff_coaxial_disks",
    "ff_parallel_rectangles",
    "ff_perpendicular_rectangles_common_edge",
    "ff_point_to_disk",
    "ff_point_to_polygon",
    "ff_point_to_rectangle_corner",
    "furnace_radiance",
    "lens_area",
    "point_lamp_irradiance",
    "regular_polygon",
    "smoothstep",
    "spot_falloff",
    "spot_lamp_irradiance",
    "sun_irradiance",
]


# --------------------------------------------------------------------------- form factors


def ff_coaxial_disks(r1, r2, h):
    """F from disk 1 (radius r1) to a parallel coaxial disk 2 (radius r2) at distance h.

    Howell C-41 / Siegel & Howell App. C: with R_i = r_i/h and X = 1 + (1 + R2²)/R1²,
        F_12 = ½ [X − sqrt(X² − 4 (R2/R1)²)].
    Evaluated in the algebraically identical, cancellation-free form
        F_12 = 2 r2² / (Z + sqrt(Z² − 4 r1² r2²)),   Z = h² + r1² + r2²,
    which is exact also for r1 → 0 (→ r2²/(h²+r2²), the point-to-disk factor).

    Reproduces: (0.1, 0.2, 0.5) → F_12 = 0.133931 (small disk to large one; this is the
    number quoted in issue 4, and the value of the EES example F3D_3(0.1, 0.2, 0.5));
    the reverse F_21 = F_12·r1²/r2² = 0.0334829. Equal disks at distance r → (3 − √5)/2 =
    0.381966; at distance 2r → 3 − 2√2 = 0.171573.
    """
    r1, r2, h = (np.asarray(v, dtype=float) for v in (r1, r2, h))
    z = h * h + r1 * r1 + r2 * r2
    return 2.0 * r2 * r2 / (z + np.sqrt(z * z - 4.0 * r1 * r1 * r2 * r2))


def ff_parallel_rectangles(a, b, c):
    """F between identical, parallel, directly opposed rectangles a × b at distance c.

    Howell C-11 (Hottel; Hamilton & Morgan): X = a/c, Y = b/c,
        F = 2/(π X Y) { ln sqrt[(1+X²)(1+Y²)/(1+X²+Y²)]
                        + X sqrt(1+Y²) atan(X/sqrt(1+Y²)) + Y sqrt(1+X²) atan(Y/sqrt(1+X²))
                        − X atan X − Y atan Y }.
    Symmetric (F_12 = F_21). Unit squares at unit distance → 0.199825 (0.1998244).
    Evaluated as written, so the terms cancel for distant rectangles: relative error ~3e-9
    at X = Y = 0.01, ~1e-4 at 0.001, meaningless below 1e-4 (use ab/(πc²) there).
    """
    a, b, c = (np.asarray(v, dtype=float) for v in (a, b, c))
    x, y = a / c, b / c
    sx, sy = np.sqrt(1.0 + x * x), np.sqrt(1.0 + y * y)
    s = (
        0.5 * np.log((1.0 + x * x) * (1.0 + y * y) / (1.0 + x * x + y * y))
        + x * sy * np.arctan(x / sy)
        + y * sx * np.arctan(y / sx)
        - x * np.arctan(x)
        - y * np.arctan(y)
    )
    return 2.0 * s / (np.pi * x * y)


def ff_perpendicular_rectangles_common_edge(w, h, length):
    """F from rectangle 1 (w × l) to rectangle 2 (h × l), sharing their edge of l = `length` at 90°.

    Howell C-14 ("two finite rectangles of same length, having one common edge, and at an
    angle of 90° to each other"): W = w/l, H = h/l, w the width of the emitting rectangle 1
    (perpendicular to the common edge), h the height of the receiving rectangle 2,
        F_12 = 1/(π W) { W atan(1/W) + H atan(1/H) − sqrt(H²+W²) atan(1/sqrt(H²+W²))
                         + ¼ ln[ (1+W²)(1+H²)/(1+W²+H²)
                                 · (W²(1+W²+H²)/((1+W²)(W²+H²)))^(W²)
                                 · (H²(1+W²+H²)/((1+H²)(W²+H²)))^(H²) ] }.
    The powers are taken as W² ln(...) to stay finite. Reciprocity: w·F(w, h, l) = h·F(h, w, l).
    Unit squares → 0.200044 (0.2000438).
    """
    w, h, length = (np.asarray(v, dtype=float) for v in (w, h, length))
    W, H = w / length, h / length
    W2, H2 = W * W, H * H
    q = np.sqrt(W2 + H2)
    s = W2 + H2 + 1.0
    log_term = (
        np.log((1.0 + W2) * (1.0 + H2) / s)
        + W2 * np.log(W2 * s / ((1.0 + W2) * (W2 + H2)))
        + H2 * np.log(H2 * s / ((1.0 + H2) * (W2 + H2)))
    )
    return (W * np.arctan(1.0 / W) + H * np.arctan(1.0 / H) - q * np.arctan(1.0 / q) + 0.25 * log_term) / (
        np.pi * W
    )


def ff_point_to_disk(h, r, offset=0.0):
    """F from a differential area to a parallel disk of radius r whose plane is h away.

    The element faces the disk; `offset` is the element's distance from the disk's axis.
    Coaxial (Howell B-13 with zero tilt; Siegel & Howell App. C):  F = r² / (h² + r²).
    Off the axis (Siegel & Howell App. C, element to a parallel disk):
        F = ½ [1 − (h² + a² − r²) / sqrt((h² + a² + r²)² − 4 a² r²)],   a = offset,
    evaluated as r² (Z + S − 2a²) / (S (Z + S)) with Z = h² + a² + r², S = sqrt(Z² − 4a²r²)
    (identical, and free of cancellation far from the disk).
    """
    h, r, a = (np.asarray(v, dtype=float) for v in (h, r, offset))
    z = h * h + a * a + r * r
    s = np.sqrt(z * z - 4.0 * a * a * r * r)
    return r * r * (z + s - 2.0 * a * a) / (s * (z + s))


def ff_point_to_rectangle_corner(h, a, b):
    """F from a differential area to a parallel a × b rectangle, the element facing one corner.

    Howell B-3 (element on the normal through a corner of the rectangle, at distance h):
    A = a/h, B = b/h,
        F = 1/(2π) [ A/sqrt(1+A²) atan(B/sqrt(1+A²)) + B/sqrt(1+B²) atan(A/sqrt(1+B²)) ].
    An element below the centre of an sx × sy rectangle sees 4·F(h, sx/2, sy/2).
    """
    h, a, b = (np.asarray(v, dtype=float) for v in (h, a, b))
    A, B = a / h, b / h
    sa, sb = np.sqrt(1.0 + A * A), np.sqrt(1.0 + B * B)
    return (A / sa * np.arctan(B / sa) + B / sb * np.arctan(A / sb)) / (2.0 * np.pi)


def _contour_sum(rel, normal):
    """Σ_edges γ_e (n · unit(R_e × R_e+1)) for vertices `rel` (m, k, 3) relative to each point."""
    nxt = np.roll(rel, -1, axis=-2)
    cr = np.cross(rel, nxt)
    cn = np.linalg.norm(cr, axis=-1)
    gamma = np.arctan2(cn, np.einsum("...i,...i->...", rel, nxt))
    proj = np.einsum("...i,...i->...", cr, normal[..., None, :])
    return np.sum(np.where(cn > 0.0, gamma * proj / np.where(cn > 0.0, cn, 1.0), 0.0), axis=-1)


def _clip_halfspace(poly, p, n):
    """Sutherland–Hodgman: the part of polygon `poly` (k, 3) where n·(x − p) ≥ 0."""
    d = (poly - p) @ n
    out = []
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if d[i] >= 0.0:
            out.append(poly[i])
        if (d[i] >= 0.0) != (d[j] >= 0.0):
            t = d[i] / (d[i] - d[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.array(out).reshape(-1, 3)


def ff_point_to_polygon(points, normals, polygon):
    """F from differential areas (points (m, 3) or (3,), unit normals same shape or (3,)) to a
    planar polygon (k, 3), by Lambert's contour formula (exact, any orientation):

        F = 1/(2π) |Σ_e γ_e  n · (R_e × R_e+1)/|R_e × R_e+1||,

    R_e the vector from the point to vertex e, γ_e the angle between R_e and R_e+1
    (Siegel & Howell, "contour integration"; Baum, Rushmeier & Winget 1989, eq. 3). It
    holds for any simple (also non-convex) polygon wholly on the front side of the point's
    tangent plane; where the polygon crosses that plane it is first clipped to the front
    side (the hidden part receives nothing), so the result is exact for any placement.
    The polygon is one-sided only through that clipping: which side of the polygon faces
    the point is not checked (a lamp's one-sidedness is handled by its caller).
    Returns an array of shape (m,) (or a scalar for a single point).
    """
    pts = np.asarray(points, dtype=float)
    single = pts.ndim == 1
    pts = np.atleast_2d(pts)
    nrm = np.broadcast_to(np.asarray(normals, dtype=float), pts.shape)
    poly = np.asarray(polygon, dtype=float)
    rel = poly[None, :, :] - pts[:, None, :]
    height = np.einsum("mki,mi->mk", rel, nrm)
    front = np.all(height >= 0.0, axis=1)
    out = np.abs(_contour_sum(rel, nrm)) / (2.0 * np.pi)
    for i in np.flatnonzero(~front):
        clipped = _clip_halfspace(poly, pts[i], nrm[i])
        out[i] = 0.0 if len(clipped) < 3 else abs(_contour_sum(clipped - pts[i], nrm[i])) / (2.0 * np.pi)
    return out[0] if single else out


def regular_polygon(center, normal, radius, k, equal_area=False):
    """Vertices (k, 3) of a regular k-gon in the plane through `center` normal to `normal`.

    Inscribed in the circle of `radius` (relative area deficit ≈ 2π²/(3k²): 1.6e-6 at
    k = 2048), or, with equal_area=True, scaled to have the disk's exact area π r².
    Vertices run counter-clockwise seen from the side `normal` points to.
    """
    c = np.asarray(center, dtype=float)
    n = np.asarray(normal, dtype=float)
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, helper)
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    if equal_area:  # same area as the disk: k/2 R² sin(2π/k) = π r²
        radius = radius * np.sqrt(2.0 * np.pi / (k * np.sin(2.0 * np.pi / k)))
    t = 2.0 * np.pi * np.arange(k) / k
    return c + radius * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


# --------------------------------------------------------------------------- geometry


def lens_area(r1, r2, d):
    """Area common to two circles of radii r1, r2 whose centres are d apart.

    Standard circle–circle intersection (e.g. Weisstein, MathWorld "Circle-Circle
    Intersection"):
        A = r1² acos((d² + r1² − r2²)/(2 d r1)) + r2² acos((d² + r2² − r1²)/(2 d r2))
            − ½ sqrt((−d + r1 + r2)(d + r1 − r2)(d − r1 + r2)(d + r1 + r2)),
    with A = 0 for d ≥ r1 + r2 and A = π min(r1, r2)² for d ≤ |r1 − r2| (one inside the other).
    For r1 = r2 = r it reduces to 2r² acos(d/2r) − (d/2) sqrt(4r² − d²).
    """
    r1, r2, d = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (r1, r2, d)))
    inside = d <= np.abs(r1 - r2)
    apart = d >= r1 + r2
    ds = np.where(inside | apart, 1.0, d)  # keep the general branch finite where unused
    c1 = np.clip((ds * ds + r1 * r1 - r2 * r2) / (2.0 * ds * r1), -1.0, 1.0)
    c2 = np.clip((ds * ds + r2 * r2 - r1 * r1) / (2.0 * ds * r2), -1.0, 1.0)
    k = (-ds + r1 + r2) * (ds + r1 - r2) * (ds - r1 + r2) * (ds + r1 + r2)
    general = r1 * r1 * np.arccos(c1) + r2 * r2 * np.arccos(c2) - 0.5 * np.sqrt(np.maximum(k, 0.0))
    out = np.where(inside, np.pi * np.minimum(r1, r2) ** 2, np.where(apart, 0.0, general))
    return out[()] if out.ndim == 0 else out


# --------------------------------------------------------------------------- lamps (Cycles units)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def point_lamp_irradiance(power, lamp, points, normals):
    """Irradiance (W/m²) from a Cycles point lamp of power P (W), radius 0, at `lamp`.

    blender.md "Light and units": Cycles spreads P over 4π sr, so the intensity is P/(4π)
    W/sr and E = P/(4π d²) · max(cos θ, 0), d the distance, θ the incidence angle at the
    receiver. On a plane at height h below the lamp, at horizontal offset x:
    E = P h / (4π (h² + x²)^{3/2}).
    """
    rel = np.asarray(lamp, dtype=float) - np.asarray(points, dtype=float)
    d2 = np.einsum("...i,...i->...", rel, rel)
    cos = np.einsum("...i,...i->...", rel, np.asarray(normals, dtype=float)) / np.sqrt(d2)
    return np.asarray(power, dtype=float) * np.maximum(cos, 0.0) / (4.0 * np.pi * d2)


def smoothstep(t):
    """3t² − 2t³ on t clamped to [0, 1] (Cycles' smoothstepf)."""
    t = np.clip(np.asarray(t, dtype=float), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def spot_falloff(cos_axis, spot_size, blend):
    """Cycles' spot cone factor for a direction at cos_axis = cos(angle from the spot axis).

    blender.md: smoothstep((cos θ_axis − cos(spot_size/2)) / ((1 − cos(spot_size/2)) · blend)),
    spot_size the full cone angle (radians). blend = 0 gives a hard edge: 1 inside the
    cone, 0 outside.
    """
    cos_axis = np.asarray(cos_axis, dtype=float)
    ch = np.cos(0.5 * np.asarray(spot_size, dtype=float))
    blend = np.asarray(blend, dtype=float)
    hard = (cos_axis > ch).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        soft = smoothstep((cos_axis - ch) / ((1.0 - ch) * blend))
    return np.where(blend > 0.0, soft, hard)


def spot_lamp_irradiance(power, spot_size, blend, lamp, axis, points, normals):
    """Irradiance from a Cycles spot lamp (radius 0) at `lamp` pointing along `axis`.

    blender.md: a point lamp of the same power (the cone does not concentrate it) times
    spot_falloff(cos θ_axis, spot_size, blend), θ_axis the angle between the axis and the
    direction from the lamp to the receiver. (Blender's spot points along its local −Z.)
    """
    rel = np.asarray(points, dtype=float) - np.asarray(lamp, dtype=float)
    cos_axis = np.einsum("...i,...i->...", _unit(rel), _unit(axis))
    return point_lamp_irradiance(power, lamp, points, normals) * spot_falloff(cos_axis, spot_size, blend)


def sun_irradiance(strength, to_sun, normals):
    """Irradiance from a sun lamp of strength S (W/m²): E = S · max(cos θ, 0).

    blender.md: strength is the irradiance on a surface facing the sun; θ is the angle
    between the receiver's normal and `to_sun` (the direction towards the sun, i.e. the
    opposite of the lamp's local −Z). The `angle` setting softens shadows; its effect on
    an unoccluded plane is of order angle² and is not modelled here.
    """
    cos = np.einsum("...i,...i->...", _unit(to_sun), np.asarray(normals, dtype=float))
    return np.asarray(strength, dtype=float) * np.maximum(cos, 0.0)


def area_lamp_rect_irradiance(power, size_x, size_y, lamp, points, normals, rotation=None):
    """Irradiance from a Cycles rectangular (or square) area lamp of power P, one-sided.

    blender.md: radiance L = P/(π A), A = size_x·size_y, emitted from the front side only
    (Blender's area lamps face their local −Z). For a Lambertian emitter the irradiance is
    E = L · π · F(point → rectangle) = (P/A) · F, F by ff_point_to_polygon (the rectangle
    clipped to the receiver's front half-space). Receivers behind the lamp's plane get 0.
    `rotation` (3×3, columns = the lamp's local x, y, z axes in world space) defaults to
    the identity: a lamp parallel to the xy plane shining down −z.
    """
    R = np.eye(3) if rotation is None else np.asarray(rotation, dtype=float)
    c = np.asarray(lamp, dtype=float)
    hx, hy = 0.5 * size_x, 0.5 * size_y
    corners = c + np.array([[-hx, -hy, 0.0], [hx, -hy, 0.0], [hx, hy, 0.0], [-hx, hy, 0.0]]) @ R.T
    pts = np.atleast_2d(np.asarray(points, dtype=float))
    front = (pts - c) @ (-R[:, 2]) > 0.0
    f = np.where(front, ff_point_to_polygon(pts, normals, corners), 0.0)
    e = power / (size_x * size_y) * f
    return e[0] if np.asarray(points).ndim == 1 else e


def area_lamp_disk_irradiance(power, radius, h, offset=0.0):
    """Irradiance from a Cycles disk area lamp of power P and radius r, on a parallel
    receiving plane facing it, h below the lamp, at distance `offset` from the lamp's axis.

    Radiance L = P/(π · π r²) (blender.md), so E = L π F = P/(π r²) · ff_point_to_disk(h, r,
    offset); on the axis E = P / (π (h² + r²)). A disk lamp of size_x ≠ size_y (ellipse) has
    no closed form here: use area_lamp_rect_irradiance's recipe with ff_point_to_polygon on
    a fine polygon of the ellipse.
    """
    r = np.asarray(radius, dtype=float)
    return np.asarray(power, dtype=float) / (np.pi * r * r) * ff_point_to_disk(h, r, offset)


# --------------------------------------------------------------------------- furnace


def furnace_radiance(Le, rho):
    """Radiance everywhere in a closed room with uniform emitted radiance Le and reflectance ρ.

    Derivation: in a closed enclosure every point's hemisphere sees the enclosure's walls
    only, so Σ_j F_ij = 1 (closure). The rendering equation for diffuse surfaces,
    L(x) = Le + ρ/π ∫_H L(y(ω)) cos θ dω, then has the constant solution L = Le + ρ L
    (∫_H cos θ dω = π), i.e. L = Le / (1 − ρ); it is the unique solution for ρ < 1 (the
    Neumann series Σ ρⁿ Le converges). In radiosity terms B = E / (1 − ρ), B = π L, E = π Le.
    Each bounce adds ρⁿ: truncating after n bounces leaves a relative deficit ρ^(n+1).
    """
    return np.asarray(Le, dtype=float) / (1.0 - np.asarray(rho, dtype=float))
