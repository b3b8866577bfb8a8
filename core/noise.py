"""How low E can go: the error between two noisy samplings of one surface.

The paper sets the hybrid's threshold "by estimating the lowest expected error that one would
have for two scans in perfect registration" (section 2.3). We measure it on each scan itself:
split its points at random into two halves, triangulate one half, and evaluate the robust error
of the other half against it. Both halves carry the scanner's noise and sampling, so this is the
E of a perfect registration, in the scan's own units, with no knowledge of the scanner. A single-view scan's
half is triangulated from its viewpoint; a panorama's or an unstructured cloud's (no one viewpoint in front of
its points) is taken as local planes fitted to its points, as their surfaces are.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .robust_error import RobustError
from .scan import Scan, ScanKind
from .surface import Surface, normal_angles, pca_normals, triangulate, view_projection

# Above this many points the floor is measured on one patch of this many neighbouring points: the
# floor is a local property (noise and spacing), and triangulating half of a 2,000,000-point scan
# takes ~11 s of CPU (500k points: 5.2 s). Bunny scans (~40k points) and the scenes (< 10k) are
# measured whole, as before; on a 200k-point terrain scan, three seeds gave 0.056-0.068 whole and
# 0.054-0.061 on the patch.
PATCH_POINTS = 100_000
# Above this many points in the half, only the half's points within WINDOW_SPACINGS x the scan's point
# spacing of a query are triangulated, and only the faces well inside that window kept (a 40k-point bunny
# scan: ~4 x less work). Measured on the four bunny scans, 12 seeds each: the median ratio to the whole
# half's floor is 0.96-1.01 (4 spacings: 0.99-1.09, 6: 0.96-0.99), while the whole half's floor itself
# spreads +-20 % from seed to seed. Scans whose half holds fewer points (the simulated scenes) are whole.
WINDOW_MIN_POINTS = 5_000
WINDOW_SPACINGS = 5.0
WINDOW_MARGIN = 0.8  # a face is kept when its circumcircle lies within this share of the window's radius
# Normals are fitted to this many nearest points (as core.fuse does; CandidateConfig.normal_neighbours).
# The pair threshold's separation (benchmarks/threshold_evidence.py --neighbours K, the five bunny pairs
# and the bowl) hardly moves with it: the largest misfit at a truth / the nearest wrong minimum's are
# 2.9 / 5.3 with 8, 3.2 / 6.3 with 12 and 2.6 / 8.1 with 20 (core.threshold.FACTOR = 4.5 between them).
NORMAL_NEIGHBOURS = 12


def noise_floor(scan: Scan, rng: np.random.Generator, n_points: int = 500) -> float:
    """Robust E (squared units) of half of ``scan`` against a surface over the other half."""
    return _measure(scan, *_draw(scan, rng, n_points))


def noise_floors(scans: list[Scan], rng: np.random.Generator, n_points: int = 500) -> list[float]:
    """:func:`noise_floor` of each scan, the same bits as one after the other from ``rng``: the draws
    are made first, in that order, and the measures run side by side (Delaunay, the k-d trees and
    the closest-point queries release the GIL: two bunny scans 0.10-0.13 s instead of 0.16-0.19),
    unless this process may use one thread only (Open3D's thread limit, which app.distributed sets
    per task stream)."""
    return noise_floors_ahead(scans, rng, n_points, threads=len(scans))()


def noise_floors_ahead(scans: list[Scan], rng: np.random.Generator, n_points: int = 500,
                       threads: int = 1) -> Callable[[], list[float]]:
    """:func:`noise_floors` started now: the draws made at once from ``rng`` (the same bits as one after
    the other), the measures on ``threads`` threads of their own while the caller works on; call the
    result for the floors (it waits for them). Held to one thread (Open3D's thread limit, which
    app.distributed sets per task stream), the measures run when it is called, in the caller's thread."""
    import open3d as o3d

    draws = [_draw(scan, rng, n_points) for scan in scans]
    threads = min(threads, len(scans))
    if o3d.utility.get_max_threads() < 2 or threads < 1:
        return lambda: [_measure(scan, *d) for scan, d in zip(scans, draws)]
    pool = ThreadPoolExecutor(threads, thread_name_prefix="noise-floor")
    if threads == 1:
        futures = [pool.submit(lambda: [_measure(scan, *d) for scan, d in zip(scans, draws)])]
    else:
        futures = [pool.submit(_measure, scan, *d) for scan, d in zip(scans, draws)]
    pool.shutdown(wait=False)
    return lambda: futures[0].result() if threads == 1 else [f.result() for f in futures]


def normal_floor(scan: Scan, at: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> float:
    """How far apart, in degrees, the normals of two noisy samplings of one surface lie: the median
    angle between the normals fitted to the even- and the odd-ranked of the 2k points of ``scan``
    nearest each of the (Q, 3) points ``at`` (the scan's frame). Deterministic; 0 (not measured) for
    fewer than 2k points."""
    if len(scan.points) < 2 * k or not len(at):
        return 0.0
    _, idx = scan.tree.query(at, 2 * k)
    return float(np.median(normal_angles(pca_normals(scan.points, idx[:, 0::2]), pca_normals(scan.points, idx[:, 1::2]))))


def _draw(scan: Scan, rng: np.random.Generator, n_points: int) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray | None]:
    """Every random choice of a floor: (the points measured on, which of them are the queries' half)
    and the queries' indices into that half."""
    points = scan.points
    if len(points) > PATCH_POINTS:
        points = _patch(points, rng, PATCH_POINTS)
    half = rng.random(len(points)) < 0.5
    n_a = int(half.sum())
    pick = rng.choice(n_a, min(n_points, n_a), replace=False) if n_a >= 3 and len(points) - n_a >= 3 else None
    return (points, half), pick


def _measure(scan: Scan, drawn: tuple[np.ndarray, np.ndarray], pick: np.ndarray | None) -> float:
    points, half = drawn
    if pick is None:
        return 0.0
    a, b = points[half], points[~half]
    q = a[pick]
    if scan.kind is not ScanKind.SINGLE_VIEW:
        return _measure_planes(q, b)
    axis = b.mean(0) - scan.viewpoint  # the whole half's viewing direction, windowed or not
    radius = WINDOW_SPACINGS * scan.spacing
    windowed = len(b) > WINDOW_MIN_POINTS
    if windowed:
        b = _window(b, q, radius, None if points is not scan.points else (scan.tree, ~half))
    try:
        faces = triangulate(replace(scan, points=b, grid=None, faces=None), axis)
        if windowed:
            faces = _inside_window(b, faces, q, radius, scan.viewpoint, axis)
    except InputError:
        return 0.0
    if not len(faces):
        return 0.0
    return RobustError(q, Surface(b, faces))(np.eye(4))


def _measure_planes(q: np.ndarray, b: np.ndarray, k: int = NORMAL_NEIGHBOURS) -> float:
    """The robust E (core.robust_error: mean of min(d^2, 2 median d^2)) of the (Q, 3) queries against local planes
    of the other half ``b``: each query's distance to the plane fitted to its k nearest points of ``b``. A panorama
    or an unstructured cloud has no single viewpoint to triangulate from; a surface of local planes is what its
    closest points lie on (the paper: "the closest point to a local surface approximation")."""
    if len(b) < max(k, 3):
        return 0.0
    _, idx = cKDTree(b).query(q, min(k, len(b)))
    n = pca_normals(b, idx)
    d2 = np.einsum("ij,ij->i", q - b[idx].mean(1), n) ** 2
    return float(np.mean(np.minimum(d2, 2.0 * np.median(d2))))


def _inside_window(b: np.ndarray, faces: np.ndarray, q: np.ndarray, radius: float, viewpoint: np.ndarray,
                   axis: np.ndarray) -> np.ndarray:
    """The faces whose circumcircle (in the view projection) lies well inside the window round its
    nearest query: no point of the whole half can lie in such a circle, so the face is one of the
    whole half's Delaunay triangles too (a face at the window's rim may not be: the half's points
    beyond the rim would have cut it)."""
    uv, _ = view_projection(b, viewpoint, axis)
    uq, basis = view_projection(q, viewpoint, axis)
    depth = (q - viewpoint) @ basis[2]
    A, B, C = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    ab, ac = B - A, C - A
    d = 2.0 * (ab[:, 0] * ac[:, 1] - ab[:, 1] * ac[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        ux = (ac[:, 1] * (ab ** 2).sum(1) - ab[:, 1] * (ac ** 2).sum(1)) / d
        uy = (ab[:, 0] * (ac ** 2).sum(1) - ac[:, 0] * (ab ** 2).sum(1)) / d
    centre = A + np.c_[ux, uy]
    rho = np.hypot(ux, uy)
    dist, j = cKDTree(uq).query(np.where(np.isfinite(centre), centre, 0.0))
    return faces[np.isfinite(rho) & (dist + rho <= WINDOW_MARGIN * radius / depth[j])]


def _window(b: np.ndarray, q: np.ndarray, radius: float, whole: tuple | None = None) -> np.ndarray:
    """The points of ``b`` within ``radius`` of any query point of ``q``, in their order.

    Only the surface near the queries enters E. A Delaunay triangle whose circumcircle lies inside
    the window is a triangle of the whole half too, and so are the 4 nearest neighbours that set an
    edge's bound (core.surface) of a point well inside it. ``whole``: the scan's k-d tree and the
    half's mask in it, to query instead of building a tree for ``b``."""
    tree, in_b = whole if whole is not None else (cKDTree(b), None)  # (the scan's tree, b's mask in it)
    near = tree.query_ball_point(q, radius)  # a few hundred queries: threads would cost more than they save
    keep = np.zeros(tree.n, dtype=bool)
    keep[np.concatenate([np.asarray(n, dtype=np.int64) for n in near])] = True
    return b[keep[in_b]] if in_b is not None else b[keep]


def _patch(points: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) the points nearest one seeded point well inside the scan (time and memory linear in N)."""
    centre = points.mean(0)
    # start from a random point in the central half (by distance to the centroid), so the patch is
    # a full disc of the surface rather than a sliver at its edge
    # |p - c|^2 as |p|^2 - 2 p.c + |c|^2: (N,) temporaries only, no (N, 3) ones (memory linear and small)
    sq = np.einsum("ij,ij->i", points, points)
    d_c = sq - 2.0 * (points @ centre) + centre @ centre
    inner = np.flatnonzero(d_c <= np.median(d_c))
    seed_point = points[inner[rng.integers(len(inner))]]
    d = sq - 2.0 * (points @ seed_point) + seed_point @ seed_point
    return points[np.sort(np.argpartition(d, n - 1)[:n])]

