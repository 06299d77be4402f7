"""Reading the world's light (World > Surface) as an engine Sky.

Read: a Background (or Emission) shader whose Color is a constant or an Environment Texture
(equirectangular, its pixels in linear RGB: float images as they are, 8-bit sRGB decoded as Cycles
decodes them), times Strength; the texture may be turned about Z by a Mapping node on its Vector
input (fed by a Texture Coordinate's Generated or Object output, or by nothing). Anything else (a
Sky Texture, a gradient, a Light Path trick, a Mapping that tilts the map) is approximated by the
world's viewport colour (World > Viewport Display > Color) with one warning naming what was
approximated. A world with strength 0, or none, gives no light.
"""

from __future__ import annotations

import numpy as np

from ..ovrad_addon import Sky
from . import compat, images, materials

MAX_SKY_WIDTH = 1024  # wider maps are averaged down by whole blocks of pixels (power kept)
_SHADERS = ("ShaderNodeBackground", "ShaderNodeEmission")
_COORDINATES = ("Generated", "Object")


def read_world(scene, warnings: list[str] | None = None) -> Sky | None:
    """The world's light as a Sky, None when it gives none (no world, strength 0, black)."""
    warnings = [] if warnings is None else warnings
    world = scene.world
    if world is None:
        return None
    if not compat.renders_with_nodes(world):
        return _emitting(Sky(tuple(float(c) for c in world.color[:3])))
    shader = materials.surface_node(world.node_tree)
    if shader is None:
        return None  # Cycles renders a world without a surface black
    if shader.bl_idname not in _SHADERS:
        return _approximate(world, f"a {shader.bl_label} shader", warnings)
    strength_socket = shader.inputs["Strength"]
    if strength_socket.is_linked:
        return _approximate(world, "a Strength driven by nodes", warnings)
    strength = float(strength_socket.default_value)
    if strength <= 0:
        return None
    color, _ = materials.upstream(shader.inputs["Color"])
    if color is None:
        rgb = np.array(shader.inputs["Color"].default_value[:3], float) * strength
        return _emitting(Sky(tuple(np.maximum(rgb, 0.0))))
    if color.bl_idname != "ShaderNodeTexEnvironment":
        return _approximate(world, f"a {color.bl_label} node", warnings)
    return _environment(world, color, strength, warnings)


def _emitting(sky: Sky) -> Sky | None:
    return sky if sky.emits else None


def _approximate(world, what: str, warnings: list[str]) -> Sky | None:
    rgb = np.maximum(np.array(world.color[:3], float), 0.0)
    warnings.append(
        f"world '{world.name}' has {what}: its light is approximated by the world's viewport colour "
        f"({', '.join(f'{v:.3g}' for v in rgb)}) (set World > Viewport Display > Color to the sky's "
        "mean radiance, or use a Background with a colour or an equirectangular Environment Texture)"
    )
    return _emitting(Sky(tuple(rgb)))


def _environment(world, node, strength: float, warnings: list[str]) -> Sky | None:
    """An Environment Texture node: its pixels x strength, turned by a Mapping node's Z rotation."""
    if node.image is None:
        # Cycles shows the missing-texture magenta; no light is the sober reading
        warnings.append(f"world '{world.name}': its Environment Texture has no image; no world light")
        return None
    if node.projection != "EQUIRECTANGULAR":
        return _approximate(
            world, f"a {node.projection.lower().replace('_', ' ')} Environment Texture", warnings
        )
    pixels = sky_pixels(node.image)
    if pixels is None:
        warnings.append(f"world '{world.name}': image '{node.image.name}' has no pixels; no world light")
        return None
    rotation = _rotation_z(node, world, warnings)
    if rotation is None:
        return _approximate(world, "a map turned other than about Z", warnings)
    return _emitting(Sky(image=pixels * np.float32(strength), rotation_z=rotation))


def _rotation_z(node, world, warnings: list[str]) -> float | None:
    """Radians the map is turned about +Z (Sky.rotation_z) by what drives its Vector input; None if
    that is not a plain turn about Z."""
    src, src_out = materials.upstream(node.inputs["Vector"])
    if src is None:
        return 0.0
    if src.bl_idname == "ShaderNodeTexCoord":
        return 0.0 if src_out.name in _COORDINATES else None
    if src.bl_idname != "ShaderNodeMapping":
        return None
    feed, feed_out = materials.upstream(src.inputs["Vector"])
    if feed is not None and not (feed.bl_idname == "ShaderNodeTexCoord" and feed_out.name in _COORDINATES):
        return None
    socket = {s.name: s for s in src.inputs}
    if any(socket[k].is_linked for k in ("Rotation", "Scale", "Location") if k in socket):
        return None
    rot = np.array(socket["Rotation"].default_value[:3], float)
    scale = np.array(socket["Scale"].default_value[:3], float) if "Scale" in socket else np.ones(3)
    if np.any(np.abs(rot[:2]) > 1e-6) or not np.allclose(scale[:2], scale[0]) or scale[0] <= 0:
        return None
    if src.vector_type == "POINT" and "Location" in socket:
        if np.any(np.abs(np.array(socket["Location"].default_value[:3])) > 1e-9):
            warnings.append(
                f"world '{world.name}': the Mapping's Location is ignored (the sky is infinitely far)"
            )
    # POINT / VECTOR / NORMAL look the map up at R d (the map turns by -z); TEXTURE at R^-1 d
    return float(rot[2]) if src.vector_type == "TEXTURE" else -float(rot[2])


def sky_pixels(image) -> np.ndarray | None:
    """Linear RGB pixels (h, w, 3) float32 of an equirectangular image, row 0 at the bottom, None
    without pixels; wider than MAX_SKY_WIDTH: averaged down by whole blocks (a small sun keeps its
    power, where picking pixels would miss it)."""
    rgb = images.linear_pixels(image)
    if rgb is None:
        return None
    h, w = rgb.shape[:2]
    step = -(-w // MAX_SKY_WIDTH)
    if step > 1:
        hh, ww = h // step * step, w // step * step
        rgb = rgb[:hh, :ww].reshape(hh // step, step, ww // step, step, 3).mean(axis=(1, 3))
    return np.ascontiguousarray(np.clip(np.nan_to_num(rgb, posinf=0.0), 0.0, None), np.float32)
