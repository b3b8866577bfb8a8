"""Surfaces (paper section 2): triangulate a scan, then find closest points on it.

How the surface is made depends on the scan's kind (core.scan.ScanKind); the closest-point queries that E,
ICP and the search use are the same for every kind (:class:`Surface`):

- single view: from the range grid when there is one (neighbouring occupied cells make triangles), else
  from a 2.5-D Delaunay triangulation of the points as seen from the viewpoint;
- panorama: from the spherical range image about the sensor, triangulated as a grid (core.panorama);
- unstructured: tangent planes at the points (core.unstructured), no triangles.

Triangles with an edge longer than ``EDGE_FACTOR`` times the local point spacing are dropped, so a
surface never bridges a depth jump or a hole. Faces are wound so that their normals face the sensor.
"""

from __future__ import annotations

import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import Delaunay, QhullError, cKDTree

from .errors import InputError
from .rows import cross, norms
from .scan import Scan, ScanKind, kd_tree
from .threads import cached_property, usable_cores

EDGE_FACTOR = 4.0  # an edge may be at most this many times the local spacing of either endpoint
SPACING_NEIGHBOURS = 4
PARALLEL_QUERY = 20_000  # k-d tree queries of more points than this run on every core
# Neighbourhood fits (:func:`spreads`) of more than this many points run in one part per core (at most Open3D's thread
# count, which a task stream's --threads sets): numpy lets go of the GIL in the mean, the products and the
# eigen-solver, and each row's fit depends on that row alone, so the parts give the whole array's bits. Measured here
# (2 cores, 250k neighbourhoods of 12): 0.78 s in one part, 0.55 s in two.
PARALLEL_SPREADS = 50_000
_SPREADS_POOL: ThreadPoolExecutor | None = None
_SPREADS_LOCK = threading.Lock()


def local_spacing(points: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    """(N,) mean distance from each point to its ``SPACING_NEIGHBOURS`` nearest neighbours (``tree``: a
    k-d tree of ``points`` already built)."""
    k = min(SPACING_NEIGHBOURS + 1, len(points))
    tree = kd_tree(points) if tree is None else tree
    # the same answer on every core; below ~20k points starting the threads costs more than they save
    d, _ = tree.query(points, k=k, workers=-1 if len(points) > PARALLEL_QUERY else 1)
    return d[:, 1:].mean(axis=1)


def pca_normals(points: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
    """(Q, 3) unit normals, sign arbitrary: the direction of least spread of each row of (Q, k) indices
    into (N, 3) ``points`` (the smallest eigenvector of the neighbourhood's covariance)."""
    return spreads(points[neighbours])[0]


def spreads(nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Of neighbourhoods (Q, k, 3): (Q, 3) the direction of least spread (unit, sign arbitrary) and (Q, 3) the
    spreads (the covariance's eigenvalues, smallest first). More than :data:`PARALLEL_SPREADS` of them: one part per
    core, the same bits."""
    if len(nb) <= PARALLEL_SPREADS:
        return _spreads(nb)
    # Open3D's thread count is the task stream's (app.distributed: --threads, a worker's share); where Open3D is not
    # loaded (info, scenes: they do without its import) no stream has set one
    o3d = sys.modules.get("open3d")
    parts = min(usable_cores(), o3d.utility.get_max_threads()) if o3d is not None else usable_cores()
    if parts < 2:
        return _spreads(nb)
    cuts = np.linspace(0, len(nb), parts + 1).astype(int)
    done = list(_spreads_pool().map(_spreads, [nb[a:b] for a, b in zip(cuts[:-1], cuts[1:])]))
    return np.concatenate([d[0] for d in done]), np.concatenate([d[1] for d in done])


def _spreads(nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    nb = nb - nb.mean(1, keepdims=True)
    vals, vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))
    return vecs[:, :, 0], vals


def _spreads_pool() -> ThreadPoolExecutor:
    global _SPREADS_POOL
    with _SPREADS_LOCK:
        if _SPREADS_POOL is None:
            _SPREADS_POOL = ThreadPoolExecutor(usable_cores(), thread_name_prefix="spreads")
        return _SPREADS_POOL


def _forget_pool_in_child() -> None:
    global _SPREADS_POOL, _SPREADS_LOCK
    _SPREADS_POOL, _SPREADS_LOCK = None, threading.Lock()  # a forked child has the pool's object, not its threads


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pool_in_child)


def normal_angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N,) angles in degrees, 0-90, between the unoriented unit normals (N, 3) ``a`` and ``b``."""
    return np.degrees(np.arccos(np.clip(np.abs(np.einsum("ij,ij->i", a, b)), 0.0, 1.0)))


def edge_bound(spacing: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M, 3) longest allowed length of each triangle edge: EDGE_FACTOR x the smaller endpoint spacing.

    The smaller, because a spurious return floating off the surface is itself sparse: judged by its
    own spacing, the long edges tying it to the surface would pass and leave a spike.
    """
    s = spacing[faces]
    return EDGE_FACTOR * np.minimum(s, np.roll(s, -1, axis=1))


EDGE_BLOCK = 1 << 20  # faces whose edges are measured at once (edge_lengths)


def edge_lengths(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(M, 3) lengths of edges (v0v1, v1v2, v2v0)."""
    # each corner gathered once (np.take: 0.44 x the time of six fancy-index gathers on the LiDAR frame's 109k
    # faces), in blocks so that the corners of a 4M-triangle mesh never sit in memory at once (0.3 GB)
    out = np.empty(faces.shape, dtype=np.float64)
    for lo in range(0, len(faces), EDGE_BLOCK):
        block = faces[lo:lo + EDGE_BLOCK]
        corners = [np.take(points, block[:, k], axis=0) for k in range(3)]
        for k in range(3):
            out[lo:lo + EDGE_BLOCK, k] = norms(corners[k] - corners[(k + 1) % 3])
    return out


def view_projection(points: np.ndarray, viewpoint: np.ndarray,
                    axis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Gnomonic projection of (N, 3) points as seen from ``viewpoint``.

    Returns (N, 2) coordinates on the plane one unit in front of the sensor, perpendicular to the
    mean viewing direction (or ``axis``), and that (3, 3) basis (rows: u, v, axis). Points must lie
    in front.
    """
    rays = points - viewpoint
    axis = rays.mean(0) if axis is None else np.array(axis, dtype=np.float64)
    if not np.linalg.norm(axis) > 0:
        raise InputError("the viewpoint sits at the centre of the points; give the sensor position")
    basis = view_basis(axis)
    local = rays @ basis.T
    depth = local[:, 2]
    if np.any(depth <= 1e-12 * np.abs(local).max()):
        raise InputError("some points lie beside or behind the viewpoint; check the sensor position")
    return local[:, :2] / depth[:, None], basis


def view_basis(axis: np.ndarray) -> np.ndarray:
    """(3, 3) rows u, v, the unit ``axis`` (3,): the plane :func:`view_projection` projects onto, and its normal."""
    axis = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    u = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(axis, u), axis])


def triangulate(scan: Scan, axis: np.ndarray | None = None) -> np.ndarray:
    """(M, 3) int64 faces over ``scan.points``; see the module notes. ``axis``: the viewing direction
    to project along (default the mean ray), so that a part of a scan triangulates as within the whole
    (a single-view scan's; a panorama's image has no axis). An unstructured scan has no triangulation
    (InputError): its surface is :func:`surface_of`'s tangent planes."""
    return _triangulate(scan, axis)[0]


def surface_of(scan: Scan) -> Surface:
    """The surface of ``scan`` by its kind (module notes): :meth:`Surface.from_scan`. Of a part of a scan
    too (``dataclasses.replace(scan, points=part, grid=None, faces=None)``), e.g. half of its points."""
    return Surface.from_scan(scan)


def _triangulate(scan: Scan, axis: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """:func:`triangulate`'s faces and their longest edge (units; :attr:`Surface.reach`), from the edge
    lengths the triangulation measures anyway."""
    pts = scan.points
    if scan.kind is ScanKind.PANORAMA:
        return _panorama_faces(scan)
    if scan.kind is ScanKind.UNSTRUCTURED:
        raise InputError(f"{scan.name}: an unstructured scan is not triangulated (its surface is tangent planes)")
    if scan.grid is not None:
        faces = _grid_faces(scan.grid.index)
    else:
        try:
            uv, _ = view_projection(pts, scan.viewpoint, axis)
        except InputError as exc:
            raise InputError(f"{scan.name}: {exc}") from None
        try:
            faces = Delaunay(uv, qhull_options="Qbb Qc Qz Q12").simplices.astype(np.int64)
        except (QhullError, ValueError):
            raise InputError(f"{scan.name}: the points are too thin to triangulate as seen from the viewpoint "
                             f"{np.round(scan.viewpoint, 4).tolist()} (seen edge-on?)") from None
    if len(faces):
        spacing = local_spacing(pts, scan.tree)  # the scan's own tree (built once, for its spacing too)
        lengths = edge_lengths(pts, faces)
        kept = np.all(lengths <= edge_bound(spacing, faces), axis=1)
        faces, lengths = faces[kept], lengths[kept]
    if len(faces) == 0:
        raise InputError(f"{scan.name}: no surface could be built (every triangle bridged a gap)")
    # winding a face the other way measures the same three edges
    return _face_sensor(pts, faces, scan.viewpoint), float(lengths.max())


# The surfaces of the other kinds are built in their own modules on top of this one (core.panorama: a spherical
# image's faces; core.unstructured: tangent planes). Each puts its builder here when it is imported (core's
# package imports both), so that this module, which they build on, imports neither.
PANORAMA_FACES: list = []  # [scan -> ((M, 3) faces, (M, 3) edge lengths)], set by core.panorama
SURFACE_OF_KIND: dict = {}  # ScanKind -> (scan -> Surface), set by core.unstructured


def _panorama_faces(scan: Scan) -> tuple[np.ndarray, float]:
    """A panorama's faces (core.panorama: its spherical image as a grid, edges bounded by the image's spacing)
    and their longest edge."""
    faces, lengths = PANORAMA_FACES[0](scan)
    if len(faces) == 0:
        raise InputError(f"{scan.name}: no surface could be built from the spherical image (every triangle "
                         "bridged a gap)")
    return _face_sensor(scan.points, faces, scan.viewpoint), float(lengths.max())


def _grid_faces(idx: np.ndarray) -> np.ndarray:
    a, b = idx[:-1, :-1], idx[:-1, 1:]
    c, d = idx[1:, :-1], idx[1:, 1:]
    tris = []
    full = (a >= 0) & (b >= 0) & (c >= 0) & (d >= 0)
    tris += [np.c_[a[full], b[full], c[full]], np.c_[b[full], d[full], c[full]]]
    for p, q, r, missing in ((a, b, c, d), (b, d, c, a), (d, c, a, b), (c, a, b, d)):
        m = (p >= 0) & (q >= 0) & (r >= 0) & (missing < 0)
        tris.append(np.c_[p[m], q[m], r[m]])
    return np.concatenate(tris).astype(np.int64)


def _face_sensor(points, faces, viewpoint):
    p0 = np.take(points, faces[:, 0], axis=0)
    n = cross(np.take(points, faces[:, 1], axis=0) - p0, np.take(points, faces[:, 2], axis=0) - p0)
    flip = np.einsum("ij,ij->i", n, viewpoint - p0) < 0
    # the flipped faces' last two corners swapped (np.where: 0.4 x the time of a boolean gather and scatter, 120k faces)
    return np.c_[faces[:, 0], np.where(flip, faces[:, 2], faces[:, 1]), np.where(flip, faces[:, 1], faces[:, 2])]


# Queries worked out in float64 at once by Surface.closest_with_normals: ~0.6 kB of temporaries a query, so a
# whole multi-million-point scan (fuse, the page's residuals) stays within ~120 MB
CLOSEST_BLOCK = 200_000


def closest_on_triangles(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For (N, 3) points ``p`` and the (N, 3) corners ``a``, ``b``, ``c`` of one triangle each: the (N, 3)
    closest points on the triangles and their (N, 3) unit normals ((b - a) x (c - a), as Open3D's), in
    float64 (Ericson, Real-Time Collision Detection, 5.1.5: the Voronoi region of a corner, an edge or the
    face). A zero-area triangle gives NaN rows."""
    ab, ac, ap = b - a, c - a, p - a
    bp, cp = p - b, p - c

    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    d1, d2, d3, d4, d5, d6 = dot(ab, ap), dot(ac, ap), dot(ab, bp), dot(ac, bp), dot(ab, cp), dot(ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v, w = vb * denom, vc * denom  # inside the face: the point is a + v ab + w ac
        # the edges and corners as (v, w), the last assigned winning where regions meet (Ericson's order reversed)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        ac_w, ab_v = d2 / (d2 - d6), d1 / (d1 - d3)
        zero, one = np.zeros_like(v), np.ones_like(v)
        for mask, rv, rw in (
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), 1 - t, t),  # edge bc
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), zero, ac_w),  # edge ac
            ((d6 >= 0) & (d5 <= d6), zero, one),  # corner c
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), ab_v, zero),  # edge ab
            ((d3 >= 0) & (d4 <= d3), one, zero),  # corner b
            ((d1 <= 0) & (d2 <= 0), zero, zero),  # corner a
        ):
            v, w = np.where(mask, rv, v), np.where(mask, rw, w)
        out = a + ab * v[:, None] + ac * w[:, None]
        n = cross(ab, ac)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
    out[~np.isfinite(n).all(axis=1)] = np.nan
    return out, n


@dataclass(eq=False)
class Surface:
    """A triangle mesh with fast closest-point queries (Open3D's RaycastingScene).

    vertices: (V, 3) float64; faces: (F, 3) int64. Embree picks each query's triangle in float32 about the
    mesh's own centre (millimetre precision for scenes far from the origin); the point on it, its distance and
    normal are worked out in float64 (:meth:`closest_with_normals`).
    """

    vertices: np.ndarray
    faces: np.ndarray
    # a k-d tree of ``vertices`` and the longest edge, when known already (a scan's own tree, the
    # triangulation's edge lengths); else made on first use
    tree: cKDTree | None = field(default=None, repr=False)
    longest_edge: float | None = field(default=None, repr=False)
    offset: np.ndarray = field(init=False)
    _built: object = field(default=None, init=False, repr=False)
    _building: threading.Lock = field(default_factory=threading.Lock, init=False, repr=False)

    def __post_init__(self):
        self.offset = self.vertices.mean(0)

    @classmethod
    def from_scan(cls, scan: Scan) -> Surface:
        """The scan's stored faces, else its surface by its kind (module notes), over its points; with the
        scan's k-d tree (its points are the vertices)."""
        if scan.faces is not None and len(scan.faces):
            return cls(scan.points, scan.faces, tree=scan.tree)
        if scan.kind in SURFACE_OF_KIND:
            return SURFACE_OF_KIND[scan.kind](scan)
        faces, longest = _triangulate(scan)
        return cls(scan.points, faces, tree=scan.tree, longest_edge=longest)

    @property
    def _scene(self):
        """Open3D's RaycastingScene of the mesh, built once (by the first query, or by :meth:`warm`)."""
        if self._built is None:
            with self._building:  # one build, whichever thread asks first; the others wait for it
                if self._built is None:
                    self._built = self._build_scene()
        return self._built

    def _build_scene(self):
        import open3d as o3d

        scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor((self.vertices - self.offset).astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(self.faces.astype(np.int32))
        scene.add_triangles(mesh)
        # Embree builds its hierarchy at the first query (a 78k-triangle bunny scan: ~0.04 s): made here
        scene.compute_closest_points(o3d.core.Tensor(np.zeros((1, 3), dtype=np.float32)))
        return scene

    def warm(self) -> Surface:
        """Build the query structure now, on a thread of its own (Open3D lets go of the GIL meanwhile),
        while the caller works on; the first query waits for it. Returns the surface."""
        if self._built is None:
            threading.Thread(target=lambda: self._scene, name="surface-warm", daemon=True).start()
        return self

    def build(self) -> Surface:
        """Build the query structure now, on this thread (one made on a worker thread, to be queried later
        from another: the 0.2 s of a 250k-point Kinect frame's). Returns the surface."""
        _ = self._scene
        return self

    def closest(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (N, 3) float64 and squared distances (N,) for (N, 3) queries."""
        c, d2, _ = self.closest_with_normals(query)
        return c, d2

    @cached_property
    def _vertex_tree(self) -> cKDTree:
        return self.tree if self.tree is not None else kd_tree(self.vertices)

    @cached_property
    def reach(self) -> float:
        """The longest edge (units): every point of the surface lies within it of a vertex."""
        if self.longest_edge is not None:
            return self.longest_edge
        return float(edge_lengths(self.vertices, self.faces).max()) if len(self.faces) else 0.0

    def squared_distances_within(self, query: np.ndarray, radius: float) -> np.ndarray:
        """(N,) squared distances to the surface, exact where they are at most ``radius`` (units) and inf
        where they are surely more (:meth:`closest_within`)."""
        return self.closest_within(query, radius)[1]

    def closest_within(self, query: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`closest` for (N, 3) queries, exact where the distance is at most ``radius``
        (units): the closest points (N, 3), NaN, and squared distances (N,), inf, where the surface is surely
        farther. The exact query costs ~10 x more for a point a centimetre off the surface than for one on it
        (Open3D's RaycastingScene, measured on the bunny); a point whose nearest vertex lies farther than
        ``radius`` + :attr:`reach` is farther than ``radius`` from every triangle, and a k-d tree of the
        vertices says so for ~1 us. Each query's answer is the one :meth:`closest` gives it."""
        query = np.asarray(query, dtype=np.float64)
        closest = np.full(query.shape, np.nan)
        d2 = np.full(len(query), np.inf)
        near, _ = self._vertex_tree.query(query, distance_upper_bound=radius + self.reach,
                                          workers=-1 if len(query) > PARALLEL_QUERY else 1)
        near = np.isfinite(near)
        if near.any():
            closest[near], d2[near] = self.closest(query[near])
        return closest, d2

    def closest_with_normals(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`closest`, and the unit normals (N, 3) float64 of the triangles the closest points lie on.

        Embree (float32) picks each query's triangle; the point on it, its distance and the triangle's normal
        are worked out again in float64 (:func:`closest_on_triangles`), in blocks of ``CLOSEST_BLOCK`` queries.
        Embree's own float32 point differs in its last digits between processors (its kernels do), which moved E
        by 1e-4 and a golden trace's ICP leg by 7 iterations between two machines; worked out here, the point and
        its distance no longer do, but where several triangles are equally close (a query nearest an edge or a
        vertex they share) which one Embree returns, and so the normal, may still differ. Where Embree finds no
        triangle (a query at infinity, a mesh with no faces) or picks a zero-area one, its own answer stands."""
        import open3d as o3d

        q = np.asarray(query, dtype=np.float64) - self.offset
        ans = self._scene.compute_closest_points(o3d.core.Tensor(np.ascontiguousarray(q, dtype=np.float32)))
        ids = ans["primitive_ids"].numpy().astype(np.int64)
        found = ids < len(self.faces)  # Embree's INVALID_ID (2^32 - 1) where it found none
        closest = np.empty_like(q)
        normals = np.empty_like(q)
        for k in range(0, len(q), CLOSEST_BLOCK):
            rows = slice(k, k + CLOSEST_BLOCK)
            tri = np.take(self.faces, np.where(found[rows], ids[rows], 0), axis=0)
            a, b, c = (np.take(self.vertices, tri[:, m], axis=0) - self.offset for m in range(3))
            closest[rows], normals[rows] = closest_on_triangles(q[rows], a, b, c)
        own = ~found | ~np.isfinite(closest).all(axis=1)
        if own.any():
            closest[own] = ans["points"].numpy()[own].astype(np.float64)
            normals[own] = ans["primitive_normals"].numpy()[own].astype(np.float64)
        d = q - closest
        return closest + self.offset, np.einsum("ij,ij->i", d, d), normals

    def first_hit(self, origins: np.ndarray, directions: np.ndarray) -> np.ndarray:
        """(N,) distance along each unit ray to the first triangle hit (inf when none)."""
        import open3d as o3d

        rays = np.empty((len(directions), 6), dtype=np.float32)  # the float64 values, rounded once
        rays[:, :3] = origins - self.offset
        rays[:, 3:] = directions
        return self._scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)

    @property
    def n_triangles(self) -> int:
        return len(self.faces)
