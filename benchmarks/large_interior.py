"""A large interior as engine arrays: a grid of rooms joined by doorways, furnished, ~1 M triangles.

    .venv/bin/python benchmarks/large_interior.py [--rooms 4] [--cell 0.05] [--npz out.npz]

Each room (5 x 5 x 3 m) has a floor, a ceiling, walls 10 cm thick with a doorway to each
neighbour (closed boxes, so both faces of a partition are surfaces), a table with four legs, two
shelves, a low cabinet and a glowing ceiling panel. Every face is split into cells of about
`cell` metres (the messy part of a production file: many triangles per face), so the triangle
count grows as 1 / cell^2: about 1 M with 4 x 4 rooms at 6.5 cm. Deterministic. scale_bench.py's
`--engine-interior` bakes it at 10^5-10^6 patches.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ovrad_addon import Surfaces  # noqa: E402

ROOM, HEIGHT, WALL, DOOR = 5.0, 3.0, 0.1, (1.0, 2.1)  # m: room side, height, wall thickness, door w x h


def grid_quad(origin, u, v, cell: float):
    """A parallelogram origin + s u + t v (s, t in [0, 1]) split into cells of about `cell`;
    normal along u x v."""
    origin, u, v = (np.asarray(x, float) for x in (origin, u, v))
    nu = max(1, int(round(np.linalg.norm(u) / cell)))
    nv = max(1, int(round(np.linalg.norm(v) / cell)))
    s, t = np.meshgrid(np.linspace(0, 1, nu + 1), np.linspace(0, 1, nv + 1), indexing="ij")
    verts = origin + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    return verts, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def box(lo, hi, cell: float, inward: bool = False):
    """The six faces of an axis-aligned box, normals outward (inward for a room's shell)."""
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    dx, dy, dz = (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, z1 - z0)
    faces = [
        ((x0, y0, z0), dy, dx),  # -z
        ((x0, y0, z1), dx, dy),  # +z
        ((x0, y0, z0), dx, dz),  # -y
        ((x0, y1, z0), dz, dx),  # +y
        ((x0, y0, z0), dz, dy),  # -x
        ((x1, y0, z0), dy, dz),  # +x
    ]
    parts = [grid_quad(o, v, u, cell) if inward else grid_quad(o, u, v, cell) for o, u, v in faces]
    return parts


def wall_x(x: float, y0: float, y1: float, door: bool, cell: float):
    """A partition of thickness WALL centred on x, from y0 to y1, with a doorway in its middle."""
    if not door:
        return box((x - WALL / 2, y0, 0), (x + WALL / 2, y1, HEIGHT), cell)
    mid, w, h = 0.5 * (y0 + y1), DOOR[0] / 2, DOOR[1]
    return (
        box((x - WALL / 2, y0, 0), (x + WALL / 2, mid - w, HEIGHT), cell)
        + box((x - WALL / 2, mid + w, 0), (x + WALL / 2, y1, HEIGHT), cell)
        + box((x - WALL / 2, mid - w, h), (x + WALL / 2, mid + w, HEIGHT), cell)
    )


def swap_xy(parts):
    """The same parts mirrored across x = y (a wall along x made from one along y): positions
    swapped, triangles flipped so normals stay outward."""
    return [(v[:, [1, 0, 2]], t[:, ::-1]) for v, t in parts]


def furniture(x0: float, y0: float, rng: np.random.Generator, cell: float):
    parts = []
    tx, ty = x0 + rng.uniform(1.5, 2.5), y0 + rng.uniform(1.5, 2.5)
    parts += box((tx, ty, 0.72), (tx + 1.6, ty + 0.9, 0.76), cell)  # table top
    for lx, ly in ((0.05, 0.05), (1.5, 0.05), (0.05, 0.8), (1.5, 0.8)):
        parts += box((tx + lx, ty + ly, 0), (tx + lx + 0.05, ty + ly + 0.05, 0.72), cell)
    for k in range(2):  # shelves against the walls
        sx = x0 + 0.3 + 2.4 * k
        parts += box((sx, y0 + ROOM - 0.55, 0), (sx + 1.8, y0 + ROOM - 0.15, 2.0), cell)
    parts += box((x0 + 0.2, y0 + 0.2, 0), (x0 + 1.2, y0 + 0.8, 0.8), cell)  # cabinet
    return parts


def large_interior(rooms: int = 4, cell: float = 0.065, seed: int = 0) -> Surfaces:
    rng = np.random.default_rng(seed)
    span = rooms * ROOM
    groups = {"shell": box((0, 0, 0), (span, span, HEIGHT), cell, inward=True)}
    walls, furnish, lamps = [], [], []
    for k in range(1, rooms):
        for j in range(rooms):
            walls += wall_x(k * ROOM, j * ROOM + WALL / 2, (j + 1) * ROOM - WALL / 2, True, cell)
            walls += swap_xy(wall_x(k * ROOM, j * ROOM + WALL / 2, (j + 1) * ROOM - WALL / 2, True, cell))
    for i in range(rooms):
        for j in range(rooms):
            furnish += furniture(i * ROOM, j * ROOM, rng, cell)
            cx, cy = (i + 0.5) * ROOM, (j + 0.5) * ROOM
            # a 1 x 1 m panel 2 cm under the ceiling, facing down
            lamps.append(grid_quad((cx - 0.5, cy - 0.5, HEIGHT - 0.02), (0, 1, 0), (1, 0, 0), cell))
    groups |= {"walls": walls, "furniture": furnish, "lamps": lamps}
    verts, tris, obj, rho, emit = [], [], [], [], []
    base = 0
    colours = {
        "shell": (0.75, 0.73, 0.7),
        "walls": (0.7, 0.6, 0.5),
        "furniture": (0.5, 0.35, 0.2),
        "lamps": (0.8,) * 3,
    }
    for k, (name, parts) in enumerate(groups.items()):
        for v, t in parts:
            verts.append(v)
            tris.append(t + base)
            obj.append(np.full(len(t), k))
            rho.append(np.tile(colours[name], (len(t), 1)))
            emit.append(np.full((len(t), 3), 20.0 if name == "lamps" else 0.0))
            base += len(v)
    return Surfaces.from_arrays(
        np.concatenate(verts),
        np.concatenate(tris),
        np.concatenate(obj),
        reflectance=np.concatenate(rho),
        emission=np.concatenate(emit),
        object_names=list(groups),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rooms", type=int, default=4)
    ap.add_argument("--cell", type=float, default=0.065)
    ap.add_argument("--npz", help="write the triangles (vertices, triangles, object) here")
    a = ap.parse_args()
    s = large_interior(a.rooms, a.cell)
    print(
        f"large_interior: {len(s.triangles):,} triangles, {len(s.vertices):,} vertices, "
        f"objects {s.object_names}"
    )
    if a.npz:
        np.savez_compressed(a.npz, vertices=s.vertices, triangles=s.triangles, object=s.object_index)


if __name__ == "__main__":
    main()
