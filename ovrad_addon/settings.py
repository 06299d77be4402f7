"""Frozen settings dataclasses: the only form in which the engine receives user choices."""

from __future__ import annotations

from dataclasses import dataclass, field

from .errors import OvradError

BETA_PROFILES = ("box", "smooth")
SHAPE_MODES = ("AUTO", "DISKS", "SQUARES")
SIDE_MODES = ("AUTO", "FRONT", "BOTH")


# The rule of C (overlap.polar_rule: 4q rays, q // 4 rings; support_cuts: q points along a cut
# ray) by the atlas's size. A final gather reads the light of the many patches its rays hit, so a
# row's quadrature error is averaged over more patches the more there are. Measured on the
# production room, every vertex scored, q = 8 against 12: 7.37 against 6.88 % at 2 172 patches,
# 8.21 against 6.31 % at 9 461 (its curved BoomBox 17.7 against 12 %), 5.28 against 5.62 % at
# 31 808, 4.98 against 4.97 % at 108 570 (Generate 54.6 against 80.9 s); the Cornell box and
# lamps_doorway at 100 k patches to the digit (1.63 and 1.74 %). Rows of C against a rule of order
# 24 on that room: 3.5 % off on average at 2 k patches with q = 8 (2.6 % with 12), 1.3 % at 100 k
# (0.64 %). The coarse rule starts well above the largest count where it was seen to cost.
# q = 6 against 8 at 100 k patches, in one sitting each: the production room 5.15 against 5.29 %
# (Generate 49.8 against 58-75 s) and, on a second build of it, 6.48 against 7.37 % (42.1 against
# 61.3 s); the Cornell box and lamps_doorway to the digit (1.63, 1.74 %). An earlier round's
# build had given 5.56 against 5.28 %: the room's error moves more between builds than with q.
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
