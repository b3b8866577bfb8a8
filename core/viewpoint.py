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
from .scan import RangeGrid

STANDOFF = 5.0


def grid_normals(points: np.ndarray, grid: RangeGrid) -> np.ndarray:
    """Area-weighted normals (M, 3) of the grid's cells, pointing towards the sensor."""
    idx = grid.index
    a, b, r = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1]
    ok = (a >= 0) & (b >= 0) & (r >= 0)
    return np.cross(points[b[ok]] - points[a[ok]], points[r[ok]] - points[a[ok]])


def face_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted normals (M, 3) of triangles (right-hand winding)."""
    p = points[faces]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


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
        lengths = np.linalg.norm(normals, axis=1)
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
    dist = np.linalg.norm(rays, axis=1)
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
    area = np.linalg.norm(normals, axis=1)
    front = float(area[facing > 0].sum() / max(area.sum(), 1e-300))
    if front < 0.5:
        raise InputError(
            f"{what}: the viewpoint {np.round(viewpoint, 4).tolist()} is on the wrong side of the surface "
            f"(it faces only {front:.0%} of it); give the sensor position on the scanned side")
