"""The surface and the view of an unstructured scan (fused fragments, photogrammetry, merged clouds).

Such a cloud has no single viewpoint to triangulate from, so its local surface approximation (the paper's
"closest point to a local surface approximation") is a plane at each point: Open3D's normals, fitted to the
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
from functools import cached_property

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .scan import Scan, ScanKind
from .surface import PARALLEL_QUERY, SURFACE_OF_KIND, Surface, local_spacing, pca_normals

# Open3D's recipe fits normals to at most 30 neighbours within 2 voxels of a downsampled cloud (its points ~1
# voxel apart). A raw cloud's median nearest-neighbour distance (Scan.spacing) is half its mean spacing where the
# points fall at random (uniform on a plane: 0.47 / sqrt(density)), so the radius is 5 of them: ~17 neighbours on
# a plane sampled at random, the 30 nearest on a grid-like scan (~78 within the radius).
NORMAL_RADIUS_SPACINGS = 5.0
NORMAL_MAX_NEIGHBOURS = 30
FALLBACK_NEIGHBOURS = 8  # a rim point's plane: its nearest points, whatever their distance
# A patch reaches 2 local spacings from its point: half the longest edge a triangulated surface keeps
# (core.surface.EDGE_FACTOR = 4), so a hole the single-view mesh would bridge the patches cover too.
PATCH_SPACINGS = 2.0
# Inside the view: within 3 spacings of a cloud point (a point that close lies on the surface up to the noise
# and the sampling: 3 nearest-neighbour distances cover a random sampling's holes, twice its mean spacing).
NEAR_SPACINGS = 3.0


def point_normals(points: np.ndarray, spacing: float, tree: cKDTree | None = None) -> np.ndarray:
    """(N, 3) unit normals (sign arbitrary) of (N, 3) points: Open3D's, from a hybrid KD search within
    ``NORMAL_RADIUS_SPACINGS`` x ``spacing`` (units), at most ``NORMAL_MAX_NEIGHBOURS`` neighbours (``tree``:
    a k-d tree of the points, for the few refitted)."""
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.asarray(points, dtype=np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=NORMAL_RADIUS_SPACINGS * spacing,
                                                              max_nn=NORMAL_MAX_NEIGHBOURS))
    n = np.array(pcd.normals)
    # Open3D leaves (0, 0, 1) where fewer than 3 points (itself included) lie within the radius (a point at a
    # rim): those are fitted to their nearest points instead. An exact +-z normal is often real (a depth
    # camera's quantised ranges make flat steps: 29 % of a Kinect frame's normals), so it is refitted only
    # where the neighbours say so.
    pts = np.asarray(points, dtype=np.float64)
    tree = cKDTree(pts) if tree is None else tree
    z = np.flatnonzero(~np.all(np.isfinite(n), axis=1) | (np.abs(n[:, 2]) == 1.0))
    if len(z) and len(pts) >= 3:
        d, _ = tree.query(pts[z], 3, distance_upper_bound=NORMAL_RADIUS_SPACINGS * spacing)
        rim = z[~np.isfinite(d[:, 2])]
        if len(rim):
            k = min(FALLBACK_NEIGHBOURS, len(pts))
            n[rim] = pca_normals(pts, tree.query(pts[rim], k)[1].reshape(-1, k))
    return n


@dataclass(eq=False)
class TangentPlanes(Surface):
    """A surface of tangent planes over a cloud (module notes): ``vertices`` (N, 3) the points, ``normals``
    (N, 3) unit, ``patch`` (N,) each plane's radius (units); ``faces`` is empty (no triangles). The closest-point
    queries answer as a mesh's do (:class:`core.surface.Surface`), so E, ICP and the search use it unchanged."""

    normals: np.ndarray | None = field(default=None, repr=False)
    patch: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def from_scan(cls, scan: Scan) -> TangentPlanes:
        """Planes over ``scan``'s points, normals fitted at its spacing, patches from its local spacing."""
        if not scan.spacing > 0:
            raise InputError(f"{scan.name}: the points repeat one another (no spacing); no surface")
        normals = point_normals(scan.points, scan.spacing, scan.tree)
        patch = PATCH_SPACINGS * local_spacing(scan.points, scan.tree)
        return cls(scan.points, np.zeros((0, 3), dtype=np.int64), tree=scan.tree, normals=normals, patch=patch)

    @cached_property
    def reach(self) -> float:
        """The largest patch radius (units): every point of the surface lies within it of a vertex."""
        return float(self.patch.max()) if len(self.patch) else 0.0

    def warm(self) -> TangentPlanes:
        """Nothing to build: the k-d tree and the planes are made already."""
        return self

    def closest_with_normals(self, query: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, 3) closest points, (N,) squared distances and (N, 3) the planes' normals for (N, 3) queries: the
        projection onto the nearest point's tangent plane, at most its patch radius from the point."""
        q = np.asarray(query, dtype=np.float64)
        _, j = self._vertex_tree.query(q, workers=-1 if len(q) > PARALLEL_QUERY else 1)
        p, n = self.vertices[j], self.normals[j]
        v = q - p
        t = v - np.einsum("ij,ij->i", v, n)[:, None] * n  # the in-plane offset
        length = np.linalg.norm(t, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            shrink = np.where(length > self.patch[j], self.patch[j] / length, 1.0)
        c = p + t * shrink[:, None]
        d = q - c
        return c, np.einsum("ij,ij->i", d, d), n.copy()

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

    def _within(self, points: np.ndarray, distance: float) -> np.ndarray:
        pts = np.asarray(points, dtype=np.float64)
        d, _ = self.tree.query(pts, distance_upper_bound=distance, workers=-1 if len(pts) > PARALLEL_QUERY else 1)
        return np.isfinite(d)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: (N, 3) points (this scan's frame) within ``near`` of a point of the cloud."""
        return self._within(points, self.near)

    def visible(self, surface, points: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool, all True: with no single sensor, nothing is hidden from it."""
        return np.ones(len(points), dtype=bool)

    def guessed(self, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: points within ``near`` plus ``margin`` (units: how far the guess may move them) of the
        cloud, whether ``inside`` or not."""
        return self._within(points, self.near + margin)

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
    return CloudView(np.array(scan.viewpoint, dtype=np.float64), scan.tree, NEAR_SPACINGS * scan.spacing, c, radius)


SURFACE_OF_KIND[ScanKind.UNSTRUCTURED] = TangentPlanes.from_scan  # core.surface's table of kinds
