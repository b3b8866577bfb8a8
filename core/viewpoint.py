"""Where the sensor stood: estimate a viewpoint that sees the scanned side, and check a given one.

A single sheet of points looks the same from both sides, so the side needs a cue:
1. a range grid: ``cross(d/dcol, d/drow)`` points towards the sensor (Stanford's convention);
2. a stored mesh: its faces' normals point to the outside, where a sensor stands;
3. bare points: the least-spread direction of the points, on the side where the sheet bulges
   (objects are scanned from outside). This is a guess: override it when it is wrong.
The estimate stands back from the centroid by 5 times the scan's size (about 1 m for the bunny).
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .rows import cross, norms
from .scan import RangeGrid

STANDOFF = 5.0


def grid_normals(points: np.ndarray, grid: RangeGrid) -> np.ndarray:
    """Area-weighted normals (M, 3) of the grid's cells, pointing towards the sensor."""
    idx = grid.index
    a, b, r = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1]
    ok = (a >= 0) & (b >= 0) & (r >= 0)
    return cross(points[b[ok]] - points[a[ok]], points[r[ok]] - points[a[ok]])


def face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted normals (M, 3) of triangles (right-hand winding)."""
    p = points[faces]
    return cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def _oriented_normals(points, grid, faces):
    if grid is not None:
        n = grid_normals(points, grid)
        if len(n):
            return n
    if faces is not None and len(faces):
        return face_normals(points, faces)
    return None


def estimate_viewpoint(points: np.ndarray, grid: RangeGrid | None = None, faces: np.ndarray | None = None) -> np.ndarray:
    """A (3,) viewpoint that sees the scanned side of (N, 3) points (see the module notes)."""
    c = points.mean(0)
    size = float(np.linalg.norm(points.max(0) - points.min(0))) or 1.0
    normals = _oriented_normals(points, grid, faces)
    unit = None
    if normals is not None:
        lengths = norms(normals)
        unit = normals[lengths > 0] / lengths[lengths > 0, None]
    if unit is not None and len(unit) and np.linalg.norm(np.median(unit, axis=0)) > 0:
        # The median facing, not the mean: grazing cells at the silhouette should not tilt it.
        direction = np.median(unit, axis=0)
    else:
        sub = points[:: max(1, len(points) // 20000)] - c
        _, _, vt = np.linalg.svd(sub, full_matrices=False)
        direction = vt[2]
        # Fit height h = q(u, v) over the best plane; a cap (negative curvature) bulges to +direction.
        u, v, h = sub @ vt[0], sub @ vt[1], sub @ vt[2]
        A = np.c_[u * u, v * v, u * v, u, v, np.ones_like(u)]
        coef, *_ = np.linalg.lstsq(A, h, rcond=None)
        if coef[0] + coef[1] > 0:
            direction = -direction
    direction = direction / np.linalg.norm(direction)
    return c + STANDOFF * size * direction


def check_viewpoint(points: np.ndarray, viewpoint: np.ndarray, grid: RangeGrid | None,
                    faces: np.ndarray | None, what: str) -> None:
    """Raise InputError when ``viewpoint`` cannot have seen the scan (inside it, edge-on, or behind)."""
    rays = points - viewpoint
    dist = norms(rays)
    if np.min(dist) == 0 and np.mean(dist == 0) > 0.5:
        raise InputError(f"{what}: the viewpoint {viewpoint.tolist()} sits on the points")
    normals = _oriented_normals(points, grid, faces)
    if normals is None:
        return
    if grid is not None:
        a = grid.index[:-1, :-1]
        b, r = grid.index[:-1, 1:], grid.index[1:, :-1]
        at = points[a[(a >= 0) & (b >= 0) & (r >= 0)]]
    else:
        at = points[faces[:, 0]]
    facing = np.einsum("ij,ij->i", normals, viewpoint - at)
    area = norms(normals)
    front = float(area[facing > 0].sum() / max(area.sum(), 1e-300))
    if front < 0.5:
        raise InputError(
            f"{what}: the viewpoint {np.round(viewpoint, 4).tolist()} is on the wrong side of the surface "
            f"(it faces only {front:.0%} of it); give the sensor position on the scanned side")


# ---- how the points lie about a sensor position (core.assemble decides the scan kind from these) ----

# Points more than VIEW_HALF_ANGLE off the mean viewing direction, as a share, above which they lie all
# around the sensor (a panorama). A single view has none (a camera's half field of view is under 60
# degrees: the Kinect frames 35, the simulated scenes 35, the bunny about its frame's origin 62); the
# spinning-LiDAR frame of ../shared/data/lidar has 26 % beyond 90 degrees, and still covers 360 degrees
# of azimuth when its frame's origin is 3 m above the sensor (every point then below it).
AROUND_SHARE = 0.05
VIEW_HALF_ANGLE = 75.0
# A sensor at the frame's origin is assumed only when the points lie within this many scan sizes of it
# (the bunny at 1 m is ~4 sizes away; a georeferenced cloud, kilometres from its origin, is not a view from it).
CONVENTION_REACH = 10.0
# A range spread (90th over 10th percentile of the distances) below which the spacing says nothing of the
# range: a sensor looking at one thing (the bunny's points 1 m from their scanner; the Kinect frames, a
# scene 1.5-3 m away, spread 1.41 and still give a slope of 1.0).
RANGE_SPREAD = 1.2
# The slope of log(spacing) against log(range) above which the points were sampled by a sensor there:
# a fixed angular step spaces returns in proportion to their range. Measured: the LiDAR frames 1.05,
# the Kinect frames 1.01 (about their origins); the bunny scans about their frame's origin -0.09..0.08;
# the LiDAR frame about a point 10 m or 30 m off its sensor 0.46 and 0.53, the Kinect frame about a
# point 1 m behind its camera 0.58.
SENSOR_SLOPE = 0.7
# A stored viewpoint is set aside for the frame's origin (core.assemble) only where the origin explains the spacing
# clearly better: the correlation of log(spacing) with log(range) is higher from the origin by at least this much.
# Measured (2026-12-06) from the frames' own origin: the shared LiDAR frames 0.885-0.888, the Kinect frame capture0002
# 0.756; from 20 random points 5-100 m off (the 95th percentile): the LiDAR frames at most 0.72 (10 m), the Kinect
# frame 0.64 (5 m), 0.57-0.60 from 10 m on. (The slope alone, asked from the viewpoint, came out sensor-like from
# 12-18 of 40 such points 10-40 m off, by chance over a range spread just above RANGE_SPREAD.) Checked on the
# simulated street and room panoramas (two seeds each, not used to set it): from the origin 0.84-0.94, and 158 of 160
# random points 5-100 m off set aside; with the frame's origin moved 0.3-3 m off the sensor and the VIEWPOINT at the
# sensor (a mount's offset, stated rightly), none of 24 set aside.
CLOSER_FIT = 0.15
# Layers: a single view holds one surface along each ray, so points next to each other as seen from the
# viewpoint lie at about one range, but at its occluding contours. The share of points with a neighbour
# (of 8, in the view) more than 10 spacings nearer or farther, measured from the estimated viewpoint:
# single views 0.05-0.27 (the bunny's points alone 0.05, bun090 with its ears 0.27, the Kinect frame
# 0.07, the simulated corner and ribbed scenes 0.20), two bunny views fused 0.09; the four bunny views
# fused all around 0.45, the LiDAR frame seen from outside 0.73.
LAYERED_SHARE = 0.35
LAYER_NEIGHBOURS = 8
LAYER_GAP = 10.0  # spacings
# Grazing: a sensor samples a surface seen edge-on sparsely or not at all, so in one view few points have a
# normal (fitted to their GRAZING_NEIGHBOURS nearest) more than GRAZING_DEG off their ray. The share of such
# points, measured on 2026-12-06 from the estimated viewpoint: single views 0.004-0.156 (the simulated corner,
# ribbed, wing and bowl scans 0.004-0.042; the bunny scans 0.021-0.117, thinned at 2 mm 0.055-0.156; the Kinect
# frame 0.033, thinned at 1-5 cm 0.071-0.093); scenes about their sensor thinned on voxels, which loses the
# range-grown spacing that marks a sensor there (the shared LiDAR frame at 0.1-1 m 0.30-0.57, the simulated
# street and room at 0.1-0.5 m 0.43-0.76: at 0.35-1 m one layer deep as seen from ~360 m below, so "one view"
# before, and the identity trusted 36-49 cm off); RGB-D fragments fused from 5 and
# 15 frames 0.23 and 0.28 (either reading registers them). The bound lies between the single views' highest and
# the scenes' lowest; left out one at a time (the bound then the geometric mean of the rest's two), every object,
# Kinect and LiDAR case keeps its side (without the thinned bun090, 0.19; without the LiDAR at 1 m, 0.26). Not
# asked where the spacing says a sensor stood (core.assemble._about_origin): a LiDAR sees its ground edge-on (the
# shared frame 0.69 from its sensor; its rings' line neighbourhoods, whose normals are any direction across the
# ring, add to that), and a view of it cropped to the front is still one view. The normals here are the nearest
# points' plane, line or not: the thinned frames that set the bound hold 5-21 % lines, the raw ones 72-77 %.
GRAZING_SHARE = 0.22
GRAZING_DEG = 80.0
GRAZING_NEIGHBOURS = 12
GRAZING_SAMPLE = 5_000
SAMPLE = 5000  # points the spacing and incidence tests are measured on


def sample(points: np.ndarray, n: int = SAMPLE) -> np.ndarray:
    """Indices of an even spread of at most ``n`` of the (N, 3) points (deterministic)."""
    return np.linspace(0, len(points) - 1, min(len(points), n)).astype(np.int64)


def share_around(points: np.ndarray, viewpoint: np.ndarray) -> float:
    """The share of (N, 3) points more than :data:`VIEW_HALF_ANGLE` degrees off the mean viewing
    direction from ``viewpoint`` (0 for a single view; a large share for a panorama)."""
    rays = points - viewpoint
    r = norms(rays)
    seen = r > 0
    if not seen.any():
        return 0.0
    unit = rays[seen] / r[seen, None]
    mean = unit.mean(0)
    if not np.linalg.norm(mean) > 1e-9:
        return 1.0
    return float(np.mean(unit @ (mean / np.linalg.norm(mean)) < np.cos(np.radians(VIEW_HALF_ANGLE))))


def surrounds(points: np.ndarray, viewpoint: np.ndarray) -> bool:
    """Whether the points lie all around ``viewpoint`` (see :data:`AROUND_SHARE`)."""
    return share_around(points, viewpoint) > AROUND_SHARE


def range_correlation(points: np.ndarray, spacing: np.ndarray, at: np.ndarray) -> float:
    """The correlation of log(spacing) with log(range from ``at``) over points (n, 3) and their nearest-neighbour
    spacings (n,): near 1 where a sensor at ``at`` sampled them (see :data:`CLOSER_FIT`); 0 when unmeasurable."""
    r = norms(points - at)
    ok = (r > 0) & (spacing > 0)
    if ok.sum() < 10:
        return 0.0
    x, y = np.log(r[ok]), np.log(spacing[ok])
    if not (np.ptp(x) > 0 and np.ptp(y) > 0):
        return 0.0
    return float(np.corrcoef(x, y)[0, 1])


def sensor_slope(points: np.ndarray, spacing: np.ndarray, at: np.ndarray) -> tuple[float, float]:
    """(slope, spread) of log(spacing) against log(range from ``at``) over points (n, 3) and their
    nearest-neighbour spacings (n,): slope ~1 where a sensor at ``at`` sampled them; spread: the 90th
    over the 10th percentile of the ranges."""
    r = norms(points - at)
    ok = (r > 0) & (spacing > 0)
    if ok.sum() < 10:
        return 0.0, 1.0
    lo, hi = np.percentile(r[ok], [10, 90])
    spread = float(hi / lo) if lo > 0 else float("inf")
    if not spread > 1.0:
        return 0.0, 1.0
    return float(np.polyfit(np.log(r[ok]), np.log(spacing[ok]), 1)[0]), spread


def grazing_share(points: np.ndarray, tree, viewpoint: np.ndarray) -> float:
    """The share of a sample of (N, 3) points (``tree`` their k-d tree) whose normal lies more than
    :data:`GRAZING_DEG` off their ray from ``viewpoint`` (see :data:`GRAZING_SHARE`)."""
    from .surface import pca_normals

    idx = sample(points, GRAZING_SAMPLE)
    k = min(GRAZING_NEIGHBOURS, len(points))
    normals = pca_normals(points, tree.query(points[idx], k)[1].reshape(len(idx), k))
    rays = points[idx] - viewpoint
    r = norms(rays)
    seen = r > 0
    cos = np.abs(np.einsum("ij,ij->i", normals[seen], rays[seen])) / r[seen]
    return float(np.mean(cos < np.cos(np.radians(GRAZING_DEG)))) if seen.any() else 1.0


def layered_share(points: np.ndarray, tree, viewpoint: np.ndarray) -> float:
    """The share of a sample of (N, 3) points (``tree`` their k-d tree) with a neighbour, as seen from
    ``viewpoint``, at a range more than :data:`LAYER_GAP` spacings apart (see :data:`LAYERED_SHARE`);
    1.0 when some points lie beside or behind the viewpoint (no single view then)."""
    from scipy.spatial import cKDTree

    rays = points - viewpoint
    r = norms(rays)
    if not np.all(r > 0):
        return 1.0
    unit = rays / r[:, None]
    axis = unit.mean(0)
    if not np.linalg.norm(axis) > 1e-9:
        return 1.0
    axis /= np.linalg.norm(axis)
    depth = unit @ axis
    if depth.min() <= 1e-9:
        return 1.0
    u = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    seen = np.c_[unit @ u, unit @ v] / depth[:, None]
    idx = sample(points)
    d, _ = tree.query(points[idx], k=2)
    spacing = float(np.median(d[:, 1]))
    _, nb = cKDTree(seen).query(seen[idx], k=min(LAYER_NEIGHBOURS, len(points)))
    return float(np.mean(np.any(np.abs(r[nb] - r[idx, None]) > LAYER_GAP * spacing, axis=1)))
