"""How low E can go: the error between two noisy samplings of one surface.

The paper sets the hybrid's threshold "by estimating the lowest expected error that one would
have for two scans in perfect registration" (section 2.3). We measure it on each scan itself:
split its points at random into two halves, triangulate one half, and evaluate the robust error
of the other half against it. Both halves carry the scanner's noise and sampling, so this is the
E of a perfect registration, in the scan's own units, with no knowledge of the scanner.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .error import RobustError
from .errors import InputError
from .scan import Scan
from .surface import Surface, triangulate

# Above this many points the floor is measured on one patch of this many neighbouring points: the
# floor is a local property (noise and spacing), and triangulating half of a 2,000,000-point scan
# takes ~11 s of CPU (500k points: 5.2 s). Bunny scans (~40k points) and the scenes (< 10k) are
# measured whole, as before; on a 200k-point terrain scan, three seeds gave 0.056-0.068 whole and
# 0.054-0.061 on the patch.
PATCH_POINTS = 100_000


def noise_floor(scan: Scan, rng: np.random.Generator, n_points: int = 500) -> float:
    """Robust E (squared units) of half of ``scan`` against a surface over the other half."""
    points = scan.points
    if len(points) > PATCH_POINTS:
        points = _patch(points, rng, PATCH_POINTS)
    half = rng.random(len(points)) < 0.5
    a, b = points[half], points[~half]
    if len(a) < 3 or len(b) < 3:
        return 0.0
    try:
        faces = triangulate(replace(scan, points=b, grid=None, faces=None))
    except InputError:
        return 0.0
    idx = rng.choice(len(a), min(n_points, len(a)), replace=False)
    return RobustError(a[idx], Surface(b, faces))(np.eye(4))


def _patch(points: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 3) the points nearest one seeded point well inside the scan (time and memory linear in N)."""
    centre = points.mean(0)
    # start from a random point in the central half (by distance to the centroid), so the patch is
    # a full disc of the surface rather than a sliver at its edge
    d_c = np.einsum("ij,ij->i", points - centre, points - centre)
    inner = np.flatnonzero(d_c <= np.median(d_c))
    seed_point = points[inner[rng.integers(len(inner))]]
    d = np.einsum("ij,ij->i", points - seed_point, points - seed_point)
    return points[np.sort(np.argpartition(d, n - 1)[:n])]

