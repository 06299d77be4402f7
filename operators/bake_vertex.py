"""Bake to vertex colours: the solved light reconstructed at every face corner of the receivers.

Values are linear FLOAT_COLOR (alpha 1): outgoing radiance L = B/pi with the surface's own
emission (a Cycles DIFFUSE bake with colour, plus emission), or irradiance E/pi. The CORNER domain
keeps one value per face corner; the POINT domain averages a vertex's corners weighted by their
angles. An attribute of the bake's name is replaced only if it is exactly what an ovrad bake
wrote: the mesh keeps, in the custom property attributes.OWNED_PROP, each baked attribute's type, domain and
a hash of its values; an attribute the user made, converted or painted over is theirs.
"""

from __future__ import annotations

import time

import bpy
import numpy as np
from bpy.props import EnumProperty, StringProperty

from ..ovrad_addon import (
    BakeRequest,
    OvradError,
    bake_normals,
    bake_sides,
    irradiance_at,
    nudge,
    radiance_at,
    shared_normals,
    split_corners,
    without_area,
)
from . import attributes, mesh_reader, polls, properties, solve
from .solution import load_solution

CHUNK = 1 << 18  # corners reconstructed at a time (bounds the sparse alpha matrices)
# Linked duplicates are baked once, as their mean, when every user is within this relative RMS of
# it: below the solve's own noise (about 1-3 %), so the mean is as good as each user's own bake.
DUPLICATE_TOLERANCE = 0.02


def corner_angles(corners: np.ndarray) -> np.ndarray:
    """(T, 3) interior angle at each corner of triangles (T, 3, 3); 0 for degenerate ones."""
    out = np.zeros(corners.shape[:2])
    for k in range(3):
        a = corners[:, (k + 1) % 3] - corners[:, k]
        b = corners[:, (k + 2) % 3] - corners[:, k]
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        ok = (na > 0) & (nb > 0)
        cos = np.einsum("ij,ij->i", a[ok], b[ok]) / (na[ok] * nb[ok])
        out[ok, k] = np.arccos(np.clip(cos, -1.0, 1.0))
    return out


def own_corner_angles(mesh, matrix_world) -> np.ndarray:
    """(L,) the interior angle at each loop of a mesh as placed by matrix_world: the angles of its
    loop triangles' corners summed per loop (a quad's corner split over two triangles adds up)."""
    data = mesh_reader.read_mesh(mesh, matrix_world)
    angles = corner_angles(data.corners).ravel()
    return np.bincount(data.loops.ravel(), weights=angles, minlength=len(mesh.loops))


class ReceiverBake:
    """One receiver's bake points, read from bpy: corners of its evaluated loop triangles, each
    standing for a loop of the object's own mesh (the values are filled in by reconstruct()).

    Where the modifiers keep the mesh's topology every corner bakes. Where they change it
    (Subdivision, Array, Boolean, Triangulate, ...), each loop of the mesh bakes at the first
    evaluated corner that is a copy of it (mesh_reader.read_with_origins; the corner Cycles' own
    vertex-colour bake picks): on the evaluated surface, at the limit position of a subdivided
    corner. A vertex with no copy left (bevelled, or cut away by a Boolean) bakes at the evaluated
    vertex nearest to it (Cycles leaves it black), and a loop with no copy takes its vertex's value.
    A loose vertex (no face of the mesh uses it) lies on no surface and gets 0, as in Cycles' bake.
    """

    def __init__(self, obj, depsgraph, first_triangle: int, n_triangles: int, origins=None, data=None):
        """origins: what mesh_reader.read_with_origins gave for obj if its modifiers change its
        topology, else None (then read here if they do after all); data: obj's evaluated mesh in
        world space as the scene model read it (mesh_reader.MeshData; None: read here)."""
        self.obj = obj
        orig = obj.data
        own = mesh_reader.loop_vertices(orig)
        self.n_vertices, self.n_loops = len(orig.vertices), len(orig.loops)
        self.loose = np.setdiff1d(np.arange(self.n_vertices), own)
        if origins is None:
            if data is None:
                data = mesh_reader.read_object(obj, depsgraph)
            if not mesh_reader.keeps_topology(data, orig):
                origins = mesh_reader.read_with_origins([obj], depsgraph)[obj.name]
        if isinstance(origins, OvradError):
            raise origins
        kept = origins is None
        if not kept:
            data, origin = origins
        if len(data.triangles) != n_triangles:
            raise OvradError(f"'{obj.name}' changed since it was read: bake again")
        self.tri_verts = data.triangles  # evaluated vertices: corners of one vertex may share a gather
        self.points = data.corners  # (T, 3, 3)
        self.triangles = first_triangle + np.arange(n_triangles)
        self.no_area = np.zeros(n_triangles, bool)  # triangles without area (set by reconstruct)
        if kept:
            self.corners = np.arange(3 * n_triangles)  # into the (T * 3) corners
            self.loops = data.loops.ravel()
            self.angles = corner_angles(self.points).ravel()
            self.positions = data.vertices
            self.vertices = own[self.loops]
        else:
            if origin is None:
                raise OvradError(
                    f"the modifiers of '{obj.name}' drop its mesh's attributes (Remesh and the like), so "
                    "colours baked on the mesh would not show: apply the modifiers first"
                )
            self.positions = mesh_reader.vertex_positions(orig, obj.matrix_world)
            loops, corners = np.unique(origin[data.loops.ravel()], return_index=True)
            keep = loops >= 0
            loops, corners = loops[keep], corners[keep]
            vertices = own[loops]
            angles = own_corner_angles(orig, obj.matrix_world)[loops]
            # A vertex with no copy left (bevelled, cut away by a Boolean) bakes at the evaluated
            # vertex nearest to it, as the mean of that vertex's corners.
            missing = np.setdiff1d(np.setdiff1d(np.arange(self.n_vertices), vertices), self.loose)
            flat = data.triangles.ravel()
            if len(missing) and len(flat):
                from scipy.spatial import cKDTree

                order = np.argsort(flat, kind="stable")
                used = np.unique(flat)
                _, k = cKDTree(data.vertices[used]).query(self.positions[missing])
                lo = np.searchsorted(flat[order], used[k], "left")
                count = np.searchsorted(flat[order], used[k], "right") - lo
                start = np.repeat(lo - (np.cumsum(count) - count), count)
                extra = order[start + np.arange(count.sum())]
                corners = np.concatenate([corners, extra])
                loops = np.concatenate([loops, np.full(len(extra), -1)])
                vertices = np.concatenate([vertices, np.repeat(missing, count)])
                angles = np.concatenate([angles, corner_angles(self.points).ravel()[extra]])
            self.corners, self.loops, self.angles, self.vertices = corners, loops, angles, vertices
        self.loop_vertices = own

    def reconstruct(
        self, solution, quantity: str, share: bool = False, corner_cache: dict | None = None
    ) -> np.ndarray:
        """(n, 3) value at each bake corner (self.corners), negative ringing clamped to 0. share:
        the corners of a vertex whose faces turn little share one gather (bake.gather.shared_normals;
        for the POINT domain, which averages them). corner_cache: a dict kept over one bake's
        receivers and chunks (bake.gather.gather_indirect)."""
        problem = solution.problem
        c = self.corners
        self.no_area = without_area(problem, self.triangles)
        sides = np.repeat(bake_sides(problem, self.triangles), 3)[c]
        at = self.points.reshape(-1, 3)[c]
        # A vertex on a chart's border lies exactly on the rim of the squares placed along it (and,
        # after float32 storage, just outside): step each corner a hair into its triangle.
        pts = nudge(problem, at, np.repeat(self.points.mean(axis=1), 3, axis=0)[c])
        # The final gather starts from the corners themselves (it steps into the triangle on its
        # own), so the corners of one vertex on one face (normal and side) share one gather. Corners
        # go by vertex, so a vertex's corners fall into one chunk.
        verts = self.tri_verts.ravel()[c]
        order = np.argsort(verts, kind="stable")
        tris = np.repeat(self.triangles, 3)[c]
        # ... except at a vertex on a contact line (a floor vertex where a wall stands on it): there
        # each corner gathers from inside its own triangle, lit or hidden as its face is.
        normals = bake_normals(problem, tris, sides)
        split = split_corners(problem.index, verts, at, pts, normals)
        at = np.where(split[:, None], pts, at)
        # A vertex's corners on one side (not split, with area) may share one gather for their faces'
        # normals, weighted as domain_values weighs them (bake.gather.shared_normals), chunk by chunk: the
        # normals of every shared gather are held for the chunk's corners only.
        group = None
        if share:
            sliver = np.repeat(self.no_area, 3)[c]
            group = np.where(split | sliver, -1, verts * 2 + (sides < 0))
        fn = irradiance_at if quantity == "IRRADIANCE" else radiance_at
        out = np.empty((len(pts), 3))
        for s in range(0, len(pts), CHUNK):
            k = order[s : s + CHUNK]
            spread = None if group is None else shared_normals(group[k], normals[k], self.angles[k])
            request = BakeRequest(
                solution.radiosity,
                solution.first_shot,
                solution.light,
                gather_points=at[k],
                gather_normals=spread,
                corner_cache=corner_cache,
            )
            out[k] = fn(problem, request, pts[k], tris[k], sides[k])
        # Smooth beta rings slightly below 0 next to contact shadows; light is never negative.
        return np.maximum(out, 0.0)

    def domain_values(self, corner_values: np.ndarray, domain: str) -> np.ndarray:
        """(n, 3) per vertex (angle-weighted mean of its corners) or per face corner (loop) of the
        object's own mesh, from the values (m, 3) at the bake corners. Corners of triangles without
        area weigh nothing where a vertex has others (three points on a line have angles 0, 0 and
        pi: the middle one would outweigh the faces around it). A loose vertex gets 0; any other
        vertex no corner stands for, the value of the nearest one that has some; a loop its vertex's
        value."""
        vals = corner_values.reshape(-1, 3)
        w = self.angles * ~np.repeat(self.no_area, 3)[self.corners]
        point, has = self._means(self.vertices, self.n_vertices, w, vals)
        has[self.loose] = True  # _means left them at 0
        if not has.all() and has.any():
            from scipy.spatial import cKDTree

            known = np.flatnonzero(has)
            _, nearest = cKDTree(self.positions[known]).query(self.positions[~has])
            point[~has] = point[known[nearest]]
        if domain == "POINT":
            return point
        of_loop = self.loops >= 0  # corners standing for a vertex only have no loop
        loop, has = self._means(self.loops[of_loop], self.n_loops, w[of_loop], vals[of_loop])
        loop[~has] = point[self.loop_vertices[~has]]
        return loop

    @staticmethod
    def _means(target: np.ndarray, n: int, w: np.ndarray, vals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) the w-weighted mean of vals per target index (the plain mean where all weights
        are 0), and (n,) whether any value went to it."""
        den = np.bincount(target, weights=w, minlength=n)
        cnt = np.bincount(target, minlength=n)
        out = np.zeros((n, 3))
        for c in range(3):
            num = np.bincount(target, weights=w * vals[:, c], minlength=n)
            plain = np.bincount(target, weights=vals[:, c], minlength=n)
            # Corners of triangles without area only (all weights 0): a plain mean.
            out[:, c] = np.where(den > 0, num / np.maximum(den, 1e-300), plain / np.maximum(cnt, 1))
        return out, cnt > 0


def alike(values: list[np.ndarray]) -> bool:
    """Whether the users of one mesh are lit alike: every user's values (n, 3) within
    DUPLICATE_TOLERANCE relative RMS of their mean."""
    mean = np.mean(values, axis=0)
    scale = np.sqrt(np.mean(mean**2))
    if scale == 0.0:
        return True
    return max(float(np.sqrt(np.mean((v - mean) ** 2))) for v in values) <= DUPLICATE_TOLERANCE * scale


def bake_meshes(context, solution, name: str, domain: str, quantity: str) -> tuple[list[str], list]:
    """(warnings, [(mesh, values (n, 3))]): the values to write on each receiver's mesh.

    A receiver that cannot be baked is skipped with a warning saying why. Linked duplicates (one
    mesh, several receivers) hold one set of colours: their mean when they are lit alike (see
    alike()), else the mesh is skipped with a warning.
    """
    depsgraph = context.evaluated_depsgraph_get()
    surfaces = solution.problem.surfaces
    users: dict = {}  # mesh -> [(object, values)]
    warnings = []
    # each receiver's evaluated mesh, as the scene model read it for this bake
    evaluated = [it.data() for it in solution.items]
    # receivers whose modifiers change their topology: their maps to their own meshes, read together
    changed = [
        o
        for o, data in zip(solution.receivers, evaluated, strict=True)
        if o.data.library is None and not mesh_reader.keeps_topology(data, o.data)
    ]
    origins = mesh_reader.read_with_origins(changed, depsgraph) if changed else {}
    shared: dict = {}  # the gathers' corner cache, one for the whole bake
    for i, obj in enumerate(solution.receivers):
        mesh = obj.data
        try:
            if mesh.library is not None:
                raise OvradError(f"the mesh of '{obj.name}' is linked from a library: make it local first")
            attributes.check_target(mesh, name)
            n_tri = int(np.sum(surfaces.object_index == i))
            first = solution.first_triangle[i]
            bake = ReceiverBake(obj, depsgraph, first, n_tri, origins.get(obj.name), evaluated[i])
            values = bake.domain_values(
                bake.reconstruct(solution, quantity, domain == "POINT", shared), domain
            )
        except OvradError as e:
            warnings.append(f"'{obj.name}' not baked: {e}")
            continue
        users.setdefault(mesh, []).append((obj, values))
    writes = []
    for mesh, baked in users.items():
        values = [v for _, v in baked]
        if len(baked) > 1 and not alike(values):
            listed = ", ".join(f"'{o.name}'" for o, _ in baked)
            warnings.append(
                f"{listed} share the mesh '{mesh.name}' but are lit differently: not baked (one mesh "
                "holds one set of colours; to bake each, select them and use Object > Relations > "
                "Make Single User > Object & Data, then Generate Atlas, Solve and Bake again)"
            )
            continue
        writes.append((mesh, np.mean(values, axis=0)))
    return warnings, writes


class OVRAD_OT_bake_vertex(bpy.types.Operator):
    bl_idname = "ovrad.bake_vertex"
    bl_label = "Bake Vertex Colors"
    bl_description = (
        "Store the solved light in a colour attribute of every mesh with an atlas (linear radiance "
        "or irradiance); replaces only an attribute that an earlier ovrad bake made"
    )
    bl_options = {"REGISTER", "UNDO"}

    # Unset properties take the scene's bake settings (the panel's).
    attribute: StringProperty(name="Attribute", description="Colour attribute to write", maxlen=63)
    domain: EnumProperty(name="Domain", items=properties.BAKE_DOMAINS, default="POINT")
    quantity: EnumProperty(name="Quantity", items=properties.BAKE_QUANTITIES, default="RADIANCE")

    @classmethod
    def poll(cls, context):
        checks = (polls.object_mode(context, "bake"), (solve.running() is None, "A solve is running"))
        return polls.passes(cls, checks)

    def _option(self, context, key: str, scene_key: str):
        if self.properties.is_property_set(key):
            return getattr(self, key)
        return getattr(context.scene.ovrad, scene_key)

    def execute(self, context):
        attributes.keep_atlases_out_of_renders()  # atlases of older files rendered: mend them
        start = time.perf_counter()
        name = self._option(context, "attribute", "bake_attribute").strip()
        domain = self._option(context, "domain", "bake_domain")
        quantity = self._option(context, "quantity", "bake_quantity")
        # Everything that can fail runs before the first write, so an error leaves the file as it was.
        try:
            if not name or name.startswith("."):
                raise OvradError("give the bake an attribute name (not empty, not starting with '.')")
            solution = load_solution(context)
            warnings, writes = bake_meshes(context, solution, name, domain, quantity)
        except OvradError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if not writes:
            self.report({"ERROR"}, "nothing was baked: " + "; ".join(warnings))
            return {"CANCELLED"}
        for w in warnings:
            self.report({"WARNING"}, w)
        for mesh, vals in writes:
            attributes.write_color(mesh, name, vals, domain)
        values = [v for _, v in writes]
        count = sum(len(v) for v in values)
        self.report(
            {"INFO"},
            f"ovrad: baked {quantity.lower()} into '{name}' ({domain.lower()}, {count:,} values) on "
            f"{len(writes)} mesh(es) in {time.perf_counter() - start:.2f} s",
        )
        return {"FINISHED"}


classes = (OVRAD_OT_bake_vertex,)
