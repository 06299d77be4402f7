"""16-bit PNG lightmaps for engines that read no OpenEXR: linear values scaled by a power of two.

Encoding: a channel value v (0-65535) stands for the linear value v / 65535 x 2^exposure, where
exposure is the smallest integer with every baked value at most 2^exposure (so nothing clips).
The file carries it in tEXt chunks: `ovrad:exposure` (the integer), `ovrad:encoding` (the rule in
words) and `Software` (ovrad). Alpha (0 or 65535) marks the texels a UV island or the dilation
filled. Rows are stored top first, as PNG orders them (Blender's images put row 0 at the bottom).
"""

from __future__ import annotations

import struct
import zlib

import numpy as np

EXPOSURE_KEY = "ovrad:exposure"
ENCODING_KEY = "ovrad:encoding"
ENCODING = "linear: value = v / 65535 * 2^exposure"


def exposure_of(rgb) -> int:
    """The smallest integer e with every value of rgb at most 2^e (0 for an all-black image)."""
    top = float(np.max(rgb, initial=0.0))
    if not top > 0 or not np.isfinite(top):
        return 0
    e = int(np.ceil(np.log2(top)))
    return e + 1 if top > 2.0**e else e  # log2's rounding must not let the top value clip


def _chunk(kind: bytes, data: bytes) -> bytes:
    body = kind + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)


def encode(pixels, exposure: int) -> bytes:
    """The PNG file (RGBA, 16 bits per channel) of pixels (H, W, 4) in Blender's layout."""
    px = np.asarray(pixels, np.float64)
    h, w = px.shape[:2]
    rgb = np.clip(px[..., :3] * 2.0**-exposure, 0.0, 1.0)
    alpha = np.clip(px[..., 3:4], 0.0, 1.0)
    values = np.rint(np.concatenate([rgb, alpha], axis=2) * 65535.0).astype(">u2")[::-1]
    rows = np.concatenate([np.zeros((h, 1), np.uint8), values.reshape(h, -1).view(np.uint8)], axis=1)
    header = struct.pack(">IIBBBBB", w, h, 16, 6, 0, 0, 0)  # 16-bit RGBA, no interlace
    text = [
        _chunk(b"tEXt", b"Software\0ovrad"),
        _chunk(b"tEXt", f"{ENCODING_KEY}\0{ENCODING}".encode("latin-1")),
        _chunk(b"tEXt", f"{EXPOSURE_KEY}\0{exposure}".encode("latin-1")),
    ]
    return b"".join(
        [b"\x89PNG\r\n\x1a\n", _chunk(b"IHDR", header), *text]
        + [_chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)), _chunk(b"IEND", b"")]
    )


def write(path: str, pixels) -> int:
    """Write pixels (H, W, 4) as a 16-bit PNG at path; returns the exposure it was encoded with."""
    exposure = exposure_of(np.asarray(pixels)[..., :3])
    data = encode(pixels, exposure)
    with open(path, "wb") as fh:
        fh.write(data)
    return exposure
