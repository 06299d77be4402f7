"""Benchmark: the per-hit work of the transport and the final gather against raw embree rays.

Run: .venv/bin/python benchmarks/hot_path_bench.py [--scene cornell rooms] [--patches 2000]
         [--repeat 7] [--name hot_path]
Scenes as engine arrays (tests/scenes.py): the Cornell box, and two rooms joined by a gap in a
thin wall (scenes.thin_wall_rooms). Per scene, at the batch defaults' patch count, in one process:
- raw embreex closest-hit rays per second on one transport chunk's rays (cosine directions from
  receiver points, 131 k rays) and on one gather chunk's (512 points x 256 directions);
- the rays with their hit points and sides (as overlap.queries.ray_hits gives them);
- alpha_at at the transport chunk's hits (hits per second);
- the gather's lattice read (bake.lattice.CornerCache.values_at) at the gather chunk's hits, with
  its nodes already filled (warm) and from an empty lattice (cold: alpha at every new node);
- the whole transport (prepare()'s: directions, rays, alpha, summing G) in rays per second.
Each is timed `repeat` times; the median is reported with its ratio to the raw rays of the same
kind (1.0: as fast as the rays alone). Raw rays run on the query threads (both cores), alpha_at
and the lattice read on the calling thread, as in one of the transport's or the gather's two
workers; the whole transport on both. Writes benchmarks/results/<name>.csv and prints a table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from per_process import write_csv  # noqa: E402  (benchmarks/, beside this script)

import scenes  # noqa: E402  (tests/scenes.py: engine scenes)
from ovrad_addon import (  # noqa: E402
    AtlasSettings,
    Gather,
    SolveSettings,
    alpha_at,
    build_atlas_and_overlaps,
    cosine_directions,
    gather_unique,
    keep,
    prepare,
)

CHUNK_RAYS = 1 << 17  # the transport's and the gather's chunk


def median_seconds(work, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        work()
        times.append(time.perf_counter() - t)
    return float(np.median(times))


def transport_rays(problem, settings: SolveSettings, rng) -> tuple[np.ndarray, np.ndarray]:
    """One transport chunk's rays: cosine directions from receiver points."""
    rp = problem.transport.points
    per = settings.rays_per_point
    pick = np.sort(rng.choice(len(rp.owner), min(len(rp.owner), CHUNK_RAYS // per), replace=False))
    nrm = rp.normals[pick]
    dirs = cosine_directions(nrm, per, rng).reshape(-1, 3)
    origins = np.repeat(rp.points[pick] + 1e-6 * problem.index.surfaces.extent * nrm, per, axis=0)
    return origins, dirs


def gather_rays(surfaces, index, rays: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """One gather chunk's rays: cosine directions from surface points."""
    pts, tri = scenes.sample_surface(surfaces, CHUNK_RAYS // rays, seed=11)
    nrm = index.charts.normals[tri]
    dirs = cosine_directions(nrm, rays, rng).reshape(-1, 3)
    return np.repeat(pts + 1e-6 * surfaces.extent * nrm, rays, axis=0), dirs


def hits(index, origins, directions):
    """(points, triangles, sides, distances) where rays land, on the side they arrive at (as
    overlap.queries.ray_hits gives them)."""
    t, tri = index.rays.closest_hit(origins, directions, np.inf)
    hit = np.flatnonzero(tri >= 0)
    d = directions[hit]
    side = np.where(np.einsum("ij,ij->i", d, index.charts.normals[tri[hit]]) < 0, 1, -1)
    return origins[hit] + t[hit, None] * d, tri[hit], side, t[hit]


def one(scene: str, patches: int, repeat: int) -> list[dict]:
    s = scenes.cornell() if scene == "cornell" else scenes.thin_wall_rooms()
    st = AtlasSettings(patch_count=patches)
    atlas, C, q, _ = build_atlas_and_overlaps(s, st)
    settings = SolveSettings()
    problem = prepare(s, atlas, settings, kept=[keep(s, atlas, C, q, st.crease_angle)])
    atlas, index, contacts = problem.atlas, problem.index, problem.contacts
    rng = np.random.default_rng(0)
    rows = []

    def row(kind: str, what: str, count: int, seconds: float, raw: float | None) -> float:
        rate = count / seconds
        rows.append(
            {
                "scene": scene,
                "patches": len(atlas),
                "rays": kind,
                "measure": what,
                "count": count,
                "seconds": round(seconds, 5),
                "per_second": round(rate),
                "ratio_to_raw_rays": round(rate / raw, 3) if raw else 1.0,
            }
        )
        return rate

    def raw_rays(kind: str, o, d) -> float:
        """Closest-hit rays per second on these rays, after one warm-up cast."""
        index.rays.closest_hit(o, d, np.inf)
        seconds = median_seconds(lambda: index.rays.closest_hit(o, d, np.inf), repeat)
        return row(kind, "raw embree rays", len(d), seconds, None)

    o, d = transport_rays(problem, settings, rng)
    raw = raw_rays("transport", o, d)
    row("transport", "rays and hit points", len(d), median_seconds(lambda: hits(index, o, d), repeat), raw)
    p, tri, side, _ = hits(index, o, d)
    alpha = median_seconds(lambda: alpha_at(atlas, index, contacts, p, tri, side), repeat)
    row("transport", "alpha_at hits", len(tri), alpha, raw)
    # prepare() cast the whole transport: directions, rays, alpha at the hits, G summed
    row("transport", "whole transport rays", problem.transport.rays, problem.seconds["transport"], raw)

    o, d = gather_rays(s, index, 256, rng)
    raw = raw_rays("gather", o, d)
    p, tri, side, t = hits(index, o, d)
    values = rng.random((len(atlas), 3))  # what the lattice interpolates does not change its cost
    # the corner cache a gather leaves in Gather.corner_cache: the lattice its hits read
    kept = {}
    at, on = scenes.sample_surface(s, 16, seed=12)
    gather_unique(
        problem,
        Gather(values, np.zeros_like(values), 256, corner_cache=kept),
        at,
        index.charts.normals[on],
        on,
    )
    (cache,) = kept.values()

    def cold():
        type(cache)(problem, values, None).values_at(p, tri, side, t)

    row("gather", "lattice read hits, cold", len(tri), median_seconds(cold, repeat), raw)
    cache.values_at(p, tri, side, t)
    warm = median_seconds(lambda: cache.values_at(p, tri, side, t), repeat)
    row("gather", "lattice read hits, warm", len(tri), warm, raw)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--scene", nargs="+", choices=("cornell", "rooms"), default=["cornell", "rooms"])
    ap.add_argument("--patches", type=int, default=2000)
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--name", default="hot_path", help="results file name without .csv")
    a = ap.parse_args()
    rows = [r for scene in a.scene for r in one(scene, a.patches, a.repeat)]
    out = RESULTS / f"{a.name}.csv"
    write_csv(rows, out, tag="hot_path_bench")
    for r in rows:
        print(
            f"{r['scene']:8s} {r['rays']:9s} {r['measure']:26s} {r['per_second']:>12,d}/s"
            f"  x{r['ratio_to_raw_rays']:.3f} of raw rays"
        )
    print(f"-> {out}")


if __name__ == "__main__":
    main()
