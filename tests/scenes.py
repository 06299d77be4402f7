"""Test scenes as plain arrays (no Blender): cube, sphere, plane, thin wall, Cornell box."""

from __future__ import annotations

import numpy as np

from ovrad_addon.scene.surfaces import Surfaces

WHITE = (0.725, 0.71, 0.68)
RED = (0.63, 0.065, 0.05)
GREEN = (0.14, 0.45, 0.091)


def quad(a, b, c, d) -> tuple[np.ndarray, np.ndarray]:
    """Two triangles a-b-c, a-c-d (counter-clockwise seen from the normal side)."""
    return np.array([a, b, c, d], float), np.array([[0, 1, 2], [0, 2, 3]])


def merge(parts, obj=None):
    """Concatenate (vertices, triangles) parts; returns vertices, triangles, object index per triangle."""
    vs, ts, os_ = [], [], []
    base = 0
    for k, (v, t) in enumerate(parts):
        vs.append(v)
        ts.append(t + base)
        os_.append(np.full(len(t), k if obj is None else obj[k]))
        base += len(v)
    return np.concatenate(vs), np.concatenate(ts), np.concatenate(os_)


def box_faces(lo, hi, inward=False):
    """Six quads of an axis-aligned box, normals outward (or inward)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    faces = [
        ((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)),  # bottom, -z
        ((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)),  # top, +z
        ((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)),  # -y
        ((x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)),  # +y
        ((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)),  # -x
        ((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)),  # +x
    ]
    out = []
    for f in faces:
        f = f[::-1] if inward else f
        out.append(quad(*f))
    return out


def cube(scale: float = 1.0, inward: bool = False) -> Surfaces:
    v, t, _ = merge(box_faces((0, 0, 0), (scale, scale, scale), inward), obj=[0] * 6)
    # share vertices as a modeller's cube would (weld is done by the engine anyway)
    return Surfaces.from_arrays(v, t)


def sphere(radius: float = 1.0, subdivisions: int = 3) -> Surfaces:
    """Icosphere, outward normals, deterministic."""
    p = (1 + 5**0.5) / 2
    v = np.array(
        [
            [-1, p, 0],
            [1, p, 0],
            [-1, -p, 0],
            [1, -p, 0],
            [0, -1, p],
            [0, 1, p],
            [0, -1, -p],
            [0, 1, -p],
            [p, 0, -1],
            [p, 0, 1],
            [-p, 0, -1],
            [-p, 0, 1],
        ],
        float,
    )
    f = np.array(
        [
            [0, 11, 5],
            [0, 5, 1],
            [0, 1, 7],
            [0, 7, 10],
            [0, 10, 11],
            [1, 5, 9],
            [5, 11, 4],
            [11, 10, 2],
            [10, 7, 6],
            [7, 1, 8],
            [3, 9, 4],
            [3, 4, 2],
            [3, 2, 6],
            [3, 6, 8],
            [3, 8, 9],
            [4, 9, 5],
            [2, 4, 11],
            [6, 2, 10],
            [8, 6, 7],
            [9, 8, 1],
        ]
    )
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mid = v[uniq].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        m = len(v) + inv.reshape(3, -1).T
        v = np.concatenate([v, mid])
        a, b, c = f.T
        f = np.concatenate(
            [
                np.stack([a, m[:, 0], m[:, 2]], 1),
                np.stack([b, m[:, 1], m[:, 0]], 1),
                np.stack([c, m[:, 2], m[:, 1]], 1),
                m,
            ]
        )
    return Surfaces.from_arrays(v * radius, f)


def plane(size: float = 1.0, n: int = 1, z: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A square [0, size]^2 at height z split into n x n quads, normal +z."""
    g = np.linspace(0, size, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, t


def bent_leaf(rng: np.random.Generator, size: float, sag: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """An open leaf centred at the origin: an n x n grid on [-size, size]^2 bent into a bowl
    (height sag * size * (u^2 + v^2) in grid units), turned by a random rotation from rng."""
    g = np.linspace(-1, 1, n + 1)
    gu, gv = np.meshgrid(g, g, indexing="ij")
    uv = np.stack([gu.ravel(), gv.ravel()], 1)
    p = np.column_stack([uv * size, sag * size * (uv**2).sum(1)])
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return p @ q.T, plane(2.0, n)[1]


def leaves_in_a_room(room, count, sizes, sag, n, where, seed):
    """(vertices, triangles, object) of a closed room (box corners `room`, inward faces; object 0)
    holding `count` bent leaves (object 1): sizes (lo, hi) drawn uniformly, bent by `sag` on an
    n x n grid (bent_leaf), centred uniformly between the corners `where`."""
    rng = np.random.default_rng(seed)
    parts, objs = list(box_faces(*room, inward=True)), [0] * 6
    for _ in range(count):
        v, t = bent_leaf(rng, rng.uniform(*sizes), sag, n)
        parts.append((v + rng.uniform(*where), t))
        objs.append(1)
    return merge(parts, obj=objs)


def thin_wall_rooms(gap: float = 0.01) -> Surfaces:
    """Two closed rooms (inward normals) sharing a thin wall of thickness `gap` at x = 0."""
    left = box_faces((-1, 0, 0), (-gap / 2, 1, 1), inward=True)
    right = box_faces((gap / 2, 0, 0), (1, 1, 1), inward=True)
    v, t, o = merge(left + right, obj=[0] * 6 + [1] * 6)
    return Surfaces.from_arrays(v, t, o, object_names=["left", "right"])


def cornell() -> Surfaces:
    """The Cornell box from the published data (metres, Blender axes), light as its own object."""

    def m(*pts):
        return [((278 - x) / 1000, z / 1000, y / 1000) for x, y, z in pts]

    walls = {
        "floor": (m((552.8, 0, 0), (0, 0, 0), (0, 0, 559.2), (549.6, 0, 559.2)), WHITE),
        "back": (m((549.6, 0, 559.2), (0, 0, 559.2), (0, 548.8, 559.2), (556, 548.8, 559.2)), WHITE),
        "right": (m((0, 0, 559.2), (0, 0, 0), (0, 548.8, 0), (0, 548.8, 559.2)), GREEN),
        "left": (m((552.8, 0, 0), (549.6, 0, 559.2), (556, 548.8, 559.2), (556, 548.8, 0)), RED),
    }
    parts, rho, em, names = [], [], [], []
    for name, (pts, col) in walls.items():
        parts.append(quad(*pts))
        rho.append([col] * 2)
        em.append([(0, 0, 0)] * 2)
        names.append(name)
    # Ceiling with a hole for the light: four quads around the light rectangle, facing down.
    y = 548.8
    xs, zs = (556, 343, 213, 0), (0, 227, 332, 559.2)
    for i in range(3):
        for j in range(3):
            if i == 1 and j == 1:
                continue
            parts.append(
                quad(
                    *m(
                        (xs[i], y, zs[j]),
                        (xs[i], y, zs[j + 1]),
                        (xs[i + 1], y, zs[j + 1]),
                        (xs[i + 1], y, zs[j]),
                    )
                )
            )
            rho.append([WHITE] * 2)
            em.append([(0, 0, 0)] * 2)
            names.append(f"ceiling{i}{j}")
    parts.append(quad(*m((343, y, 227), (343, y, 332), (213, y, 332), (213, y, 227))))
    rho.append([(0.78, 0.78, 0.78)] * 2)
    em.append([(17, 12, 4)] * 2)
    names.append("light")
    blocks = {
        "short": [
            ((130, 165, 65), (82, 165, 225), (240, 165, 272), (290, 165, 114)),
            ((290, 0, 114), (290, 165, 114), (240, 165, 272), (240, 0, 272)),
            ((130, 0, 65), (130, 165, 65), (290, 165, 114), (290, 0, 114)),
            ((82, 0, 225), (82, 165, 225), (130, 165, 65), (130, 0, 65)),
            ((240, 0, 272), (240, 165, 272), (82, 165, 225), (82, 0, 225)),
        ],
        "tall": [
            ((423, 330, 247), (265, 330, 296), (314, 330, 456), (472, 330, 406)),
            ((423, 0, 247), (423, 330, 247), (472, 330, 406), (472, 0, 406)),
            ((472, 0, 406), (472, 330, 406), (314, 330, 456), (314, 0, 456)),
            ((314, 0, 456), (314, 330, 456), (265, 330, 296), (265, 0, 296)),
            ((265, 0, 296), (265, 330, 296), (423, 330, 247), (423, 0, 247)),
        ],
    }
    for name, faces in blocks.items():
        for f in faces:
            parts.append(quad(*m(*f)))
            rho.append([WHITE] * 2)
            em.append([(0, 0, 0)] * 2)
            names.append(f"{name}")
    obj_names = list(dict.fromkeys(names))
    obj = [obj_names.index(nm) for nm in names]
    v, t, o = merge(parts, obj=obj)
    return Surfaces.from_arrays(v, t, o, np.concatenate(rho), np.concatenate(em), obj_names)


def sample_surface(surfaces: Surfaces, count: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Uniform random points on all non-degenerate triangles: (points (count, 3), triangle (count,))."""
    c = surfaces.corners
    area = 0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    tri = rng.choice(len(c), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    cc = c[tri]
    return cc[:, 0] + u[:, None] * (cc[:, 1] - cc[:, 0]) + v[:, None] * (cc[:, 2] - cc[:, 0]), tri


def window_room(w: float = 2.4, d: float = 2.4, h: float = 2.2, window=(0.7, 1.7, 0.8, 1.8)) -> Surfaces:
    """The real-scenes window room (benchmarks/real_scenes.py _window_room) as arrays: a room
    [0, w] x [0, d] x [0, h], faces inward, whose south wall (y = 0) has a window
    (x0, x1, z0, z1); white 0.75."""
    hx0, hx1, hz0, hz1 = window
    x0, y0, z0 = 0.0, 0.0, 0.0
    faces = [f for k, f in enumerate(box_faces((x0, y0, z0), (w, d, h), inward=True)) if k != 2]
    for a0, a1, b0, b1 in ((0, hx0, 0, h), (hx1, w, 0, h), (hx0, hx1, 0, hz0), (hx0, hx1, hz1, h)):
        faces.append(quad((a0, 0, b0), (a0, 0, b1), (a1, 0, b1), (a1, 0, b0)))  # normal +Y
    v, t, o = merge(faces, obj=[0] * len(faces))
    return Surfaces.from_arrays(v, t, reflectance=np.tile([0.75, 0.75, 0.75], (len(t), 1)))
