"""The atlas of overlapping patches: one array per patch property (Atlas), as stored on an atlas object."""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from .. import names
from ..errors import OvradError
from .lookup import PatchGrid
from .support import patch_table


@dataclass(frozen=True, eq=False)
class Atlas:
    """n patches; every array has n rows.

    centers (n, 3), normals (n, 3) unit, tangents (n, 3) unit in-plane axis, radii (n,) (disk
    radius, or half the side of a square), shapes (n,) int8 (0 disk, 1 square), sheet (n,)
    surface sheet index, source_object (n,) index into the surfaces' objects, thickness (n,)
    tolerated distance from the patch plane, min_cos (n,) least normal agreement,
    support_area (n,) area A_h of D_h on the surface, effective_area (n,) c_hh,
    overlap_count (n,) other patches overlapping, random (n,) stable value in [0, 1).
    triangle (n,) int64 and side (n,) int8 (+1 front, -1 back) say which sheet the patch lies on
    without searching: the sheet is (chart of that triangle, side); triangle is counted among the
    source object's own triangles, so it stays valid when other objects change. None (or -1
    entries) for atlases made before they existed: their sheets are found by locating the patch.
    anchor (n, 3): the point of its sheet a patch sees its support from (overlap/contacts.py); None (or NaN
    rows) where it was not stored: then the rule point nearest the centre.
    """

    centers: np.ndarray
    normals: np.ndarray
    tangents: np.ndarray
    radii: np.ndarray
    shapes: np.ndarray
    sheet: np.ndarray
    source_object: np.ndarray
    thickness: np.ndarray
    min_cos: np.ndarray
    support_area: np.ndarray
    effective_area: np.ndarray
    overlap_count: np.ndarray
    random: np.ndarray
    beta: str = "smooth"
    triangle: np.ndarray | None = None
    side: np.ndarray | None = None
    anchor: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.centers)

    @cached_property
    def bounding_radii(self) -> np.ndarray:
        """(n,) radius of the smallest ball around the centre holding the whole patch."""
        return self.radii * np.where(self.shapes == names.SHAPE_SQUARE, np.sqrt(2.0), 1.0)

    @cached_property
    def tree(self) -> cKDTree:
        """KD-tree of the patch centres."""
        return cKDTree(self.centers)

    @cached_property
    def grid(self):
        """PatchGrid (atlas/lookup.py): the candidate patches of surface points, by sheet and cell."""
        return PatchGrid.build(self)

    @cached_property
    def bitangents(self) -> np.ndarray:
        """(n, 3) second in-plane axis, normal x tangent."""
        return np.cross(self.normals, self.tangents)

    @cached_property
    def table(self) -> np.ndarray:
        """(n, k) float64: what a membership test reads of each patch, one row per patch
        (atlas/support.py patch_table: centre, frame, radius, thickness, min_cos, shape)."""
        return patch_table(self)

    @property
    def placement(self) -> tuple[np.ndarray, ...]:
        """The arrays that place and shape each patch, in a fixed order (content keys hash them)."""
        return (
            self.centers,
            self.normals,
            self.tangents,
            self.radii,
            self.shapes,
            self.thickness,
            self.min_cos,
        )

    def select(self, mask) -> Atlas:
        """The patches where mask is true (or the given indices), same beta."""
        kw = {f.name: getattr(self, f.name) for f in fields(self)}
        for k, v in kw.items():
            if isinstance(v, np.ndarray):
                kw[k] = v[mask]
        return Atlas(**kw)

    def point_attributes(self) -> dict[str, tuple[np.ndarray, str]]:
        """Blender POINT attributes: name -> (array, attribute type)."""
        located = {}
        if self.triangle is not None and self.side is not None:
            located = {
                names.TRIANGLE: (self.triangle.astype(np.int32), "INT"),
                names.SIDE: (self.side.astype(np.int32), "INT"),
            }
        if self.anchor is not None:
            located[names.ANCHOR] = (self.anchor, "FLOAT_VECTOR")
        return located | {
            names.NORMAL: (self.normals, "FLOAT_VECTOR"),
            names.RADIUS: (self.radii, "FLOAT"),
            names.SHAPE: (self.shapes.astype(np.int32), "INT"),
            names.TANGENT: (self.tangents, "FLOAT_VECTOR"),
            names.AREA: (self.effective_area, "FLOAT"),
            names.OVERLAP: (self.overlap_count.astype(np.int32), "INT"),
            names.SHEET: (self.sheet.astype(np.int32), "INT"),
            names.THICKNESS: (self.thickness, "FLOAT"),
            names.MIN_COS: (self.min_cos, "FLOAT"),
            names.SUPPORT_AREA: (self.support_area, "FLOAT"),
            names.RANDOM: (self.random, "FLOAT"),
        }

    def as_stored(self) -> Atlas:
        """This atlas as a file keeps it (Blender attributes: float32 and int32 values), read back as
        from_point_attributes() reads it; the very same values again when it already is. Build_atlas
        integrates C on it, so the C it gives is the one a solve of the stored atlas integrates."""
        attrs = {
            k: np.asarray(v, np.float32 if kind.startswith("FLOAT") else np.int32)
            for k, (v, kind) in self.point_attributes().items()
        }
        centers = np.asarray(self.centers, np.float32)
        return Atlas.from_point_attributes(centers, attrs, self.beta, self.source_object)

    @staticmethod
    def concatenate(atlases: list[Atlas]) -> Atlas:
        """One atlas holding all patches of several (e.g. one per Blender atlas object); same beta."""
        if not atlases:
            raise OvradError("no atlas: generate an atlas first")
        betas = {a.beta for a in atlases}
        if len(betas) > 1:
            raise OvradError(
                "atlases were generated with different beta profiles: generate them again together"
            )
        kw = {}
        for f in fields(Atlas):
            vals = [getattr(a, f.name) for a in atlases]
            if f.name in ("triangle", "side", "anchor"):
                # an atlas without them (made before they existed) is located by search (-1), its
                # anchors found again (NaN)
                missing = {"anchor": lambda k: np.full((k, 3), np.nan)}.get(
                    f.name, lambda k: np.full(k, -1, np.int64)
                )
                vals = (
                    None
                    if all(v is None for v in vals)
                    else [missing(len(a)) if v is None else v for a, v in zip(atlases, vals, strict=True)]
                )
                kw[f.name] = None if vals is None else np.concatenate(vals)
                continue
            kw[f.name] = np.concatenate(vals) if isinstance(vals[0], np.ndarray) else vals[0]
        return Atlas(**kw)

    @staticmethod
    def from_point_attributes(centers, attributes: dict, beta: str, source_object=None) -> Atlas:
        """Rebuild an atlas from point positions and the attributes point_attributes() wrote.

        Values are taken as they are (a file's float32 values widened, unit vectors unit to that
        rounding, not renormalised): so writing the atlas again keeps exactly the same values."""
        c = np.asarray(centers, np.float64).reshape(-1, 3)

        def get(name, shape=None, dtype=np.float64):
            a = np.asarray(attributes[name], dtype)
            return a.reshape(shape) if shape else a

        n = len(c)
        return Atlas(
            centers=c,
            normals=get(names.NORMAL, (-1, 3)),
            tangents=get(names.TANGENT, (-1, 3)),
            radii=get(names.RADIUS),
            shapes=get(names.SHAPE, dtype=np.int8),
            sheet=get(names.SHEET, dtype=np.int64),
            source_object=np.zeros(n, np.int64)
            if source_object is None
            else np.asarray(source_object, np.int64),
            thickness=get(names.THICKNESS),
            min_cos=get(names.MIN_COS),
            support_area=get(names.SUPPORT_AREA),
            effective_area=get(names.AREA),
            overlap_count=get(names.OVERLAP, dtype=np.int64),
            random=get(names.RANDOM),
            beta=beta,
            triangle=get(names.TRIANGLE, dtype=np.int64) if names.TRIANGLE in attributes else None,
            side=get(names.SIDE, dtype=np.int8) if names.SIDE in attributes else None,
            anchor=get(names.ANCHOR, (-1, 3)) if names.ANCHOR in attributes else None,
        )
