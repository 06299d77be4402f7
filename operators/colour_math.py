"""Cycles' colour nodes as numpy functions of colours (..., 3), float64: RGB and HSV, every Mix
blend type, Hue/Saturation/Value, Gamma, Brightness/Contrast and RGB Curves (tabulated as Cycles
tabulates them). The material reader (materials.py) applies them to constants, texels and paint."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Cycles' colour nodes on colours (..., 3), float64 (intern/cycles/kernel/svm/color_util.h,
# hsv.h, gamma.h, ramp.h and util/color.h), written for numpy arrays.


def _interp(a, b, t):
    return a + t * (b - a)


def rgb_to_hsv(c: np.ndarray) -> np.ndarray:
    """Cycles' rgb_to_hsv on colours (..., 3): hue in [0, 1), saturation, value (the maximum)."""
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    cmax = np.maximum(r, np.maximum(g, b))
    delta = cmax - np.minimum(r, np.minimum(g, b))
    s = np.where(cmax != 0.0, delta / np.where(cmax != 0.0, cmax, 1.0), 0.0)
    chromatic = s != 0.0
    d = np.where(chromatic, delta, 1.0)
    cr, cg, cb = (cmax - r) / d, (cmax - g) / d, (cmax - b) / d
    h = np.where(r == cmax, cb - cg, np.where(g == cmax, 2.0 + cr - cb, 4.0 + cg - cr)) / 6.0
    h = np.where(h < 0.0, h + 1.0, h)
    return np.stack([np.where(chromatic, h, 0.0), s, cmax], axis=-1)


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """Cycles' hsv_to_rgb on (..., 3) hue, saturation, value."""
    h, s, v = hsv[..., 0], hsv[..., 1], hsv[..., 2]
    h = np.where(h == 1.0, 0.0, h) * 6.0
    i = np.floor(h)
    f = h - i
    p, q, t = v * (1.0 - s), v * (1.0 - s * f), v * (1.0 - s * (1.0 - f))
    sectors = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v)]
    rgb = [
        np.select([i == k for k in range(5)], [sec[ch] for sec in sectors], (v, p, q)[ch]) for ch in range(3)
    ]
    return np.where((s != 0.0)[..., None], np.stack(rgb, axis=-1), v[..., None])


def _with_hsv(a, mask, hsv):
    """hsv_to_rgb(hsv) where mask (...,), a elsewhere."""
    return np.where(mask[..., None], hsv_to_rgb(hsv), a)


def mix_colours(blend: str, t: float, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cycles' Mix (colour) node of blend type `blend` at factor t on colours a, b (..., 3) (the
    factor already clamped where the node clamps it; the result unclamped)."""
    a, b = np.broadcast_arrays(np.asarray(a, float), np.asarray(b, float))
    tm = 1.0 - t
    if blend == "MIX":
        return _interp(a, b, t)
    if blend == "ADD":
        return _interp(a, a + b, t)
    if blend == "MULTIPLY":
        return _interp(a, a * b, t)
    if blend == "SUBTRACT":
        return _interp(a, a - b, t)
    if blend == "SCREEN":
        return 1.0 - (tm + t * (1.0 - b)) * (1.0 - a)
    if blend == "OVERLAY":
        return np.where(a < 0.5, a * (tm + 2.0 * t * b), 1.0 - (tm + 2.0 * t * (1.0 - b)) * (1.0 - a))
    if blend == "DIVIDE":
        return np.where(b != 0.0, tm * a + t * a / np.where(b != 0.0, b, 1.0), a)
    if blend == "DIFFERENCE":
        return _interp(a, np.abs(a - b), t)
    if blend == "EXCLUSION":
        return np.maximum(_interp(a, a + b - 2.0 * a * b, t), 0.0)
    if blend == "DARKEN":
        return _interp(a, np.minimum(a, b), t)
    if blend == "LIGHTEN":
        return _interp(a, np.maximum(a, b), t)
    if blend == "DODGE":
        den = 1.0 - t * b
        dodged = np.where(den <= 0.0, 1.0, np.minimum(a / np.where(den <= 0.0, 1.0, den), 1.0))
        return np.where(a != 0.0, dodged, a)
    if blend == "BURN":
        den = tm + t * b
        burnt = np.clip(1.0 - (1.0 - a) / np.where(den <= 0.0, 1.0, den), 0.0, 1.0)
        return np.where(den <= 0.0, 0.0, burnt)
    if blend == "SOFT_LIGHT":
        screen = 1.0 - (1.0 - b) * (1.0 - a)
        return tm * a + t * ((1.0 - a) * b * a + a * screen)
    if blend == "LINEAR_LIGHT":
        return a + t * (2.0 * b - 1.0)
    ha, hb = rgb_to_hsv(a), rgb_to_hsv(b)
    if blend == "HUE":
        hsv = np.concatenate([hb[..., :1], ha[..., 1:]], axis=-1)
        return np.where((hb[..., 1] != 0.0)[..., None], _interp(a, hsv_to_rgb(hsv), t), a)
    if blend == "COLOR":
        hsv = np.concatenate([hb[..., :2], ha[..., 2:]], axis=-1)
        return np.where((hb[..., 1] != 0.0)[..., None], _interp(a, hsv_to_rgb(hsv), t), a)
    if blend == "SATURATION":
        hsv = ha.copy()
        hsv[..., 1] = tm * ha[..., 1] + t * hb[..., 1]
        return _with_hsv(a, ha[..., 1] != 0.0, hsv)
    if blend == "VALUE":
        hsv = ha.copy()
        hsv[..., 2] = tm * ha[..., 2] + t * hb[..., 2]
        return hsv_to_rgb(hsv)
    raise ValueError(blend)


MIX_BLENDS = (
    "MIX ADD MULTIPLY SUBTRACT SCREEN OVERLAY DIVIDE DIFFERENCE EXCLUSION DARKEN LIGHTEN DODGE BURN "
    "SOFT_LIGHT LINEAR_LIGHT HUE SATURATION COLOR VALUE"
).split()


def hue_saturation_value(
    c: np.ndarray, hue: float, saturation: float, value: float, fac: float
) -> np.ndarray:
    """Cycles' Hue/Saturation/Value node on colours (..., 3)."""
    hsv = rgb_to_hsv(c)
    h = hsv[..., 0] + hue + 0.5
    hsv = np.stack(
        [h - np.floor(h), np.clip(hsv[..., 1] * saturation, 0.0, 1.0), hsv[..., 2] * value], axis=-1
    )
    return np.maximum(fac * hsv_to_rgb(hsv) + (1.0 - fac) * c, 0.0)


def gamma(c: np.ndarray, g: float) -> np.ndarray:
    """Cycles' Gamma node: c^g on positive channels (others unchanged); white for g = 0."""
    if g == 0.0:
        return np.ones_like(c)
    return np.where(c > 0.0, np.abs(c) ** g, c)


def bright_contrast(c: np.ndarray, bright: float, contrast: float) -> np.ndarray:
    """Cycles' Brightness/Contrast node: max((1 + contrast) c + bright - contrast / 2, 0)."""
    return np.maximum((1.0 + contrast) * c + bright - 0.5 * contrast, 0.0)


@dataclass(frozen=True, eq=False)
class CurvesTable:
    """An RGB Curves node's mapping as Cycles renders it: each of R, G, B of the combined curve,
    tabulated at 257 points over [lo, hi] (the curves' points' extent, at least [0, 1]) and
    interpolated linearly; outside it extended linearly from the ends (Extrapolated) or held."""

    table: np.ndarray  # (257, 3)
    lo: float
    hi: float
    extrapolate: bool

    @classmethod
    def of(cls, mapping) -> CurvesTable:
        mapping.initialize()
        curves = list(mapping.curves)[:4]
        lo = min(0.0, *(c.points[0].location[0] for c in curves))
        hi = max(1.0, *(c.points[-1].location[0] for c in curves))
        xs = lo + np.arange(257, dtype=np.float32) / np.float32(256) * np.float32(hi - lo)
        combined = [mapping.evaluate(curves[3], float(x)) for x in xs]
        table = [[mapping.evaluate(curves[k], y) for k in range(3)] for y in combined]
        return cls(np.array(table, float), lo, hi, mapping.extend == "EXTRAPOLATED")

    def __call__(self, c: np.ndarray, fac: float = 1.0) -> np.ndarray:
        """The node at factor fac on colours (..., 3): (1 - fac) c + fac curves(c)."""
        n = len(self.table) - 1
        rel = (c - self.lo) / (self.hi - self.lo)
        f = np.clip(rel, 0.0, 1.0) * n
        i = np.clip(np.floor(f).astype(np.int64), 0, n)
        w = f - i
        ch = np.arange(3)
        out = (1.0 - w) * self.table[i, ch] + w * self.table[np.minimum(i + 1, n), ch]
        if self.extrapolate:
            low = self.table[0] + (self.table[0] - self.table[1]) * (-rel) * n
            high = self.table[n] + (self.table[n] - self.table[n - 1]) * (rel - 1.0) * n
            out = np.where(rel < 0.0, low, np.where(rel > 1.0, high, out))
        return (1.0 - fac) * c + fac * out
