"""A range grid recovered from bare points that lie on a depth camera's pixel lattice.

An RGB-D frame written as bare points (Open3D's ``create_from_rgbd_image`` and ``create_from_depth_image``,
a PLY or an unorganised PCD) has lost its ``WIDTH x HEIGHT``, but not its pixels: a pinhole camera puts pixel
(row, col) at ``x / z = (col - cx) / fx`` and ``y / z = (row - cy) / fy``, so seen from the camera the points
lie on a lattice of two pitches. Where they all do, one point a cell, the grid is recovered and the frame is
triangulated and thinned as the organised frame is (core.surface: the grid's faces, in O(N)) instead of by a
Delaunay triangulation of its projection (the shared Kinect frame capture0002 as bare points: 2.6 s to a pose
against 1.5 s organised, at load ~2).

A cloud thinned on voxels, fused from several frames or sampled by a scanner that is no pinhole camera (a
spinning or solid-state LiDAR, a structured-light object scanner) leaves the lattice and keeps its points.
"""

from __future__ import annotations

import numpy as np

# A point lies on the lattice when its image coordinate is within this share of a pitch of a lattice line, once
# the lattice is fitted. Measured (2026-12-06) on the shared Kinect frames written as float32 bare points: at most
# 0.0004 of a pitch after the fit (0.03 with the pitch taken from the median gap alone); a frame thinned at 1 cm
# or a fused fragment: a median point 0.25 of a pitch off, as for points at random.
ON_LATTICE = 0.1
# Gaps between image coordinates smaller than this share of the largest one are float32 rounding within one
# column of pixels (x / z of float32 values: ~1e-7 of it), not a column apart (a 4000-pixel-wide image: 2.5e-4).
ROUNDING = 1e-6
# A grid is kept only where its points fill this share of its cells at least (a Kinect frame: 0.8; a frame with
# its far wall out of range keeps more than half): a bound on the grid's memory, 10 cells a point.
MIN_FILL = 0.1
# ... and where this share of its filled cells has its right and lower neighbours filled too, so that the grid's
# faces cover the frame: the shared Kinect frames 0.986-0.989; the same frames thinned to every 2nd or 3rd point
# (Open3D's uniform_down_sample), which stay on the lattice, 0.0, and at random to half, 0.25. Those keep their
# points and are triangulated as bare points (a sparse grid had left no face, or a tenth of them).
MIN_ADJACENT = 0.5
MIN_POINTS = 100


def pixel_grid(points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray | None:
    """(rows, cols) int64 index into (N, 3) ``points`` (-1: an empty cell), rows and columns in the order of
    the image coordinates along the frame's axes, when the points, seen from ``viewpoint`` (3,) along the frame
    axis they lie furthest along, lie one to a cell on a pixel lattice (module notes); else None."""
    rel = np.asarray(points, dtype=np.float64) - viewpoint
    if len(rel) < MIN_POINTS:
        return None
    r = np.linalg.norm(rel, axis=1)
    if not np.all(r > 0):
        return None
    axis = int(np.argmax(np.abs((rel / r[:, None]).mean(0))))
    depth = rel[:, axis]
    if not (np.all(depth > 0) or np.all(depth < 0)):
        return None
    across = [a for a in range(3) if a != axis]
    index = []
    for a in across:
        k = _lattice(rel[:, a] / depth)
        if k is None:
            return None
        index.append(k)
    col, row = index
    rows, cols = int(row.max()) + 1, int(col.max()) + 1
    if len(rel) < MIN_FILL * rows * cols:
        return None
    grid = np.full((rows, cols), -1, dtype=np.int64)
    grid[row, col] = np.arange(len(rel))
    filled = grid >= 0
    if np.count_nonzero(filled) != len(rel):  # two points in one cell: no depth image's
        return None
    corner = filled[:-1, :-1]
    if np.count_nonzero(corner & filled[:-1, 1:] & filled[1:, :-1]) < MIN_ADJACENT * max(np.count_nonzero(corner), 1):
        return None
    return grid


def _lattice(a: np.ndarray) -> np.ndarray | None:
    """(N,) int64 lattice indices (0 at the smallest) of image coordinates ``a`` (N,) that lie on lines one
    pitch apart, the pitch and offset fitted by least squares; None where they do not."""
    values = np.unique(a)
    gaps = np.diff(values)
    gaps = gaps[gaps > ROUNDING * np.abs(values).max()]
    if len(gaps) < 2:
        return None
    pitch = float(np.median(gaps))
    k = np.round((a - values[0]) / pitch)
    design = np.c_[np.ones_like(k), k]
    (offset, pitch), *_ = np.linalg.lstsq(design, a, rcond=None)
    if not pitch > 0:
        return None
    exact = (a - offset) / pitch
    k = np.round(exact)
    if np.abs(exact - k).max() > ON_LATTICE:
        return None
    k -= k.min()
    return k.astype(np.int64)
