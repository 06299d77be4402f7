"""Image pixels as Cycles reads them: linear RGB (an 8-bit sRGB image decoded with the sRGB curve),
the stored values of an 8-bit sRGB image (which Cycles interpolates before decoding), and an
image's alpha channel; images larger than MAX_TEXTURE_SIDE are read at every k-th pixel."""

from __future__ import annotations

import numpy as np

MAX_TEXTURE_SIDE = 2048  # larger images are read at a reduced size (the bake samples them bilinearly)
_LINEAR_SPACES = {
    "Linear",
    "Linear Rec.709",
    "Linear CIE-XYZ E",
    "Linear FilmLight E-Gamut",
    "Non-Color",
    "Raw",
}


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """The sRGB transfer function, inverted (what Cycles applies to an 8-bit sRGB texture)."""
    c = np.asarray(c, np.float32)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _stored_rgb(image) -> np.ndarray | None:
    """An image's RGB as Blender stores it (h, w, 3) float32, row 0 at the bottom; None if it has
    no pixels (a missing file)."""
    w, h = image.size[:]
    if w == 0 or h == 0 or not image.has_data and not _load(image):
        return None
    w, h = image.size[:]
    channels = image.channels
    buf = np.empty(w * h * channels, np.float32)
    image.pixels.foreach_get(buf)
    px = buf.reshape(h, w, channels)
    return px[..., :3] if channels >= 3 else np.repeat(px[..., :1], 3, axis=2)


def _srgb_bytes(image) -> bool:
    """An 8-bit image in a non-linear colour space (decoded with the sRGB curve, as Cycles does)."""
    return not image.is_float and image.colorspace_settings.name not in _LINEAR_SPACES


def linear_pixels(image) -> np.ndarray | None:
    """All pixels of an image as linear RGB (h, w, 3) float32, row 0 at the bottom (an 8-bit
    sRGB image decoded as Cycles decodes it); None if it has no pixels (a missing file)."""
    rgb = _stored_rgb(image)
    return srgb_to_linear(rgb) if rgb is not None and _srgb_bytes(image) else rgb


def image_pixels(image) -> tuple[np.ndarray, np.ndarray | None] | None:
    """An albedo map's pixels: linear RGB (h, w, 3) float32, and for an 8-bit sRGB image its
    pixels as stored (sRGB-encoded; else None), which Cycles interpolates before decoding them
    (between a bright and a dark texel, less light than the mean of the decoded texels). None if
    the image has no pixels; an image larger than MAX_TEXTURE_SIDE is read at every k-th pixel."""
    rgb = _stored_rgb(image)
    if rgb is None:
        return None
    step = max(1, -(-max(rgb.shape[:2]) // MAX_TEXTURE_SIDE))
    rgb = np.ascontiguousarray(np.clip(rgb[::step, ::step], 0.0, None), np.float32)
    if not _srgb_bytes(image):
        return rgb, None
    encoded = np.minimum(rgb, 1.0)
    return srgb_to_linear(encoded), encoded


def _load(image) -> bool:
    try:
        image.pixels[0]  # touching the pixels loads the image
    except (IndexError, RuntimeError):
        return False
    return bool(image.has_data)


def alpha_pixels(image) -> np.ndarray | None:
    """An image's alpha channel (h, w) float32, row 0 at the bottom (read at every k-th pixel above
    MAX_TEXTURE_SIDE); None if the image has no alpha (no fourth channel, or Alpha mode None)."""
    if image.alpha_mode == "NONE" or image.channels < 4:
        return None
    w, h = image.size[:]
    if w == 0 or h == 0 or not image.has_data and not _load(image):
        return None
    w, h = image.size[:]
    buf = np.empty(w * h * image.channels, np.float32)
    image.pixels.foreach_get(buf)
    a = buf.reshape(h, w, image.channels)[..., 3]
    step = max(1, -(-max(a.shape) // MAX_TEXTURE_SIDE))
    return np.ascontiguousarray(np.clip(a[::step, ::step], 0.0, 1.0), np.float32)
