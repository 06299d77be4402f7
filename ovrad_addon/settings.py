"""Frozen settings dataclasses: the only form in which the engine receives user choices."""

from __future__ import annotations

from dataclasses import dataclass, field

from .errors import OvradError

BETA_PROFILES = ("box", "smooth")
SHAPE_MODES = ("AUTO", "DISKS", "SQUARES")
SIDE_MODES = ("AUTO", "FRONT", "BOTH")


# The rule of C (overlap/rule.py polar_rule: 4q rays, q // 4 rings; overlap/cuts.py support_cuts: q points
# along a cut ray) by the atlas's size. A final gather reads the light of the many patches its rays hit,
# so a row's quadrature error is averaged over more patches the more there are. Measured on the production
# room, every vertex scored, q = 8 against 12: 7.37 against 6.88 % at 2 172 patches, 8.21 against 6.31 %
# at 9 461 (its curved BoomBox 17.7 against 12 %), 5.28 against 5.62 % at 31 808, 4.98 against 4.97 % at
# 108 570 (Generate 54.6 against 80.9 s); the Cornell box and lamps_doorway at 100 k patches to the digit
# (1.63 and 1.74 %). Rows of C against a rule of order 24 on that room: 3.5 % off on average at 2 k
# patches with q = 8 (2.6 % with 12), 1.3 % at 100 k (0.64 %). The coarse rule starts well above the
# largest count where it measurably costs accuracy.
# q = 6 against 8 at 100 k patches: the production room 5.15 against 5.29 % (Generate 49.8 against 58-75
# s), 6.48 against 7.37 % (42.1 against 61.3 s) and 5.56 against 5.28 % on three builds of its atlas; the
# Cornell box and lamps_doorway to the digit (1.63, 1.74 %). The room's error moves more between builds of
# the atlas than with q.
FINE_QUADRATURE = 12
COARSE_QUADRATURE = 6
COARSE_FROM = 50_000  # patches


def rule_order(patches: int) -> int:
    """The default quadrature of C for an atlas of `patches` patches."""
    return COARSE_QUADRATURE if patches >= COARSE_FROM else FINE_QUADRATURE


@dataclass(frozen=True)
class ObjectSettings:
    """Per-object overrides.

    density: patch density multiplier (2.0 gives patches half the size on this object).
    sides: which sides of the faces get patches: "FRONT" (as normals point), "BOTH",
        or "AUTO" (front only on closed meshes; on open meshes also the back side,
        unless nothing in the scene can be seen from it).
    """

    density: float = 1.0
    sides: str = "AUTO"

    def __post_init__(self) -> None:
        if not (self.density > 0.0 and self.density < 1e3):
            raise OvradError(f"object density must be in (0, 1000), got {self.density}")
        if self.sides not in SIDE_MODES:
            raise OvradError(f"sides must be one of {SIDE_MODES}, got {self.sides!r}")


@dataclass(frozen=True)
class AtlasSettings:
    """How to cover surfaces with patches.

    patch_size: grid spacing in scene units; None derives it from patch_count.
    patch_count: target number of patches over the whole scene (used when patch_size is None).
    overlap: patch radius over the smallest radius that still covers its grid cell
        (1.0 = minimal overlap; squares then tile exactly). Must be >= 1.
    beta: "box" (constant) or "smooth" (1 at the centre falling continuously to 0 at the rim).
    shapes: "AUTO" (disks inside, squares on cells cut by an edge), "DISKS", "SQUARES".
    max_patches: refuse to build more patches than this.
    quadrature: points per patch side of the integration rule (accuracy of C and areas); None
        (the default) chooses by the atlas's patch count (rule_order).
    crease_angle: faces meeting at a sharper dihedral angle (degrees) start a new chart.
    """

    patch_size: float | None = None
    patch_count: int = 2000
    overlap: float = 1.3
    beta: str = "smooth"
    shapes: str = "AUTO"
    max_patches: int = 200_000
    quadrature: int | None = None
    crease_angle: float = 40.0
    objects: tuple[ObjectSettings, ...] = field(default=())

    def __post_init__(self) -> None:
        if self.patch_size is not None and not (self.patch_size > 0.0 and self.patch_size < 1e30):
            raise OvradError(f"patch size must be a positive length, got {self.patch_size}")
        if self.patch_size is None and not (1 <= self.patch_count):
            raise OvradError(f"patch count must be at least 1, got {self.patch_count}")
        if not (1.0 <= self.overlap <= 4.0):
            raise OvradError(
                f"overlap must be between 1 (patches just cover the surface) and 4, got {self.overlap}"
            )
        if self.beta not in BETA_PROFILES:
            raise OvradError(f"beta must be one of {BETA_PROFILES}, got {self.beta!r}")
        if self.shapes not in SHAPE_MODES:
            raise OvradError(f"shapes must be one of {SHAPE_MODES}, got {self.shapes!r}")
        if self.max_patches < 1:
            raise OvradError("max_patches must be at least 1")
        if self.quadrature is not None and not (2 <= self.quadrature <= 64):
            raise OvradError(f"quadrature must be between 2 and 64, got {self.quadrature}")
        if not (1.0 <= self.crease_angle <= 89.0):
            raise OvradError(f"crease angle must be between 1 and 89 degrees, got {self.crease_angle}")

    def rule_order(self, patches: int) -> int:
        """The quadrature of C for an atlas of `patches` patches: the one set, else rule_order()."""
        return rule_order(patches) if self.quadrature is None else self.quadrature

    def object_settings(self, index: int) -> ObjectSettings:
        """Settings of object `index`, defaults where none were given."""
        return self.objects[index] if index < len(self.objects) else ObjectSettings()


# Transport rays cast at most (SolveSettings.max_rays): 32 rays per receiver point reach it at
# about 16 000 box patches; larger atlases cast fewer per point (see gather_transport).
MAX_TRANSPORT_RAYS = 1 << 23
MAX_GATHER_RAYS = 1 << 14  # final-gather rays per bake point at most


@dataclass(frozen=True)
class SolveSettings:
    """tolerance: stop when unshot power < tolerance x emitted power; rule: "exact" (eq. 9) or
    "paper" (the published update); rays_per_point: hemisphere rays per receiver point;
    batch: shooters per step at least (radiosity.solver.solve_progressive); light_samples: emitter samples
    per receiver point (direct light);
    bake_samples: emitter samples per bake point (direct light at vertices and texels);
    smoothing: weight of the overlap-graph Laplacian added to C when solving (see
    radiosity/first_shot.py laplacian_smoothed()),
    0 solves equation (9) exactly; min_rays: transport rays cast at least, in all (a small atlas
    gets more receiver points and rays per point, see gather_transport); max_rays: at most (a large
    atlas casts fewer per receiver point, MAX_TRANSPORT_RAYS); gather_rays: final-gather
    rays per bake point for its indirect light (bake/gather.py), 0 reconstructs it from the patches
    (Cornell box, 2 086 patches, every vertex: 5.6 % relative RMS with 0, 3.5 / 2.4 / 1.9 % with
    64 / 128 / 256 rays for +2.9 / 3.9 / 6.1 s over 8 482 vertices; benchmarks/gather_bench.py);
    sky_samples / bake_sky_samples: world directions of the sky's fixed rule (light/sky.py) at the
    solve's receiver points / at bake points. Their error is aliasing, not noise: a window is
    seen along the few directions of the rule that pass through it. Measured in the real-scenes
    window room (2.4 m, 1 x 1 m window), floor and back wall against 16 384 directions, relative
    RMS per point: 22 / 12 / 6.7 / 3.9 % with 256 / 512 / 1024 / 2048 directions (constant sky;
    HDR sky with a sun 20 / 11 / 5.4 / 3.0 %), about 5 M shadow rays/s, half the directions facing
    a surface. The solve (~10^5 receiver points) takes 256, about 1.3 x 10^7 rays, the transport's
    order; the first shot feeds only the indirect light of bakes. Bake points take 1024."""

    tolerance: float = 1e-3
    rule: str = "exact"
    rays_per_point: int = 32
    batch: int = 64
    light_samples: int = 16
    smoothing: float = 0.1
    bake_samples: int = 64
    min_rays: int = 1 << 20
    max_rays: int = MAX_TRANSPORT_RAYS
    gather_rays: int = 256
    # Gather hits closer than a patch radius get their direct light computed where they land
    # (bake/lattice.py NearField): Cornell box, 2 000 box patches, 256 rays, every vertex: 1.65 %
    # relative RMS against 1.86 % without, vertices within 5 mm of another object +1.6 % bias
    # against +2.7 %; bake time +30 %.
    near_field: bool = True
    # ... and the light that came to them by way of other surfaces from a second gather of this many
    # rays at the nodes of a lattice over their triangle, not the patches' mean over their support
    # (NearField.second_rays; 0: from the patches). Real-scenes set, every vertex, 0 / 16 rays:
    # doorway 1.62 / 1.31 % (vertices where walls meet +2.8 / +1.4 % bias, room corners +12.5 /
    # +7.7 %), textured 2.44 / 1.80 %, production room 6.84 / 6.22 %; whole batch +8-16 %. 32 and
    # 64 rays gave what 16 gave within 0.01 points on the doorway. The Cornell box goes the other
    # way: 1.60 % with 0, 1.75 / 1.72 / 1.64 / 1.63 % with 16 / 32 / 64 / 256 (its ceiling 2.9 % at
    # 0 and 64 rays, 3.1 % at 16 and 32; its blocks 1.6 -> 2.2 % at any count).
    near_gather_rays: int = 16
    sky_samples: int = 256
    bake_sky_samples: int = 1024
    # Far transport hits link to clusters of patches (radiosity/clusters.py) whose cell diagonal is under
    # this many times the hit's distance; 0: alpha at every hit. Measured at every vertex against
    # Cycles, angle 0 / 0.125 / 0.25: at 100 k patches lamps_doorway 1.76 / 1.74 / 1.83 %, the
    # Cornell box 1.65 / 1.64 / 1.64 %, transport 15.1 / 11.8 / 11.6 s and 16.5 / 11.4 / 11.4 s
    # (scale_bench.py); at 2 000 patches (real_scenes_bench.py) doorway 1.62 / 1.63 / 1.51 %,
    # lamps_doorway 1.76 / 1.77 / 1.68 %, the other seven within 0.03 points. At 0.5 the doorway
    # is at 2.06 %: a large cluster seen near a receiver's horizon, or partly hidden, gives light
    # from where its rays do not land.
    cluster_angle: float = 0.125

    def __post_init__(self) -> None:
        if not (0 < self.tolerance < 1):
            raise OvradError(f"tolerance must be in (0, 1), got {self.tolerance}")
        if self.rule not in ("exact", "paper"):
            raise OvradError(f"rule must be 'exact' or 'paper', got {self.rule!r}")
        if not (0.0 <= self.smoothing <= 10.0):
            raise OvradError(f"smoothing must be in [0, 10], got {self.smoothing}")
        if not (1 <= self.rays_per_point <= 4096) or not (1 <= self.light_samples <= 1024):
            raise OvradError("rays_per_point must be in [1, 4096] and light_samples in [1, 1024]")
        if not (0 <= self.max_rays <= 1 << 30):
            raise OvradError(f"max_rays must be in [0, {1 << 30}], got {self.max_rays}")
        if not (0 <= self.min_rays <= 1 << 28):
            raise OvradError(f"min_rays must be in [0, {1 << 28}], got {self.min_rays}")
        if not (1 <= self.bake_samples <= 4096):
            raise OvradError(f"bake_samples must be in [1, 4096], got {self.bake_samples}")
        if not (2 <= self.sky_samples <= 1 << 16) or not (2 <= self.bake_sky_samples <= 1 << 16):
            raise OvradError("sky_samples and bake_sky_samples must be in [2, 65536]")
        if not (0.0 <= self.cluster_angle <= 2.0):
            raise OvradError(f"cluster_angle must be in [0, 2], got {self.cluster_angle}")
        if not (0 <= self.gather_rays <= MAX_GATHER_RAYS):
            raise OvradError(f"gather_rays must be in [0, {MAX_GATHER_RAYS}], got {self.gather_rays}")
        if not (0 <= self.near_gather_rays <= 1024):
            raise OvradError(f"near_gather_rays must be in [0, 1024], got {self.near_gather_rays}")


DEFAULT_SOLVE = SolveSettings()  # the defaults, one frozen instance for default arguments
