"""Model construction (paper sections 1 and 2, Fig. 2): registered scans -> one surface model.

Where scans overlap we keep ONE of them, point by point: the better-sampled one, judged by
``quality = cos(viewing angle) / local point spacing`` (a surface seen face-on and densely gives
the most trustworthy samples; a grazing or sparse view the least). Points in no triangle of their
own scan's surface (spurious returns) are left out. A point is in the overlap when
another scan's surface lies within ``3 x`` the spacing of it. The kept points, with normals
facing their own sensors, are then meshed as one surface by screened Poisson reconstruction
(Open3D), which stitches the seams between scans without holes or double layers; the mesh is
trimmed back to where data was (no surface farther than 2 spacings from a kept point).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .noise import NORMAL_NEIGHBOURS
from .scan import Scan, kd_tree
from .surface import PARALLEL_QUERY, Surface, local_spacing, pca_normals
from .transforms import apply


@dataclass(frozen=True, eq=False)
class FusedModel:
    """vertices: (V, 3), faces: (F, 3) in the first scan's frame; kept: per scan, (N_k,) bool."""

    vertices: np.ndarray
    faces: np.ndarray
    kept: list
    points: np.ndarray  # (K, 3) the kept samples the mesh was built from
    owner: np.ndarray  # (K,) index of the scan each kept sample came from

    def __repr__(self) -> str:
        share = np.bincount(self.owner, minlength=len(self.kept))
        return f"FusedModel({len(self.vertices)} vertices, {len(self.faces)} triangles, samples per scan {share.tolist()})"


def _normals_towards(points: np.ndarray, viewpoint: np.ndarray, k: int = NORMAL_NEIGHBOURS,
                     tree: cKDTree | None = None, rows: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) PCA normals of (N, 3) points, each flipped to face ``viewpoint`` (``tree``: a k-d tree of ``points``
    built already, as core.scan.kd_tree builds it); only those of ``rows`` (M,) when given, (M, 3)."""
    tree = kd_tree(points) if tree is None else tree
    at = points if rows is None else points[rows]
    # the same answer on every core; below ~20k points starting the threads costs more than they save
    _, idx = tree.query(at, k=min(k, len(points)), workers=-1 if len(at) > PARALLEL_QUERY else 1)
    n = pca_normals(points, idx.reshape(len(at), -1))
    flip = np.einsum("ij,ij->i", n, viewpoint - at) < 0
    n[flip] *= -1
    return n


class FacingNormals:
    """A scan's per-point normals facing its sensor (those of :func:`sample_quality`), each worked out when first
    asked for and kept. A campaign asks for a few thousand a pair (the polish's matched points, an overlap's
    sample, a pair's information): all of a 250k-point Kinect frame's took 1.3 s, five times its registration's
    share of them. Each row is the whole array's bit for bit (a row's neighbours and its fit depend on it alone).
    Safe to ask from several threads."""

    def __init__(self, scan: Scan) -> None:
        self.scan = scan
        self._normals = np.zeros((len(scan.points), 3))
        self._done = np.zeros(len(scan.points), dtype=bool)
        self._lock = threading.Lock()

    def __getitem__(self, rows: np.ndarray | slice) -> np.ndarray:
        """The normals (..., 3) of ``rows``: an integer index array (any shape) or a slice of the scan's points."""
        if isinstance(rows, slice):
            rows = np.arange(len(self._done))[rows]
        rows = np.asarray(rows)
        if rows.dtype == bool:
            raise TypeError("FacingNormals takes row indices or a slice, not a mask")
        rows = rows.astype(np.int64, copy=False)
        with self._lock:
            need = np.unique(rows[~self._done[rows]])
            if len(need):
                self._normals[need] = _normals_towards(self.scan.points, self.scan.viewpoint, tree=self.scan.tree,
                                                       rows=need)
                self._done[need] = True
            return self._normals[rows]


def sample_quality(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    """Per-point normals (N, 3) facing the sensor and quality cos(view angle) / spacing (N,)."""
    n = _normals_towards(scan.points, scan.viewpoint, tree=scan.tree)
    rays = scan.viewpoint - scan.points
    cos = np.einsum("ij,ij->i", n, rays) / np.linalg.norm(rays, axis=1)
    return n, np.clip(cos, 0.0, 1.0) / np.maximum(local_spacing(scan.points, scan.tree), 1e-300)


def fuse(scans: list[Scan], poses: list[np.ndarray], surfaces: list[Surface] | None = None,
         depth: int = 9, qualities: list[tuple[np.ndarray, np.ndarray]] | None = None) -> FusedModel:
    """Fuse scans placed by ``poses`` (each T_first_scan, (4, 4)) into one triangle mesh. ``surfaces`` and
    ``qualities`` (:func:`sample_quality` per scan): when made already."""
    if len(scans) != len(poses) or not scans:
        raise InputError("fuse needs one pose per scan")
    import open3d as o3d

    surfaces = surfaces or [Surface.from_scan(s) for s in scans]
    world = [apply(T, s.points) for s, T in zip(scans, poses)]
    normals, quality = [], []
    if qualities is not None and len(qualities) != len(scans):
        raise InputError("fuse needs one sample quality per scan")
    for k, (s, T) in enumerate(zip(scans, poses)):
        n, q = sample_quality(s) if qualities is None else qualities[k]
        normals.append(n @ T[:3, :3].T)
        quality.append(q)
    spacing = float(np.median([s.spacing for s in scans]))
    tol = 3.0 * spacing
    kept = []
    for i, (pts, q) in enumerate(zip(world, quality)):
        # Only samples on their own scan's surface: a point in no triangle is a spurious return or an
        # isolated speck the triangulation already refused (section 2's surface model).
        keep = np.zeros(len(pts), bool)
        keep[surfaces[i].faces.ravel()] = True
        for j, (surf, T) in enumerate(zip(surfaces, poses)):
            if j == i:
                continue
            # Only the points still kept can lose, and only where scan j's surface is within tol (a point
            # away from it is ruled out by a k-d tree at a tenth of the exact query's cost): on a 10-stop
            # turntable most of a scan's points lie far from most other scans.
            todo = np.flatnonzero(keep)
            # Closest point on scan j's surface, in scan j's frame.
            c, d2 = surf.closest_within(apply(np.linalg.inv(T), pts[todo]), tol)
            covered = d2 < tol * tol
            if not covered.any():
                continue
            _, nearest = scans[j].tree.query(c[covered], workers=-1 if covered.sum() > PARALLEL_QUERY else 1)
            qj = quality[j][nearest]
            # The better-sampled scan wins; ties go to the earlier scan.
            here = todo[covered]
            lose = (qj > q[here]) | ((qj == q[here]) & (j < i))
            keep[here[lose]] = False
        kept.append(keep)
    points = np.concatenate([w[k] for w, k in zip(world, kept)])
    owner = np.concatenate([np.full(k.sum(), i) for i, k in enumerate(kept)])
    nrm = np.concatenate([n[k] for n, k in zip(normals, kept)])
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    pcd.normals = o3d.utility.Vector3dVector(nrm)
    # One thread: on several, Open3D's Poisson gives a slightly different mesh from run to run (the four bunny
    # scans: 240,144-240,147 triangles) and at times segfaults (upstream isl-org/Open3D issue 6828, open); on one, the
    # same mesh every run, in no more time here (those scans: 6.2-7.5 s of CPU against 7.6-8.4 s, load ~10).
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        mesh, _ = o3d.geometry.TriangleMesh.create_from_point_cloud_poisson(pcd, depth=depth, linear_fit=True,
                                                                            n_threads=1)
    verts = np.asarray(mesh.vertices)
    faces = np.asarray(mesh.triangles)
    d, _ = cKDTree(points).query(verts, workers=-1 if len(verts) > PARALLEL_QUERY else 1)
    near = d <= 2.0 * spacing
    faces = faces[np.all(near[faces], axis=1)]
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    return FusedModel(verts[used], remap[faces], kept, points, owner)


def double_layer_fraction(vertices: np.ndarray, faces: np.ndarray, gap: float) -> float:
    """Fraction of triangles with another sheet of the mesh within ``gap`` along their normal, either side.

    vertices: (V, 3); faces: (F, 3); gap in the vertices' units. A fused model of overlapping scans
    should be one sheet: two overlapping scan surfaces left on top of each other score about the
    overlap fraction, since they lie within the noise of each other.
    """
    import open3d as o3d

    if len(faces) == 0:
        return 0.0
    tri = vertices[faces]
    centre = tri.mean(1)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices.astype(np.float32), faces.astype(np.uint32))
    eps = 1e-3 * gap  # start just off the triangle so it does not hit itself
    hit = np.zeros(len(faces), bool)
    for sign in (1.0, -1.0):
        rays = np.hstack([centre + sign * eps * n, sign * n]).astype(np.float32)
        t = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        hit |= t < gap
    return float(hit.mean())
