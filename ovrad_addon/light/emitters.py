"""Emissive triangles as a fixed rule of samples (the same for every receiver point: no noise) and
the exact irradiance of a triangle at a point (polygon_irradiance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from ..geometry import subtriangle_centroids, subtriangle_corners
from ..scene.albedo import TextureAlbedo, texel_means, texel_spans
from ..scene.surfaces import Surfaces, triangle_geometry

SQRT_2PI = np.sqrt(2.0 * np.pi)


@dataclass(frozen=True)
class EmitterSamples:
    """A fixed quadrature of the emitting surfaces: points (k, 3), unit normals (k, 3), the area
    each point stands for (k,), and its emitted radiance (k, 3) (of a light tree's cut: the radiance
    that gives the node's power vector along its normal)."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    radiance: np.ndarray
    # each emitting triangle's own samples (None when samples stand for a share of the total power):
    # the first sample of each triangle's run (s,), the triangle (s,) of each run, and per emitting
    # triangle its corners (E, 3, 3), radiance (E, 3) and spacing of its samples (E,)
    run_start: np.ndarray | None = None
    run_triangle: np.ndarray | None = None
    corners: np.ndarray | None = None
    triangle_radiance: np.ndarray | None = None
    spacing: np.ndarray | None = None
    # the nodes of a light tree's cut, for more emitting triangles than samples (light.tree.LightTree):
    # each one's central triangle (k,), the sample's place; corners and triangle_radiance then hold
    # every emitting triangle's
    pick: np.ndarray | None = None
    # a cut node's faces turn: the direction (k, 3) and length (k,) of their mean unit normal and
    # their normals' covariance (k, 6: xx, yy, zz, xy, xz, yz); a sample then lights a point by the
    # faces facing it (front_cosine), not by its mean normal alone (`normals`: its central triangle's)
    axis: np.ndarray | None = None
    normal_length: np.ndarray | None = None
    normal_cov: np.ndarray | None = None
    # ... and each node's centroid (k, 3) and second moment of area about it (k, 6): a sample's
    # light is corrected to second order for its node's extent (light.tree.second_order)
    centre: np.ndarray | None = None
    moment: np.ndarray | None = None


# An emitting triangle whose Emission Color is an image lights its surroundings through pieces of
# about PIECE_TEXELS texels of that image, each emitting its own mean (k^2 congruent pieces, k from
# the triangle's longest edge in texels): a screen's warm and cool halves light the wall beside each
# the way Cycles does, where the triangle's mean colour lit it evenly.
PIECE_TEXELS = 1.0
PIECES_PER_EDGE_MOST = 64  # a triangle splits into at most 64^2 pieces
PIECES_MOST = 1 << 13  # pieces over all emitters; beyond, every triangle's split is made coarser
PIECE_MEAN_SPLIT = 3  # a piece's mean colour: over at least the centroids of its 3^2 sub-triangles
# A triangle whose pieces all emit within this share of its mean stays whole: a piece costs a point
# near it a walk of the light tree to that piece (a uniform band of a screen needs none)
PIECE_VARIATION = 0.01


def emitting_triangles(surfaces: Surfaces, emitters: np.ndarray, scale: float = 1.0, piece_size: float = 0.0):
    """The corners (E, 3, 3) and radiance (E, 3) of the triangles among `emitters` ((T,) bool) that
    emit some power; a triangle whose emitted colour is an image (Surfaces.emitted) comes as its
    pieces (emission_pieces, none smaller than piece_size), each with its own mean radiance, in its
    place."""
    tri = np.flatnonzero(np.asarray(emitters, bool) & (surfaces.emission.sum(axis=1) > 0))
    c = surfaces.corners[tri]
    radiance = surfaces.emission[tri] * scale
    if surfaces.emitted is not None:
        c, radiance = emission_pieces(surfaces.emitted, tri, c, radiance, scale, piece_size)
    area, _ = triangle_geometry(c)
    keep = area * radiance.sum(axis=1) > 0
    return c[keep], radiance[keep]


def piece_splits(
    table: TextureAlbedo, tri: np.ndarray, corners: np.ndarray | None = None, piece_size: float = 0.0
) -> np.ndarray:
    """(t,) int64: into k^2 pieces each triangle `tri` splits for its light, k at least 1: the
    triangles with an image, so that a piece's edges span about PIECE_TEXELS texels but its
    longest is no shorter than piece_size (corners (t, 3, 3) then give the triangles' edges), at
    most PIECES_PER_EDGE_MOST per edge and PIECES_MOST pieces in all; the others (a constant or
    painted emission, linear over the triangle) stay whole."""
    k = np.ones(len(tri), np.int64)
    span = texel_spans(table, tri)
    mapped = np.flatnonzero(span > 0)
    if len(mapped) == 0:
        return k
    want = np.ceil(span[mapped] / PIECE_TEXELS)
    if piece_size > 0:
        c = corners[mapped]
        edge = np.linalg.norm(c[:, [1, 2, 0]] - c, axis=2).max(axis=1)
        want = np.minimum(want, np.ceil(edge / piece_size))
    k[mapped] = np.clip(want, 1, PIECES_PER_EDGE_MOST).astype(np.int64)
    total = int(np.sum(k * k))
    if total > PIECES_MOST:
        shrink = np.sqrt((PIECES_MOST - (len(k) - len(mapped))) / max(total - (len(k) - len(mapped)), 1))
        k[mapped] = np.maximum(1, np.floor(k[mapped] * shrink)).astype(np.int64)
    return k


def emission_pieces(
    table: TextureAlbedo,
    tri: np.ndarray,
    corners: np.ndarray,
    radiance: np.ndarray,
    scale: float,
    piece_size: float = 0.0,
):
    """Emitting triangles tri (t,), corners (t, 3, 3), radiance (t, 3), with each one split as
    piece_splits says (pieces no smaller than piece_size): (corners (E, 3, 3), radiance (E, 3)), a
    triangle's pieces in its place, a piece's radiance the mean of the emitted colour over it x
    scale. A triangle left whole, or whose pieces emit within PIECE_VARIATION of their mean, keeps
    its row as given."""
    k = piece_splits(table, tri, corners, piece_size)
    if np.all(k == 1):
        return corners, radiance
    rows = np.ones(len(tri), np.int64)  # rows each triangle gives
    split = []  # (triangles, their pieces' corners (s, p, 3, 3), radiance (s, p, 3))
    for level in np.unique(k[k > 1]):
        sel = np.flatnonzero(k == level)
        bary = subtriangle_corners(int(level))  # (p, 3, 3): each piece's corners' barycentrics
        t = tri[sel]
        pc = np.einsum("pab,tbj->tpaj", bary, corners[sel])
        uv = np.einsum("pab,tbj->tpaj", bary, table.uv[t]).reshape(-1, 3, 2)
        paint = None
        if table.corners is not None:
            paint = np.einsum("pab,tbj->tpaj", bary, table.corners[t]).reshape(-1, 3, 3)
        rep = np.repeat(t, len(bary))
        pieces = TextureAlbedo(
            table.images, table.image_of[rep], uv, table.tint[rep], corners=paint, srgb=table.srgb
        )
        means = texel_means(
            pieces, np.zeros((len(rep), 3)), pc.reshape(-1, 3, 3), PIECE_MEAN_SPLIT, clip=False
        )
        means = means.reshape(len(t), len(bary), 3)
        mean = means.mean(axis=1)
        spread = np.abs(means - mean[:, None]).sum(axis=2).max(axis=1)
        uneven = np.flatnonzero(spread > PIECE_VARIATION * mean.sum(axis=1))
        rows[sel[uneven]] = len(bary)
        split.append((sel[uneven], pc[uneven], means[uneven] * scale))
    first = np.concatenate([[0], np.cumsum(rows)[:-1]])
    out_c = np.empty((int(rows.sum()), 3, 3))
    out_r = np.empty((len(out_c), 3))
    whole = rows == 1
    out_c[first[whole]], out_r[first[whole]] = corners[whole], radiance[whole]
    for sel, pc, pr in split:
        at = (first[sel][:, None] + np.arange(pc.shape[1])).ravel()
        out_c[at], out_r[at] = pc.reshape(-1, 3, 3), pr.reshape(-1, 3)
    return out_c, out_r


def emitter_samples(c: np.ndarray, radiance: np.ndarray, count: int) -> EmitterSamples:
    """About `count` points over the emitting triangles c (E, 3, 3) of radiance (E, 3)
    (emitting_triangles), shared by every receiver point, for at most `count` triangles (more:
    light.tree.LightTree's cut).

    A fixed rule instead of random samples per receiver: neighbouring bake points see the same
    samples, so the result is smooth (no noise); its error is that of a midpoint rule. Each
    triangle gets points in proportion to its power, as the centroids of its k^2 congruent
    sub-triangles.
    """
    area, normal = triangle_geometry(c)
    power = area * radiance.sum(axis=1)
    if len(c) == 0 or count < 1:
        z = np.zeros((0, 3))
        return EmitterSamples(z, z, np.zeros(0), z)
    if len(c) > count:
        raise ValueError(f"{len(c)} emitting triangles for {count} samples: use the light tree's cut")
    total = power.sum()
    want = np.maximum(1, np.round(count * power / total)).astype(np.int64)
    side = np.ceil(np.sqrt(want)).astype(np.int64)
    pts, nrm, wts, rad, owner = [], [], [], [], []
    for k in np.unique(side):
        sel = np.flatnonzero(side == k)
        uv = subtriangle_centroids(int(k))
        cc = c[sel]
        p = cc[:, None, 0] + uv[None, :, :1] * (cc[:, None, 1] - cc[:, None, 0])
        p = p + uv[None, :, 1:] * (cc[:, None, 2] - cc[:, None, 0])
        pts.append(p.reshape(-1, 3))
        nrm.append(np.repeat(normal[sel], len(uv), axis=0))
        wts.append(np.repeat(area[sel] / len(uv), len(uv)))
        rad.append(np.repeat(radiance[sel], len(uv), axis=0))
        owner.append(np.repeat(sel, len(uv)))
    owner = np.concatenate(owner)  # each triangle's samples are one run
    start = np.flatnonzero(np.r_[True, owner[1:] != owner[:-1]])
    spacing = np.sqrt(area / side**2)
    return EmitterSamples(
        np.vstack(pts),
        np.vstack(nrm),
        np.concatenate(wts),
        np.vstack(rad),
        start,
        owner[start],
        c,
        radiance,
        spacing,
    )


def polygon_irradiance(points: np.ndarray, normals: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Irradiance (k,) at points (k, 3) with unit normals (k, 3) from triangles (k, 3, 3) of unit
    radiance emitting from both sides, unoccluded: (1/2) |sum over edges gamma_i n . c_i| (Lambert's
    contour integral, pi x the form factor) over the part of the triangle above the point's plane."""
    h = plane_heights(triangles - points[:, None], normals)
    whole = h.min(axis=1) > 0
    if whole.all():
        return _unclipped_irradiance(triangles - points[:, None], normals)
    if whole.any():
        out = np.empty(len(points))
        out[whole] = _unclipped_irradiance(triangles[whole] - points[whole, None], normals[whole])
        part = ~whole
        out[part] = polygon_irradiance(points[part], normals[part], triangles[part])
        return out
    slots = np.zeros((len(points), 6, 3))
    valid = np.zeros((len(points), 6), bool)
    for j in range(3):  # Sutherland-Hodgman: each corner above the plane, each edge's crossing
        a, b = triangles[:, j], triangles[:, (j + 1) % 3]
        ha, hb = h[:, j], h[:, (j + 1) % 3]
        slots[:, 2 * j], valid[:, 2 * j] = a, ha > 0
        cross = (ha > 0) != (hb > 0)
        f = np.where(cross, ha / np.where(cross, ha - hb, 1.0), 0.0)
        slots[:, 2 * j + 1], valid[:, 2 * j + 1] = a + f[:, None] * (b - a), cross
    r = slots - points[:, None]
    total = np.zeros(len(points))
    for j in range(6):  # each kept vertex to the next kept one, cyclically
        nxt = np.full(len(points), -1)
        for o in range(5, 0, -1):
            nxt = np.where(valid[:, (j + o) % 6], (j + o) % 6, nxt)
        use = valid[:, j] & (nxt >= 0)
        a = r[:, j]
        b = np.take_along_axis(r, np.maximum(nxt, 0)[:, None, None].repeat(3, axis=2), axis=1)[:, 0]
        c = np.cross(a, b)
        cn = np.linalg.norm(c, axis=1)
        gamma = np.arctan2(cn, np.einsum("kj,kj->k", a, b))
        total += np.where(
            use & (cn > 0), gamma * np.einsum("kj,kj->k", c, normals) / np.maximum(cn, 1e-300), 0.0
        )
    return 0.5 * np.abs(total)


PLANE_TOLERANCE = 1e-9  # a corner this close to a point's plane (relative to its distance) lies in it


def plane_heights(r: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Heights (k, 3) over the points' planes of triangles' corners given less the points (k, 3, 3),
    those within PLANE_TOLERANCE of their distance made 0: a point's own triangle then lies in its
    plane and sends it nothing (its corners' rounding error, +4e-17, read it as wholly above the
    point, which its contour then wholly surrounds: the light of a whole hemisphere, pi)."""
    h = np.einsum("kcj,kj->kc", r, normals)
    return np.where(np.abs(h) <= PLANE_TOLERANCE * np.linalg.norm(r, axis=2), 0.0, h)


def _unclipped_irradiance(r: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """polygon_irradiance of triangles wholly above the points' planes, given as their corners less
    the points (k, 3, 3): the contour's three edges, nothing to clip."""
    total = np.zeros(len(r))
    for j in range(3):
        a, b = r[:, j], r[:, (j + 1) % 3]
        c = np.cross(a, b)
        cn = np.sqrt(np.einsum("kj,kj->k", c, c))
        gamma = np.arctan2(cn, np.einsum("kj,kj->k", a, b))
        total += np.where(cn > 0, gamma * np.einsum("kj,kj->k", c, normals) / np.maximum(cn, 1e-300), 0.0)
    return 0.5 * np.abs(total)


def front_cosine(facing: np.ndarray, length: np.ndarray, cov: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """The mean over a node's faces of max(0, n . u) for u the direction to a point on the side its
    mean normal faces, its faces' normals taken as normal about their mean: facing (r, s) the cosine
    between the directions omega (r, s, 3) and the samples' unit normals, length (s,) the mean
    normal's length, cov (s, 6) the normals' covariance. A flat node's is |facing|; a cap seen at
    its rim still gets the light of the faces turned to the point (the mean normal alone cancels
    them against the faces turned away, which a closed emitter hides)."""
    mu = np.abs(facing) * length[None, :]
    # omega . cov . omega from the six entries: the off-diagonal ones twice
    pairs = omega[..., [0, 1, 2, 0, 0, 1]] * omega[..., [0, 1, 2, 1, 2, 2]]
    var = np.einsum("rsk,sk->rs", pairs, cov * [1.0, 1.0, 1.0, 2.0, 2.0, 2.0])
    sigma = np.sqrt(np.maximum(var, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sigma > 0, mu / sigma, np.inf)
    return np.where(sigma > 0, mu * ndtr(z) + sigma * np.exp(-0.5 * np.minimum(z, 1e3) ** 2) / SQRT_2PI, mu)
