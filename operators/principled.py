"""How much of a Principled BSDF's light is diffuse, as Cycles' diffuse bake counts it.

Cycles (Principled v2, Blender 4.0+) builds the BSDF in layers: the metallic and transmission
lobes take their shares of the weight first, then a dielectric specular lobe (and a coat, when
there is one) takes 1 - its albedo towards the viewer, and the diffuse lobe gets what is left.
ovrad is a diffuse solver, so:
- the metallic and transmission shares scale the reflectance everywhere (transport_factor): past
  a diffuse bounce Cycles' converged references, reflective caustics off, have no metallic lobe
  either, only its missing share;
- the specular and coat layers' share depends on the viewing direction, and after a diffuse
  bounce (reflective caustics off) Cycles leaves those layers out: they only scale what a bake
  reports, which Cycles views along each point's normal (bake_weight).
BAKE_WEIGHT is that diffuse weight of a white Principled BSDF viewed along its normal, measured
from Cycles' DIFFUSE bake colour pass (benchmarks/principled_layer.py, Blender 5.0.1; 4.2.23 gives
the same table, 5.3.0 within 6e-5), over roughness x F0. At roughness 0 it is 1 - F0 exactly, F0
being the Fresnel reflectance at normal incidence.
"""

from __future__ import annotations

import numpy as np

ROUGHNESS = np.linspace(0.0, 1.0, 11)
F0 = np.array([0.0, 0.02, 0.04, 0.08, 0.16, 0.32, 0.64, 1.0])
# rows: ROUGHNESS; columns: F0 (the last, F0 = 1, a mirror: nothing left for the diffuse lobe)
BAKE_WEIGHT = np.array(
    [
        (1.00000, 0.98000, 0.96000, 0.92000, 0.84000, 0.68000, 0.36000, 0.0),
        (1.00000, 0.98000, 0.96000, 0.92001, 0.84001, 0.68002, 0.36002, 0.0),
        (1.00000, 0.98002, 0.96004, 0.92010, 0.84020, 0.68037, 0.36041, 0.0),
        (1.00000, 0.98011, 0.96025, 0.92054, 0.84111, 0.68201, 0.36222, 0.0),
        (1.00000, 0.98043, 0.96094, 0.92197, 0.84394, 0.68701, 0.36783, 0.0),
        (1.00000, 0.98125, 0.96262, 0.92535, 0.85051, 0.69858, 0.38111, 0.0),
        (1.00000, 0.98283, 0.96579, 0.93163, 0.86253, 0.71976, 0.40639, 0.0),
        (1.00000, 0.98520, 0.97048, 0.94079, 0.87998, 0.75088, 0.44574, 0.0),
        (1.00000, 0.98801, 0.97601, 0.95158, 0.90063, 0.78854, 0.49724, 0.0),
        (1.00000, 0.99080, 0.98149, 0.96228, 0.92134, 0.82747, 0.55605, 0.0),
        (1.00000, 0.99320, 0.98621, 0.97160, 0.93969, 0.86329, 0.61682, 0.0),
    ]
)

DEFAULT_ROUGHNESS = 0.5  # a roughness driven by nodes (a texture) is read as Blender's default


def f0_of(ior: float, level: float = 0.5) -> float:
    """Fresnel reflectance at normal incidence of a Principled BSDF's specular lobe: ((IOR - 1) /
    (IOR + 1))^2, times 2 x its Specular IOR Level (0.5 leaves it as the IOR gives it), in [0, 1]."""
    ior = max(float(ior), 1e-5)
    f0 = ((ior - 1.0) / (ior + 1.0)) ** 2 * 2.0 * max(float(level), 0.0)
    return float(min(f0, 1.0))


def layer_weight(roughness: float, f0: float) -> float:
    """The diffuse weight (BAKE_WEIGHT) under one dielectric lobe of this roughness and F0, viewed
    along the normal: bilinear in roughness and F0."""
    r = float(np.clip(roughness, 0.0, 1.0)) * (len(ROUGHNESS) - 1)
    i = min(int(r), len(ROUGHNESS) - 2)
    row = BAKE_WEIGHT[i] * (i + 1 - r) + BAKE_WEIGHT[i + 1] * (r - i)
    return float(np.interp(np.clip(f0, 0.0, 1.0), F0, row))


def _value(node, name: str, fallback: float, linked=None) -> float:
    """A float input's value: its own, or where nodes drive it what linked(socket) reads (None:
    unread), else `fallback` (also for a missing input)."""
    socket = node.inputs.get(name)
    if socket is None:
        return fallback
    if not socket.is_linked:
        return float(socket.default_value)
    got = None if linked is None else linked(socket)
    return fallback if got is None else float(got)


def transport_factor(node, linked=None) -> float:
    """The share of a Principled BSDF's Base Color its diffuse lobe keeps: (1 - Metallic) x
    (1 - Transmission Weight) (driven by nodes linked cannot read: 0). linked(socket) -> float or
    None reads a float input that nodes drive (materials.float_input)."""
    metallic = np.clip(_value(node, "Metallic", 0.0, linked), 0.0, 1.0)
    transmission = np.clip(_value(node, "Transmission Weight", 0.0, linked), 0.0, 1.0)
    return float((1.0 - metallic) * (1.0 - transmission))


def bake_weight(node, linked=None) -> float:
    """The share of a Principled BSDF's diffuse light a bake reports: under its specular lobe
    (Roughness, IOR, Specular IOR Level, the brightest channel of Specular Tint) and its coat (Coat
    Weight, Coat Roughness, Coat IOR), viewed along the normal. linked: as transport_factor's."""
    roughness = _value(node, "Roughness", DEFAULT_ROUGHNESS, linked)
    tint = node.inputs.get("Specular Tint")
    brightest = 1.0
    if tint is not None and not tint.is_linked:
        brightest = max(0.0, float(max(tint.default_value[:3])))
    level = _value(node, "Specular IOR Level", 0.5, linked)
    f0 = f0_of(_value(node, "IOR", 1.5, linked), level) * brightest
    weight = layer_weight(roughness, f0)
    coat = np.clip(_value(node, "Coat Weight", 0.0, linked), 0.0, 1.0)
    if coat > 0.0:
        coat_f0 = f0_of(_value(node, "Coat IOR", 1.5, linked))
        weight *= 1.0 - coat * (1.0 - layer_weight(_value(node, "Coat Roughness", 0.03, linked), coat_f0))
    return float(weight)
