"""Shared lightmap atlases: the lightmaps of many meshes packed into as few images as the maximum
image size allows, as lightmappers' atlas groups do.

The meshes of a shared atlas bake through UV maps ovrad makes for them together
(lightmap_uv.make_shared: their islands packed into one unit square, each mesh at its own texel
density). A linked duplicate shares its mesh, so its UV map, with the other users: it cannot
take a place of its own in an atlas and gets an image of its own.
"""

from __future__ import annotations

import bpy

ATLAS_NAME = "ovrad_atlas"  # the image (and the {object} of the file path) of a shared atlas
# Islands packed by their bounding boxes fill about this share of an atlas: meshes are grouped so
# that each group's texels at the density fit in FILL x the largest image (a group that packs
# larger than the largest image all the same is halved until it fits).
FILL = 0.6


def linked(obj) -> bool:
    """Whether another object uses obj's mesh (a linked duplicate)."""
    mesh = obj.data
    return any(o.data is mesh for o in bpy.data.objects if o is not obj)


def groups(needs: list[float], max_size: int) -> list[list[int]]:
    """Indices of meshes, grouped into atlases: needs (texels each mesh takes at its density),
    largest first, each into the first group with room for it under FILL x max_size^2 (a mesh
    needing more than that is a group of its own)."""
    room = FILL * float(max_size) ** 2
    out: list[list[int]] = []
    used: list[float] = []
    for i in sorted(range(len(needs)), key=lambda i: (-needs[i], i)):
        for g, u in enumerate(used):
            if u + needs[i] <= room:
                out[g].append(i)
                used[g] += needs[i]
                break
        else:
            out.append([i])
            used.append(needs[i])
    return [sorted(g) for g in out]


def halves(group: list[int], needs: list[float]) -> list[list[int]]:
    """A group split in two of about equal need: largest first, each into the half needing less."""
    out: list[list[int]] = [[], []]
    used = [0.0, 0.0]
    for i in sorted(group, key=lambda i: (-needs[i], i)):
        k = 0 if used[0] <= used[1] else 1
        out[k].append(i)
        used[k] += needs[i]
    return [sorted(h) for h in out if h]


def atlas_names(count: int) -> list[str]:
    """The names of `count` shared atlases: ATLAS_NAME, or ATLAS_NAME_1, _2, ... when several."""
    return [ATLAS_NAME] if count == 1 else [f"{ATLAS_NAME}_{k + 1}" for k in range(count)]
