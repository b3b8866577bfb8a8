"""Weighted absolute orientation: Horn's closed-form unit-quaternion solution (Horn 1987, paper [7]).

Finds the rigid T minimising sum_i w_i |R x_i + t - y_i|^2. With weights the centroids and the
cross-covariance are weighted (Horn, section 2.D), which lets ICP walk the same robust error
surface as annealing (paper section 2.3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError


def weighted_horn(x: np.ndarray, y: np.ndarray, w: np.ndarray | None = None) -> np.ndarray:
    """(4, 4) T with T(x_i) ~ y_i; x, y: (N, 3); w: (N,) non-negative weights (default 1)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    w = np.ones(len(x)) if w is None else np.asarray(w, dtype=np.float64)
    if x.shape != y.shape or x.ndim != 2 or x.shape[1] != 3 or w.shape != (len(x),):
        raise InputError(f"weighted_horn: shapes {x.shape}, {y.shape}, {w.shape} do not match")
    if np.any(w < 0) or not np.all(np.isfinite(w)):
        raise InputError("weighted_horn: weights must be finite and non-negative")
    total = w.sum()
    if np.count_nonzero(w) < 3 or total <= 0:
        raise InputError("weighted_horn: needs at least 3 pairs with positive weight")
    cx = w @ x / total
    cy = w @ y / total
    M = (x - cx).T @ ((y - cy) * w[:, None])  # M[a, b] = sum w x'_a y'_b
    Sxx, Sxy, Sxz = M[0]
    Syx, Syy, Syz = M[1]
    Szx, Szy, Szz = M[2]
    N = np.array([
        [Sxx + Syy + Szz, Syz - Szy, Szx - Sxz, Sxy - Syx],
        [Syz - Szy, Sxx - Syy - Szz, Sxy + Syx, Szx + Sxz],
        [Szx - Sxz, Sxy + Syx, -Sxx + Syy - Szz, Syz + Szy],
        [Sxy - Syx, Szx + Sxz, Syz + Szy, -Sxx - Syy + Szz],
    ])
    vals, vecs = np.linalg.eigh(N)
    q = vecs[:, -1]  # (w, x, y, z) for the largest eigenvalue
    R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = cy - R @ cx
    return T
