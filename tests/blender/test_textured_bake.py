"""The real-scenes `textured` room through the documented batch command: the floor's baked
radiance follows its sRGB checker texture, cell by cell."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.blender

ROOT = Path(__file__).resolve().parents[2]
BATCH = ROOT / "scripts" / "ovrad_batch.py"

BUILD = (
    "import sys; sys.path.insert(0, {bench!r}); import real_scenes; real_scenes.build('textured', {path!r})"
)
# The floor's vertices and baked radiance, and the checker's stored (8-bit sRGB) colours of a
# blue cell (texel 0, 0) and a warm one (texel 0, 8).
SHOW = (
    "import bpy, json, numpy as np; o = bpy.data.objects['Floor']; me = o.data; "
    "co = np.empty(3 * len(me.vertices)); me.vertices.foreach_get('co', co); "
    "a = me.color_attributes['ovrad_radiance']; c = np.empty(4 * len(a.data)); "
    "a.data.foreach_get('color', c); img = bpy.data.images['checker.png']; "
    "px = np.empty(4 * img.size[0] * img.size[1], np.float32); img.pixels.foreach_get(px); "
    "px = px.reshape(img.size[1], img.size[0], 4); "
    "print('FLOOR', json.dumps(dict(co=co.tolist(), L=c.tolist(), blue=px[0, 0, :3].tolist(), "
    "warm=px[0, 8, :3].tolist(), space=img.colorspace_settings.name)))"
)


def srgb_decoded(c):
    c = np.asarray(c, float)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def cell(x):
    """The checker cell (1 m per tile, 8 cells) of coordinates x, and whether x lies more than
    half a texel (1/128 m) from a cell border (so bilinear filtering gives the cell's colour)."""
    f = np.mod(x, 1.0) * 8
    return np.floor(f).astype(int), np.abs(f - np.round(f)) * 16 > 1.5


def test_baked_floor_follows_its_checker_texture(ovrad, run_blender, tmp_path):
    blend, out = tmp_path / "textured.blend", tmp_path / "baked.blend"
    code = BUILD.format(bench=str(ROOT / "benchmarks"), path=str(blend))
    proc = run_blender(["-b", "--python-exit-code", "1", "--python-expr", code], timeout=300)
    assert proc.returncode == 0, proc.stderr
    proc = run_blender(["-b", str(blend), "-P", str(BATCH), "--", "--output", str(out)], timeout=900)
    assert proc.returncode == 0, proc.stderr
    assert "Checker" not in proc.stdout + proc.stderr  # no warning about the floor's material
    proc = run_blender(["-b", str(out), "--python-exit-code", "1", "--python-expr", SHOW])
    assert proc.returncode == 0, proc.stderr
    got = json.loads(next(ln for ln in proc.stdout.splitlines() if ln.startswith("FLOOR "))[6:])
    assert got["space"] == "sRGB"
    blue, warm = srgb_decoded(got["blue"]), srgb_decoded(got["warm"])
    assert np.all(np.abs(warm - blue) > 0.2)  # the cells really differ (not a black image)
    co = np.array(got["co"]).reshape(-1, 3)
    L = np.array(got["L"]).reshape(-1, 4)[:, :3]
    (cx, okx), (cy, oky) = cell(co[:, 0]), cell(co[:, 1])
    albedo = np.where(((cx + cy) % 2 == 1)[:, None], warm, blue)
    pure = okx & oky
    # triples along x: a vertex and its neighbours 0.1 m either side, all inside cells, the
    # neighbours of the other colour (a cell is 0.125 m: they lie in the cells either side);
    # averaging both neighbours cancels the light's gradient. Not at the floor's border, where the
    # walls stand: there a vertex sees the wall's foot, lit by its own cell up close, so its light
    # follows its cell's colour (the converged Cycles bake's ratios on the 29 triples touching the
    # border: 0.84-1.21; on the others 0.95-1.09, its noise).
    key = {tuple(np.round(p[:2] * 10).astype(int)): i for i, p in enumerate(co)}
    lo, hi = co[:, :2].min(axis=0), co[:, :2].max(axis=0)
    border = np.any((np.abs(co[:, :2] - lo) < 1e-6) | (np.abs(co[:, :2] - hi) < 1e-6), axis=1)
    ratios, at_border = [], []
    for i in np.flatnonzero(pure):
        gx, gy = np.round(co[i, :2] * 10).astype(int)
        j, k = key.get((gx - 1, gy)), key.get((gx + 1, gy))
        if j is None or k is None or not (pure[j] and pure[k]):
            continue
        if np.allclose(albedo[j], albedo[i]) or not np.allclose(albedo[j], albedo[k]):
            continue
        side = 0.5 * (L[j] + L[k])
        ratio = (L[i] / side) / (albedo[i] / albedo[j])
        if border[[i, j, k]].any():
            at_border.append(ratio[0] > 1.0 if np.allclose(albedo[i], warm) else ratio[0] < 1.0)
        else:
            ratios.append(ratio)
    ratios = np.array(ratios)
    # At the border a warm cell's vertex gets more red light than its blue neighbours (the wall's
    # foot over it is lit by it): the converged Cycles bake shows it on 26 of the 29 triples, ovrad
    # on 26 (the gather's near hits on the wall take their light from a second gather that sees
    # the cells one by one); read off the patches' mean, 11 of 29.
    assert len(at_border) > 20 and np.mean(at_border) >= 0.75, (len(at_border), np.sum(at_border))
    assert len(ratios) > 50, len(ratios)
    # the radiance ratio of neighbouring cells is their albedo ratio (red: 7.7 x between them):
    # 171 triples within 1.0 %, median 0.2 %, measured
    assert np.all(np.abs(ratios - 1.0) < 0.03), (ratios.min(), ratios.max())
    assert np.abs(np.median(ratios, axis=0) - 1.0).max() < 0.01
