"""The files and image data blocks of an image bake: paths from a template, folders made (and
removed again on failure), and the image written to its file first, then to Blender's image
`name` (replacing only an image an earlier bake made)."""

from __future__ import annotations

import os
import tempfile

import bpy
import numpy as np

from ..ovrad_addon import OvradError, names
from . import png16

IMAGE_MARK = "ovrad_bake"  # custom property on images this operator made (only those are replaced)
EXTENSIONS = {"OPEN_EXR": ".exr", "PNG": ".png"}  # the file format of an image bake, by its extension
FORMAT_NAMES = {"OPEN_EXR": "OpenEXR", "PNG": "16-bit PNG"}


def resolve_path(template: str, obj_name: str, file_format: str = "OPEN_EXR") -> str:
    """Absolute file path for an object; '//' needs a saved .blend file. A path without an
    extension gets the format's; one with another extension is refused."""
    path = template.replace("{object}", bpy.path.clean_name(obj_name))
    if path.startswith("//") and not bpy.data.filepath:
        raise OvradError(
            "the output path is relative ('//') but the .blend file is not saved: give a full path"
        )
    path = os.path.abspath(bpy.path.abspath(path))
    ext = EXTENSIONS[file_format]
    have = os.path.splitext(path)[1]
    if not have:
        path += ext
    elif have.lower() != ext:
        raise OvradError(f"the output must be a {FORMAT_NAMES[file_format]} file ({ext}), got '{path}'")
    return path


def prepare_folder(path: str, created: list) -> None:
    """Make the file's folder (recording what was created) and check a file can be written there."""
    folder = os.path.dirname(path)
    missing = []
    probe = folder
    while not os.path.exists(probe):
        missing.append(probe)
        probe = os.path.dirname(probe)
    try:
        for d in reversed(missing):
            os.mkdir(d)
            created.append(d)
        if os.path.isdir(path):
            raise OSError("it is a folder")
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".ovrad-probe-"):
            pass
    except OSError as e:
        raise OvradError(f"cannot write '{path}': {e.strerror or e}") from None


def remove_created(created: list) -> None:
    for d in reversed(created):
        try:
            os.rmdir(d)
        except OSError:
            pass


def write_image(
    name: str, pixels: np.ndarray, path: str, stored_path: str, file_format: str = "OPEN_EXR"
) -> bpy.types.Image:
    """Save pixels (H, W, 4) as a 32-bit float EXR (or a 16-bit PNG, png16.py), then create or
    replace the image `name` (a PNG's holds the file's values; its exposure is the image's custom
    property names.PROP_EXPOSURE)."""
    h, w = pixels.shape[:2]
    if file_format == "PNG":
        try:
            exposure = png16.write(path, pixels)
            img = bpy.data.images.load(path, check_existing=False)
            img.colorspace_settings.name = "Non-Color"  # linear values, no view transform
            img.reload()
        except (OSError, RuntimeError) as e:
            raise OvradError(f"cannot write '{path}': {str(e).strip().splitlines()[0]}") from None
        img[names.PROP_EXPOSURE] = exposure
    else:
        img = bpy.data.images.new(name + ".tmp", w, h, alpha=True, float_buffer=True)
        try:
            img.colorspace_settings.name = "Non-Color"  # linear values, no view transform
            img.pixels.foreach_set(np.ascontiguousarray(pixels, np.float32).ravel())
            img.file_format = "OPEN_EXR"
            img.filepath_raw = path
            img.save()
        except RuntimeError as e:
            bpy.data.images.remove(img)
            raise OvradError(f"cannot write '{path}': {str(e).strip().splitlines()[0]}") from None
    img.filepath_raw = stored_path
    img[IMAGE_MARK] = True
    img.use_fake_user = True  # kept in the saved file even before a material uses it
    old = bpy.data.images.get(name)
    if old is not None and old.get(IMAGE_MARK):
        old.user_remap(img)  # materials using the earlier bake now show this one
        bpy.data.images.remove(old)
    img.name = name
    return img
