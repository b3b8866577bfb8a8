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


def noise_floor(scan: Scan, rng: np.random.Generator, n_points: int = 500) -> float:
    """Robust E (squared units) of half of ``scan`` against a surface over the other half."""
    half = rng.random(len(scan.points)) < 0.5
    a, b = scan.points[half], scan.points[~half]
    if len(a) < 3 or len(b) < 3:
        return 0.0
    try:
        faces = triangulate(replace(scan, points=b, grid=None, faces=None))
    except InputError:
        return 0.0
    idx = rng.choice(len(a), min(n_points, len(a)), replace=False)
    return RobustError(a[idx], Surface(b, faces))(np.eye(4))


