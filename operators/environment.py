"""The environment atlas: patches on every rendered mesh that has no atlas of its own (instances,
meshes not baked), so they reflect light in a solve; one hidden atlas object keeps them (and their
radiosity, which bakes gather from) with a fingerprint of the surfaces they were built from."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..ovrad_addon import (
    Atlas,
    AtlasSettings,
    KeptOverlaps,
    ObjectSettings,
    OvradError,
    Surfaces,
    add_array,
    build_atlas_and_overlaps,
    hasher,
    keep,
    names,
    triangle_geometry,
)
from . import attributes

# Environment patches are this many times the receivers' typical spacing. Their light reaches
# what is baked only through the transport and the bakes' final gather, which both integrate
# it over solid angle, so their own detail matters less than the receivers'; shadows they cast
# come from rays, not from their patches. 1.5x costs 1/2.25 of the patches per area.
SPACING_FACTOR = 1.5
# At most this many environment patches per receiver patch (and at least MIN_CAP in all): a
# large surrounding (a forest of instances around one baked floor) coarsens instead of making
# the solve many times slower.
PATCHES_PER_RECEIVER_PATCH = 2.0
MIN_CAP = 2000


@dataclass
class Environment:
    """The environment atlas of a solve or bake.

    atlas: its patches (source_object: the surfaces object each lies on, -1 when an older stored
    atlas does not say) or None when nothing lacks an atlas (or it could not
    be built); key: fingerprint of what it covers; new: built now, to be written when the solve
    finishes; name: the atlas object holding it (names.ENVIRONMENT until a new one is written);
    kept: the C of its patches, as integrated when it was built or kept on its object (None: none).
    """

    atlas: Atlas | None
    key: str
    new: bool = False
    name: str = ""
    kept: KeptOverlaps | None = None


def receiver_spacing(atlas: Atlas) -> float:
    """Typical spacing of the receivers' patches: the median sqrt of their effective areas
    (sum_k c_kk is the surface's area, so c_kk is one patch's share of it)."""
    a = atlas.effective_area[atlas.effective_area > 0]
    if len(a) == 0:
        return float(np.median(atlas.radii))
    return float(np.median(np.sqrt(a)))


def _settings(base: AtlasSettings, surfaces: Surfaces, env: np.ndarray, n_receiver_patches: int, spacing):
    """The scene's atlas settings with a patch size for the environment (see SPACING_FACTOR)."""
    area = float(triangle_geometry(surfaces.corners[env[surfaces.object_index]])[0].sum())
    cap = max(PATCHES_PER_RECEIVER_PATCH * n_receiver_patches, MIN_CAP)
    size = max(SPACING_FACTOR * spacing, float(np.sqrt(area / cap)))
    # Per-object density is a receiver's setting: the environment keeps only the sides chosen.
    objects = tuple(ObjectSettings(sides=o.sides) for o in base.objects)
    return replace(base, patch_size=size, objects=objects)


def fingerprint(surfaces: Surfaces, env: np.ndarray, settings: AtlasSettings) -> str:
    """What the environment atlas depends on: the world geometry of every surface (probe rays
    see all of them), which objects it covers, and the settings."""
    h = hasher(20)
    for a in (surfaces.vertices, surfaces.triangles, surfaces.object_index, env):
        add_array(h, a)
    h.update(repr(settings).encode())
    return h.hexdigest()


def plan(
    scene, surfaces: Surfaces, n_receivers: int, receivers: Atlas, base: AtlasSettings, build: bool, warnings
) -> Environment:
    """The environment of surfaces whose objects from n_receivers on have no atlas of their own:
    the stored atlas when its fingerprint matches, else (build) a new one; raises OvradError when
    a bake finds it missing or stale."""
    env = np.arange(len(surfaces.object_names)) >= n_receivers
    stored = attributes.environment_object(scene)
    if not env.any():
        return Environment(None, "")
    settings = _settings(base, surfaces, env, len(receivers), receiver_spacing(receivers))
    key = fingerprint(surfaces, env, settings)
    if stored is not None and stored.get(names.PROP_ENVIRONMENT) == key:
        atlas = attributes.read_atlas(stored)
        # the fingerprint matched: the surfaces, so their object numbers, are those it was built on
        if names.OBJECT in stored.data.attributes:
            owner = attributes.read_point_attribute(stored.data, names.OBJECT).astype(np.int64)
        else:
            owner = np.full(len(atlas), -1, np.int64)  # located by search (radiosity.problem.attach_sheets)
        kept = attributes.read_kept(stored, len(receivers))
        return Environment(replace(atlas, source_object=owner), key, name=stored.name, kept=kept)
    if not build:
        raise OvradError(
            "the meshes without an atlas of their own (they reflect light too) changed since the last "
            "solve: press Solve again first"
        )
    try:
        atlas, C, quadrature, flags = build_atlas_and_overlaps(replace(surfaces, receiver=env), settings)
    except OvradError as e:
        warnings.append(f"the meshes without an atlas only cast shadows in this solve: {e}")
        return Environment(None, key)
    atlas = atlas.as_stored()
    # its C, integrated just now: this solve uses it, and the file keeps it for the next ones
    kept = keep(surfaces, atlas, C, quadrature, settings.crease_angle, len(receivers), flags)
    return Environment(atlas, key, new=True, name=names.ENVIRONMENT, kept=kept)


def store(scene, environment: Environment) -> str:
    """Write a new environment atlas (or remove a stale one when none is needed); returns the
    name of the object holding it ('' if none)."""
    stored = attributes.environment_object(scene)
    if environment.atlas is None:
        if stored is not None:
            attributes.remove_atlas(stored)
        return ""
    if environment.new:
        stored = attributes.write_environment(scene, environment.atlas, environment.key, environment.kept)
        environment.new = False
    environment.name = stored.name
    return stored.name
