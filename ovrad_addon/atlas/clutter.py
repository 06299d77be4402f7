"""Clutter: the many small separate pieces of a production mesh, covered by a few ball patches.

A chart much smaller than a patch (a leaf, a bolt, a tiny cube, a sliver cut off by a crease)
cannot carry a grid of its own, and one patch per piece makes the atlas as large as the mesh's
piece count (100 k triangles of scattered pieces gave 30 000 patches for a target of 2 000, and
a minute of overlap integration). Such charts are clutter. All clutter charts of an object, on
one side, form one sheet, covered by *ball* patches (SHAPE_BALL) centred on the cells of a
world-anchored cubic grid of the object's spacing: a point of a clutter sheet is in a ball patch
when it lies within the radius of its centre, whatever its normal. A ball's radiosity is the
mean over the pieces it holds, as a cluster's in hierarchical radiosity; the bake still computes
direct light and the final gather at every vertex of every piece, so the pieces keep their own
shading. Every point of a cell lies inside the ball of its cell (the radius circumscribes it),
so the balls cover the clutter and alpha sums to one on it.

The supports are integrated with samples on the clutter triangles themselves (sub-triangle
centroids, area weights; points inside closed objects dropped), not with the polar rule.

Which charts are clutter is decided at Generate (chart area against the spacing) and read back
at Solve from the atlas: the charts of an object with ball patches that hold none of its other
patches (clutter_from_atlas), so the sheets are the same without storing the threshold.
"""

from __future__ import annotations

import numpy as np

from ..names import SHAPE_BALL

CLUTTER_AREA = 0.1  # a chart with less area than this times its spacing squared is clutter

# ... and a curved chart with less than this: a patch on a curved sheet holds the points it meets
# along its normal, and a small piece that curves more than its one disk can follow hides part of
# itself (the production room's BoomBox at 100 k patches: a 4 cm^2 knob, 0.18 of a cell, met only
# other parts of the model along its 4.5 cm disk's normal; its patch had no support, was dropped,
# and the knob baked black). Ball patches hold the pieces' own samples. A quarter, not a whole
# cell: at the room's default 2 000 patches a whole cell turns most of the BoomBox into balls,
# whose mean light its underside then reads (its error 13.4 % with a whole cell, 11.2 % with a
# quarter, 11.3 % with plain patches).
CURVED_CLUTTER_AREA = 0.25


def chart_objects(surfaces, charts) -> np.ndarray:
    """(n_charts,) object index of each chart."""
    chart_obj = np.zeros(charts.count, np.int64)
    ok = charts.chart >= 0
    chart_obj[charts.chart[ok]] = surfaces.object_index[ok]
    return chart_obj


def sheet_table_with_clutter(
    table: np.ndarray, chart_obj: np.ndarray, clutter: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Sheets when the `clutter` charts of each object join one sheet per side.

    table (n_charts, 2): sheet of each chart's front and back (-1: none). Returns the new
    table, sheet_chart (a representative chart for a clutter sheet), sheet_side and
    sheet_clutter (n_sheets,). Other charts keep their own sheets, numbered as before.
    """
    has = table >= 0
    own = has & ~clutter[:, None]
    new = np.full_like(table, -1)
    n_own = int(own.sum())
    new[own] = np.arange(n_own)  # row-major: the order index_surfaces numbers sheets in
    own_chart, own_col = np.nonzero(own)
    cl_chart, cl_col = np.nonzero(has & clutter[:, None])
    key = 2 * chart_obj[cl_chart] + cl_col
    uniq, first, inv = np.unique(key, return_index=True, return_inverse=True)
    new[cl_chart, cl_col] = n_own + inv.reshape(-1)
    sheet_chart = np.concatenate([own_chart, cl_chart[first]]).astype(np.int64)
    sheet_side = np.concatenate([np.where(own_col == 0, 1, -1), np.where(uniq % 2 == 0, 1, -1)])
    sheet_clutter = np.concatenate([np.zeros(n_own, bool), np.ones(len(uniq), bool)])
    return new, sheet_chart, sheet_side.astype(np.int64), sheet_clutter


def small_charts(
    chart_area: np.ndarray, chart_spacing: np.ndarray, flat: np.ndarray | None = None
) -> np.ndarray:
    """(n_charts,) bool: charts too small for patches of their own at this spacing; flat (n_charts,)
    bool: the planar charts (None: all), the others curved (CURVED_CLUTTER_AREA)."""
    share = CLUTTER_AREA if flat is None else np.where(flat, CLUTTER_AREA, CURVED_CLUTTER_AREA)
    return chart_area < share * chart_spacing**2


def clutter_from_atlas(index, atlas) -> np.ndarray:
    """(n_charts,) bool: the clutter charts an atlas was generated with.

    An object whose atlas has ball patches had its clutter charts covered by them; its other
    charts each hold patches of their own. So the clutter charts are the object's charts that
    hold no non-ball patch (found from the triangles the patches store).
    """
    s, charts = index.surfaces, index.charts
    clutter = np.zeros(charts.count, bool)
    if atlas.triangle is None or not np.any(atlas.shapes == SHAPE_BALL):
        return clutter
    obj = chart_objects(s, charts)
    ball = atlas.shapes == SHAPE_BALL
    with_balls = np.zeros(len(s.object_names), bool)
    with_balls[atlas.source_object[ball]] = True
    regular = ~ball & (atlas.triangle >= 0)
    tri = s.global_triangle(atlas.source_object[regular], atlas.triangle[regular])
    held = np.zeros(charts.count, bool)
    ch = charts.chart[tri]
    held[ch[ch >= 0]] = True
    return with_balls[obj] & ~held
