"""The colour and alpha tables of a scene read's meshes (scene_io.py: each placed mesh's arrays),
merged over all of them into the engine's TextureAlbedo and Coverage, images shared by name."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..ovrad_addon import Coverage, TextureAlbedo


@dataclass
class ColourTable:
    """One mesh's colour from maps and paint, as a TextureAlbedo holds it over its triangles:
    textures (image name, pixels, whether sRGB-encoded), image_of (T,), uv (T, 3, 2), tint (T, 3),
    corners (T, 3, 3) or None."""

    textures: list
    image_of: np.ndarray
    uv: np.ndarray
    tint: np.ndarray
    corners: np.ndarray | None = None


def coverage_table(parts: list) -> Coverage | None:
    """One Coverage over the triangles of all parts, alpha maps shared by name; None where every
    surface is opaque."""
    opacity = np.concatenate([p.opacity for p in parts])
    if opacity.min(initial=1.0) >= 1.0 and not any(p.alpha_maps for p in parts):
        return None
    if not any(p.alpha_maps for p in parts):
        return Coverage(opacity)
    images: dict[str, int] = {}
    pixels, alpha_of, uv = [], [], []
    for p in parts:
        n = len(p.triangles)
        if not p.alpha_maps:
            alpha_of.append(np.full(n, -1, np.int64))
            uv.append(np.zeros((n, 3, 2)))
            continue
        remap = []
        for name, px in p.alpha_maps:
            if name not in images:
                images[name] = len(pixels)
                pixels.append(px)
            remap.append(images[name])
        alpha_of.append(np.array(remap + [-1], np.int64)[p.alpha_of])
        uv.append(p.alpha_uv)
    return Coverage(opacity, tuple(pixels), np.concatenate(alpha_of), np.concatenate(uv))


def albedo_table(parts: list) -> TextureAlbedo | None:
    """One TextureAlbedo over the triangles of all parts, images shared by name; None if no map
    and no paint."""
    tables = [
        None
        if not p.textures and p.corners is None
        else ColourTable(p.textures, p.image_of, p.uv, p.tint, p.corners)
        for p in parts
    ]
    return merged_colours(tables, parts)


def merged_colours(tables: list[ColourTable | None], parts: list) -> TextureAlbedo | None:
    """One TextureAlbedo over the triangles of all parts from each part's table (None: no map, no
    paint and a tint of 1 there), images shared by name; None if no part has a table."""
    if all(t is None for t in tables):
        return None
    images: dict[str, int] = {}
    pixels, srgb = [], []
    image_of, uv, tint = [], [], []
    for p, table in zip(parts, tables, strict=True):
        n = len(p.triangles)
        tint.append(np.ones((n, 3)) if table is None or table.tint is None else table.tint)
        if table is None or not table.textures:
            image_of.append(np.full(n, -1, np.int64))
            uv.append(np.zeros((n, 3, 2)))
            continue
        remap = []
        for name, px, encoded in table.textures:
            if name not in images:
                images[name] = len(pixels)
                pixels.append(px)
                srgb.append(encoded)
            remap.append(images[name])
        remap = np.array(remap + [-1], np.int64)  # -1 -> -1 (the last entry)
        image_of.append(remap[table.image_of])
        uv.append(table.uv)
    image_of = np.concatenate(image_of)
    corners = None
    if any(t is not None and t.corners is not None for t in tables):
        corners = np.concatenate(
            [
                t.corners
                if t is not None and t.corners is not None
                else np.full((len(p.triangles), 3, 3), np.nan)
                for p, t in zip(parts, tables, strict=True)
            ]
        )
    return TextureAlbedo(
        images=tuple(pixels),
        image_of=image_of,
        uv=np.concatenate(uv),
        tint=np.concatenate(tint),
        corners=corners,
        srgb=tuple(srgb),
    )
