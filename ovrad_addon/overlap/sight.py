"""What a patch sees along its sheet: its contacts as values (anchor, lift, cut, whole, covered) and
the tests they make, segments blocked along the sheet and covers over it (see contacts.py)."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ..names import SHAPE_BALL

LIFT = 2e-3  # the segment's height over the sheet, relative to the patch radius

COVER = 0.5  # a point with other geometry this close over it (share of the patch radius) is covered

LIFT_EXTENT = 2e-6  # ... and at least this much of the scene size (float32 rays)


@dataclass(frozen=True)
class Contacts:
    """Per patch: anchor (n, 3) on its sheet, lift (n,) the segments' height, cut (n,) bool;
    whole (n,) bool: a planar patch all of whose coarse rule points lie on its sheet, uncovered
    (no border, footprint or hole within its disk or square, as far as the rule can tell);
    covered (n,) bool: the anchor lies under a cover (covered()))."""

    anchor: np.ndarray
    lift: np.ndarray
    cut: np.ndarray
    whole: np.ndarray
    covered: np.ndarray

    def select(self, keep) -> Contacts:
        """The contacts of atlas.select(keep): a patch's anchor, lift and flags are its own."""
        return Contacts(*(getattr(self, f.name)[keep] for f in fields(Contacts)))


def planar_patches(atlas, index) -> np.ndarray:
    """Indices of the patches on planar sheets, not clutter balls: those the contact rule applies to
    and generate/refine.py may refine."""
    planar = index.planar[index.sheet_chart[atlas.sheet]] & ~index.sheet_clutter[atlas.sheet]
    return np.flatnonzero(planar & (atlas.shapes != SHAPE_BALL))


def lift_of(atlas, index) -> np.ndarray:
    return np.maximum(LIFT * atlas.radii, LIFT_EXTENT * index.surfaces.extent)


def blocked(index, normals: np.ndarray, lift: np.ndarray, start: np.ndarray, end: np.ndarray) -> np.ndarray:
    """(m,) bool: the segment start -> end, lifted by `lift` along the sheet's normals, hits
    something. The segment stops `lift` short of both ends: geometry passing through an end (a rule
    point or an anchor on the contact line itself) decides nothing, whatever the float rounding."""
    if len(start) == 0:
        return np.zeros(0, bool)
    a = start + normals * lift[:, None]
    d = end - start
    dist = np.linalg.norm(d, axis=1)
    far = dist > 2.0 * lift
    out = np.zeros(len(start), bool)
    if far.any():
        u = d[far] / dist[far, None]
        out[far] = index.rays.occluded(a[far] + lift[far, None] * u, u, dist[far] - 2.0 * lift[far])
    return out


def covered(atlas, index, patches: np.ndarray, points: np.ndarray, lift: np.ndarray) -> np.ndarray:
    """(m,) bool per (patch, point on its sheet) pair: other geometry lies over the point, along
    the sheet's normal, closer than COVER x the patch radius (lift: per patch, as lift_of()).

    A lamp panel a centimetre under a ceiling, a frame hung off a wall, a sofa low over a floor:
    the sheet under the cover and the sheet beside it see different light (the ceiling over a
    lamp's back gets tens of times the light of the ceiling around it, and none of it comes out),
    and a patch much wider than the gap cannot follow the change at the cover's rim. So the cover's
    rim is a contact line: covered and open points are never in one patch's part (a patch that
    straddles the rim splits, as at a contact), and the light under the cover stays there.
    """
    if len(patches) == 0:
        return np.zeros(0, bool)
    return geometry_over(
        index.rays,
        points,
        np.take(atlas.normals, patches, axis=0),
        lift[patches],
        COVER * atlas.radii[patches],
    )


def geometry_over(
    rays, points: np.ndarray, normals: np.ndarray, up: np.ndarray, reach: np.ndarray
) -> np.ndarray:
    """(m,) bool: a ray along the normal from `up` over each point meets something within `reach`
    of it (False where reach <= up)."""
    out = np.zeros(len(points), bool)
    ok = reach > up
    if ok.any():
        n = normals[ok]
        out[ok] = rays.occluded(points[ok] + n * up[ok, None], n, reach[ok] - up[ok])
    return out


def visible(c: Contacts, atlas, index, patches: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(m,) bool for (patch, point) pairs: the point is seen from the patch's anchor along the sheet
    and lies on the anchor's side of any cover's rim. Always true for a patch neither cut nor
    covered; a covered patch that the coarse rule found whole is still tested, so that the part
    of its disk reaching past the cover's rim (between two rule points) never carries the light
    under the cover into the open."""
    out = np.ones(len(patches), bool)
    test = np.flatnonzero(c.cut[patches] | c.covered[patches])
    if len(test):
        g = patches[test]
        seen = np.ones(len(test), bool)
        k = np.flatnonzero(c.cut[g])
        gk = g[k]
        at = np.take(points, test[k], axis=0)
        seen[k] = ~blocked(
            index, np.take(atlas.normals, gk, axis=0), c.lift[gk], np.take(c.anchor, gk, axis=0), at
        )
        s = np.flatnonzero(seen)
        seen[s] = covered(atlas, index, g[s], np.take(points, test[s], axis=0), c.lift) == c.covered[g[s]]
        out[test] = seen
    return out
