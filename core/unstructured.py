"""The surface and the view of an unstructured scan (fused fragments, photogrammetry, merged clouds).

Such a cloud has no single viewpoint to triangulate from, so its local surface approximation (the paper's
"closest point to a local surface approximation") is a plane at each point: its normal fitted to the
neighbours within ``NORMAL_RADIUS_SPACINGS`` point spacings (at most ``NORMAL_MAX_NEIGHBOURS``). The closest
point to a query is its projection onto the tangent plane of its nearest cloud point (point-to-plane),
bounded to that point's patch: a disc of ``PATCH_SPACINGS`` times the point's local spacing, so that a query
beyond the cloud's rim or over a hole is not matched to a plane extended past the points.

Overlap is mutual closeness: a point of the other scan is inside this one's view when it lies within
``NEAR_SPACINGS`` point spacings of the cloud, and under an uncertain guess within that plus the move the
uncertainty allows.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .rows import first_in_cells
from .scan import Scan, ScanKind
from .surface import PARALLEL_QUERY, SPACING_NEIGHBOURS, SURFACE_OF_KIND, Surface, local_spacing, spreads
from .threads import cached_property

# Open3D's recipe fits normals to at most 30 neighbours within 2 voxels of a downsampled cloud (its points ~1
# voxel apart). A raw cloud's median nearest-neighbour distance (Scan.spacing) is half its mean spacing where the
# points fall at random (uniform on a plane: 0.47 / sqrt(density)), so the radius is 5 of them: ~17 neighbours on
# a plane sampled at random, the 30 nearest on a grid-like scan (~78 within the radius).
NORMAL_RADIUS_SPACINGS = 5.0
NORMAL_MAX_NEIGHBOURS = 30
FALLBACK_NEIGHBOURS = 8  # a rim point's plane: its nearest points, whatever their distance
# A neighbourhood whose second spread is under LINEAR_SPREAD of its first is a line, not a plane: a spinning
# LiDAR's ring (its points ~20 x closer along the ring than between rings), whose "normal" is any direction
# across it. Measured (2026-12-06, the share of such neighbourhoods): the shared LiDAR frames 0.72-0.77, thinned
# at 0.1-0.5 m 0.06-0.21, the simulated street and room 0.13-0.28; the Kinect frame, RGB-D fragments and the
# bunny 0.000-0.002. Its plane is fitted to its NORMAL_MAX_NEIGHBOURS nearest, whatever their distance, then
# to its LINE_NEIGHBOURS nearest. Read as unstructured (--scan-kind), the shared pair was trusted 0.67 deg /
# 50 cm off before (now "trust no"); thinned at 0.1 m it ends 0.15 deg / 2.4 cm off against 0.38 deg / 1.9 cm.
LINEAR_SPREAD = 0.01
LINE_NEIGHBOURS = 120
# A patch reaches 2 local spacings from its point: half the longest edge a triangulated surface keeps
# (core.surface.EDGE_FACTOR = 4), so a hole the single-view mesh would bridge the patches cover too.
PATCH_SPACINGS = 2.0
# Inside the view: within 3 spacings of a cloud point (a point that close lies on the surface up to the noise
# and the sampling: 3 nearest-neighbour distances cover a random sampling's holes, twice its mean spacing).
NEAR_SPACINGS = 3.0
# The coarse subset of a cloud's view (CloudView._within): one point per cube of 3 x NEAR_SPACINGS point spacings,
# used from COARSE_MIN_POINTS points on. The answer does not depend on the cube (it only decides how many points the
# whole tree is asked about); 1, 2 and 3 x near took 3.0, 2.0 and 1.9 s of CPU in the cuts of one TSDF pair from the
# identity (room 11, at load 3), every 64th point 2.5 s.
COARSE_CELL_NEARS = 3.0
COARSE_MIN_POINTS = 64
COARSE_EVERY = 64  # the coarse subset of the surface's vertices (TangentPlanes._nearest): every 64th


def fit_planes(points: np.ndarray, tree: cKDTree, spacing: float, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tangent planes at the points ``at`` ((M,) indices into (N, 3) ``points``, whose k-d tree is ``tree``):
    (M, 3) unit normals (sign arbitrary) and (M,) patch radii (units).

    A normal is the direction of least spread of the point's neighbours within ``NORMAL_RADIUS_SPACINGS`` x
    ``spacing``, at most ``NORMAL_MAX_NEIGHBOURS`` of them, itself included (Open3D's hybrid search in
    ``estimate_normals``: the same neighbourhoods and covariance, its normals to 2e-6 degrees on a 274k-point
    simulated fragment); a point with fewer than 3 there (at a rim) is fitted to its ``FALLBACK_NEIGHBOURS``
    nearest points instead (not asked whether they lie on a line); one whose neighbours lie on a line
    (:data:`LINEAR_SPREAD`) is fitted to more, farther ones. A patch is ``PATCH_SPACINGS`` x the mean distance to the point's
    ``SPACING_NEIGHBOURS`` nearest (core.surface.local_spacing), from the same query."""
    pts = np.asarray(points, dtype=np.float64)
    at = np.asarray(at, dtype=np.int64)
    k = min(max(NORMAL_MAX_NEIGHBOURS, SPACING_NEIGHBOURS + 1), len(pts))
    d, j = tree.query(pts[at], k=k, workers=-1 if len(at) > PARALLEL_QUERY else 1)
    d, j = d.reshape(len(at), k), j.reshape(len(at), k)
    patch = PATCH_SPACINGS * d[:, 1:min(SPACING_NEIGHBOURS + 1, k)].mean(axis=1)
    kn = min(NORMAL_MAX_NEIGHBOURS, k)
    within = d[:, :kn] <= NORMAL_RADIUS_SPACINGS * spacing
    count = within.sum(axis=1)
    normals = np.empty((len(at), 3))
    linear = np.zeros(len(at), dtype=bool)
    for lo in range(0, len(at), PLANE_CHUNK):
        w = within[lo:lo + PLANE_CHUNK, :, None]
        nb = pts[j[lo:lo + PLANE_CHUNK, :kn]]
        c = (nb - (nb * w).sum(axis=1, keepdims=True) / np.maximum(count[lo:lo + PLANE_CHUNK, None, None], 1)) * w
        vals, vecs = np.linalg.eigh(np.matmul(c.transpose(0, 2, 1), c))
        normals[lo:lo + PLANE_CHUNK] = vecs[:, :, 0]
        linear[lo:lo + PLANE_CHUNK] = vals[:, 1] < LINEAR_SPREAD * vals[:, 2]
    rim = np.flatnonzero(count < 3)
    if len(rim):
        normals[rim] = _plane(pts[j[rim, :min(FALLBACK_NEIGHBOURS, k)]])[0]
    # a line of points (a scan line, a ring) spans no plane: reach past it. Where the radius held all kn nearest
    # already, asking for them again gives the same line: those go straight to the wider reach.
    line = np.flatnonzero(linear & (count >= 3))
    for wide, ask in ((kn, count < kn), (LINE_NEIGHBOURS, np.ones(len(at), dtype=bool))):
        kw = min(wide, len(pts))
        for lo in range(0, len(line), PLANE_CHUNK // 4):  # (5k, 120, 3) float64 temporaries, 14 MB
            part = line[lo:lo + PLANE_CHUNK // 4]
            part = part[ask[part]]
            if not len(part):
                continue
            nb = tree.query(pts[at[part]], k=kw, workers=-1 if len(part) > PARALLEL_QUERY else 1)[1]
            n, still = _plane(pts[nb.reshape(len(part), kw)])
            normals[part[~still]] = n[~still]
            linear[part[~still]] = False
        line = line[linear[line]]
    return normals, patch


def _plane(nb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) unit normals of neighbourhoods (M, k, 3) and (M,) whether each is a line (LINEAR_SPREAD)."""
    normals, vals = spreads(nb)
    return normals, vals[:, 1] < LINEAR_SPREAD * vals[:, 2]


PLANE_CHUNK = 20_000  # planes fitted at once: (20k, 30, 3) float64 temporaries, 14 MB
# A query far from a cloud costs a k-d tree ~50 x more than one on it (the search visits every leaf the ball reaches
# on a 2-D manifold): the 38,880 points of a TSDF fragment's 720 rotation samples (core.candidates.shift_to_fit),
# median 0.68 m (45 spacings) off, took 1.33 s on one thread against 0.03 s for as many on the cloud. A BVH of one
# tiny triangle per point (Open3D's RaycastingScene) finds their nearest points in 0.21 s (the same point for all but
# 2 of them: float32 against float64, a near-tie). So a query farther than FAR_SPACINGS spacings from a coarse subset
# of the cloud (every COARSE_EVERY-th point) asks the BVH; a nearer one, the tree (its answer as before, bit for bit).
FAR_SPACINGS = 20.0


@dataclass(eq=False)
class TangentPlanes(Surface):
    """A surface of tangent planes over a cloud (module notes): ``vertices`` (N, 3) the points, ``spacing`` their
    median spacing (units: the normals' neighbourhood), ``normals`` (N, 3) unit, ``patch`` (N,) each plane's
    radius (units); ``faces`` is empty (no triangles). The closest-point queries answer as a mesh's do
    (:class:`core.surface.Surface`), so E, ICP and the search use it unchanged.

    A plane is fitted when a query first lands on its point (:func:`fit_planes`): a registration's queries
    land on a few thousand of a cloud's points, and fitting every plane of a 274k-point fragment took 2.5 s of
    CPU (Open3D's normals and the patches' spacing), most of a run's setup. ``normals`` and ``patch`` fit the
    rest when asked for whole."""

    spacing: float = 0.0
    _normals: np.ndarray = field(init=False, repr=False)
    _patch: np.ndarray = field(init=False, repr=False)
    _fitted: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        super().__post_init__()
        n = len(self.vertices)
        self._normals, self._patch, self._fitted = np.zeros((n, 3)), np.zeros(n), np.zeros(n, dtype=bool)

    @classmethod
    def from_scan(cls, scan: Scan) -> TangentPlanes:
        """Planes over ``scan``'s points, normals fitted at its spacing, patches from its local spacing."""
        if not scan.spacing > 0:
            raise InputError(f"{scan.name}: the points repeat one another (no spacing); no surface")
        return cls(scan.points, np.zeros((0, 3), dtype=np.int64), tree=scan.tree, spacing=scan.spacing)

    def _planes_at(self, j: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(normals, patch radii) of the planes at vertex indices ``j`` (any shape), fitting those not fitted yet
        (the same values whichever thread fits them first)."""
        new = np.unique(j[~self._fitted[j]])
        if len(new):
            self._normals[new], self._patch[new] = fit_planes(self.vertices, self._vertex_tree, self.spacing, new)
            self._fitted[new] = True
        return self._normals[j], self._patch[j]

    @property
    def normals(self) -> np.ndarray:
        """(N, 3) unit normals of every plane."""
        return self._planes_at(np.arange(len(self.vertices)))[0]

    @property
    def patch(self) -> np.ndarray:
        """(N,) every plane's radius (units)."""
        return self._planes_at(np.arange(len(self.vertices)))[1]

    @cached_property
    def reach(self) -> float:
        """The largest patch radius (units): every point of the surface lies within it of a vertex. From every
        point's spacing alone (0.2 s of CPU on 100k points; their normals too would take ~1.3 s)."""
        if not len(self.vertices):
            return 0.0
        if self._fitted.all():
            return float(self._patch.max())
        return float(PATCH_SPACINGS * local_spacing(self.vertices, self._vertex_tree).max())

    def warm(self) -> TangentPlanes:
        """Nothing to build ahead: the k-d tree is made already, each plane when a query first lands on it."""
        return self

    def build(self) -> TangentPlanes:
        """Nothing to build ahead (:meth:`warm`); ray casting (:meth:`first_hit`) builds its patches when asked."""
        return self

    def closest_with_normals(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) closest points, (N,) squared distances and (N, 3) the planes' normals for (N, 3) queries: the
        projection onto the nearest point's tangent plane, at most its patch radius from the point."""
        q = np.asarray(query, dtype=np.float64)
        j = self._nearest(q)
        n, r = self._planes_at(j)
        p = self.vertices[j]
        v = q - p
        t = v - np.einsum("ij,ij->i", v, n)[:, None] * n  # the in-plane offset
        length = np.linalg.norm(t, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            shrink = np.where(length > r, r / length, 1.0)
        c = p + t * shrink[:, None]
        d = q - c
        return c, np.einsum("ij,ij->i", d, d), n

    def _nearest(self, q: np.ndarray) -> np.ndarray:
        """(N,) index of the vertex nearest each of (N, 3) queries (module notes: FAR_SPACINGS)."""
        workers = -1 if len(q) > PARALLEL_QUERY else 1
        if len(q) <= PARALLEL_QUERY or len(self.vertices) <= COARSE_EVERY:
            return self._vertex_tree.query(q, workers=workers)[1]
        d, _ = self._coarse_tree.query(q, workers=workers)
        far = d > FAR_SPACINGS * self.spacing
        j = np.empty(len(q), dtype=np.int64)
        j[~far] = self._vertex_tree.query(q[~far], workers=workers)[1]
        if far.any():
            import open3d as o3d

            hits = self._point_scene.compute_closest_points(o3d.core.Tensor((q[far] - self.offset).astype(np.float32)))
            j[far] = hits["primitive_ids"].numpy()
        return j

    @cached_property
    def _coarse_tree(self) -> cKDTree:
        """A k-d tree of every COARSE_EVERY-th vertex (:meth:`_nearest`)."""
        return cKDTree(self.vertices[::COARSE_EVERY])

    @cached_property
    def _point_scene(self):
        """Open3D's RaycastingScene of one tiny triangle at each vertex, triangle k at vertex k (:meth:`_nearest`)."""
        import open3d as o3d

        v = self.vertices - self.offset
        e = 1e-3 * self.spacing
        corners = np.stack([v, v + [e, 0.0, 0.0], v + [0.0, e, 0.0]], axis=1).reshape(-1, 3)
        scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(corners.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(np.arange(len(corners), dtype=np.int32).reshape(-1, 3))
        scene.add_triangles(mesh)
        return scene

    def _build_scene(self):
        """For ray casting only (:meth:`first_hit`): each patch as a square of two triangles inscribed in its disc."""
        import open3d as o3d

        n = self.normals
        helper = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0.0, 0.0]]), np.array([[0.0, 1.0, 0.0]]))
        u = np.cross(n, helper)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        w = np.cross(n, u)
        p = self.vertices - self.offset
        r = self.patch[:, None]
        corners = np.stack([p + r * u, p + r * w, p - r * u, p - r * w], axis=1).reshape(-1, 3)
        base = 4 * np.arange(len(p))[:, None]
        faces = np.vstack([base + [0, 1, 2], base + [0, 2, 3]])
        scene = o3d.t.geometry.RaycastingScene()
        mesh = o3d.t.geometry.TriangleMesh()
        mesh.vertex.positions = o3d.core.Tensor(corners.astype(np.float32))
        mesh.triangle.indices = o3d.core.Tensor(faces.astype(np.int32))
        scene.add_triangles(mesh)
        return scene


@dataclass(frozen=True, eq=False)
class CloudView:
    """The overlap test of an unstructured scan, in its frame (module notes): apex (3,) its stated viewpoint
    (drawn only), ``tree`` a k-d tree of its points, ``near`` (units) the distance that counts as on the cloud,
    ``radius`` (units) the cloud's extent about ``centre`` (3,) (how far a rotation of the guess moves it)."""

    apex: np.ndarray
    tree: cKDTree = field(repr=False)
    near: float
    centre: np.ndarray
    radius: float

    @cached_property
    def _coarse(self) -> tuple[cKDTree, float]:
        """A k-d tree of one point of the cloud per cube of ``COARSE_CELL_NEARS`` x ``near`` (:meth:`_within`), and
        how far from it any point of the cloud can lie (units: the cube's diagonal)."""
        pts = self.tree.data
        cell = COARSE_CELL_NEARS * self.near
        first = first_in_cells(np.floor((pts - pts.min(0)) / cell).astype(np.int64))
        return cKDTree(pts[np.sort(first)]), cell * np.sqrt(3.0) * (1 + 1e-9)

    def _within(self, points: np.ndarray, distance: float) -> np.ndarray:
        """(N,) bool: (N, 3) points within ``distance`` (units) of a point of the cloud. Beyond ``near`` (a guess's
        margin: up to the whole cloud's size with no guess) a point within it of the coarse subset is within it of
        the cloud, one farther than that plus the subset's reach from every point of the subset is not, and the
        whole tree is asked only about the rest, a thin shell: a nearest-point search that may reach far costs
        the whole tree ~15 x more (100k points of a fragment, no guess: 1.05 s of CPU, 0.07 s through a subset).
        The same answer as the whole tree's, faster: measured on a TSDF fragment pair (room 11, from the
        identity) the whole tree was asked about 8-92k points a cut with every 64th point as the subset, 1.4-10k
        with a point a cube."""
        pts = np.asarray(points, dtype=np.float64)
        inside = np.zeros(len(pts), dtype=bool)
        rest = np.arange(len(pts))
        if distance > self.near > 0 and len(self.tree.data) > COARSE_MIN_POINTS:
            coarse, reach = self._coarse
            d, _ = coarse.query(pts, distance_upper_bound=distance + reach, workers=-1 if len(pts) > PARALLEL_QUERY else 1)
            inside = d < distance  # a point of the subset is a point of the cloud (strictly within: as the tree's bound)
            rest = np.flatnonzero(np.isfinite(d) & ~inside)
        if len(rest):
            d, _ = self.tree.query(pts[rest], distance_upper_bound=distance,
                                   workers=-1 if len(rest) > PARALLEL_QUERY else 1)
            inside[rest] = np.isfinite(d)
        return inside

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: (N, 3) points (this scan's frame) within ``near`` of a point of the cloud."""
        return self._within(points, self.near)

    def visible(self, surface, points: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool, all True: with no single sensor, nothing is hidden from it."""
        return np.ones(len(points), dtype=bool)

    def guessed(self, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: points within ``near`` plus ``margin`` (units: how far the guess may move them) of the
        cloud, whether ``inside`` or not."""
        if not margin >= 0:  # no margin to widen by (NaN, negative): the test itself, as asked
            return self._within(points, self.near + margin)
        out = inside.copy()  # those within ``near`` (inside) are within more: only the others are asked
        rest = np.flatnonzero(~inside)
        out[rest] = self._within(points[rest], self.near + margin)
        return out

    def widened(self, points: np.ndarray, angle: float, translation: float = 0.0) -> np.ndarray:
        """(N,) bool: points within ``near`` plus the move a rotation of ``angle`` radians (about the cloud's
        centre) and a shift of ``translation`` (units) allow."""
        if angle >= np.pi / 2:
            return np.ones(len(points), dtype=bool)
        return self._within(points, self.near + translation + 2 * self.radius * np.sin(angle / 2))

    def wireframe(self) -> np.ndarray:
        """(0, 2, 3): no pyramid to draw."""
        return np.zeros((0, 2, 3))

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        return self.apex[None].copy(), np.zeros((0, 3), dtype=np.int64)

    @property
    def far(self) -> float:
        return self.radius


def cloud_view(scan: Scan) -> CloudView:
    c = np.array(scan.centroid, dtype=np.float64)
    radius = float(np.sqrt(np.max(np.einsum("ij,ij->i", scan.points - c, scan.points - c))))
    view = CloudView(np.array(scan.viewpoint, dtype=np.float64), scan.tree, NEAR_SPACINGS * scan.spacing, c, radius)
    if len(scan.points) > COARSE_MIN_POINTS and view.near > 0:  # every cut asks for it (its margin): made with the view,
        _ = view._coarse  # so that a view made ahead (core.global_search: the whole scans') has it too
    return view


SURFACE_OF_KIND[ScanKind.UNSTRUCTURED] = TangentPlanes.from_scan  # core.surface's table of kinds
