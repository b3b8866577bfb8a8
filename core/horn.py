"""Weighted absolute orientation: Horn's closed-form unit-quaternion solution (Horn 1987, paper [7]).

Finds the rigid T minimising sum_i w_i |R x_i + t - y_i|^2. With weights the centroids and the
cross-covariance are weighted (Horn, section 2.D), which lets ICP walk the same robust error
surface as annealing (paper section 2.3).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .lock import LockFrame
from .transforms import apply


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


def constrained_horn(y: np.ndarray, q: np.ndarray, w: np.ndarray, frame: LockFrame, z0: np.ndarray,
                     max_steps: int = 50) -> np.ndarray:
    """z (k,) minimising sum_i w_i |m_i(z) - q_i|^2, the weighted Horn problem on a lock's free
    coordinates only: m_i(z) are the points y (N, 3, at the frame's reference pose) moved to z.

    A turntable's lone angle has a closed form; otherwise Gauss-Newton from ``z0`` (exact in one
    step when no rotation is free: the weighted centroid difference), each step halved until the
    sum falls, so it never rises.
    """
    y, q = np.asarray(y, dtype=np.float64), np.asarray(q, dtype=np.float64)
    w = np.asarray(w, dtype=np.float64)
    if y.shape != q.shape or y.ndim != 2 or y.shape[1] != 3 or w.shape != (len(y),):
        raise InputError(f"constrained_horn: shapes {y.shape}, {q.shape}, {w.shape} do not match")
    if np.any(w < 0) or not np.all(np.isfinite(w)) or not w.sum() > 0:
        raise InputError("constrained_horn: weights must be finite, non-negative and not all zero")
    z = np.array(z0, dtype=np.float64)
    if frame.axis is not None and frame.k == 1:
        # rotation about a fixed line: maximise sum w (q - p).R(a)(y - p) (Horn's 1-D case)
        a, b = y - frame.pivot, q - frame.pivot
        d = frame.axis
        cross = np.cross(a, b) @ d
        dot = np.einsum("ij,ij->i", a, b) - (a @ d) * (b @ d)
        return np.array([np.arctan2(w @ cross, w @ dot)])

    def cost(z):
        m, J = frame.motion(z, y)
        r = m - q
        return float(w @ np.einsum("ij,ij->i", r, r)), r, J

    f, r, J = cost(z)
    for _ in range(max_steps):
        H = np.einsum("n,nik,nil->kl", w, J, J)
        g = np.einsum("n,nik,ni->k", w, J, r)
        dz = -np.linalg.lstsq(H, g, rcond=None)[0]
        for _ in range(30):
            f_new, r_new, J_new = cost(z + dz)
            if f_new <= f:
                break
            dz *= 0.5
        else:
            break
        z = z + dz
        done = f - f_new <= 1e-15 * max(f, 1e-300) or np.linalg.norm(dz) <= 1e-12 * (1 + np.linalg.norm(z))
        f, r, J = f_new, r_new, J_new
        if done:
            break
    return z


def locked_horn(x: np.ndarray, y: np.ndarray, w: np.ndarray | None, frame: LockFrame) -> np.ndarray:
    """(4, 4) the pose of ``frame``'s allowed set with T(x_i) ~ y_i (point-pair alignment under a
    lock); x: (N, 3) source frame, y: (N, 3) target frame, w: (N,) weights (default 1).

    Starts from the unconstrained Horn pose projected onto the set (a large rotation is found
    there; the turntable's angle is closed-form anyway), then :func:`constrained_horn`.
    """
    x = np.asarray(x, dtype=np.float64)
    w = np.ones(len(x)) if w is None else np.asarray(w, dtype=np.float64)
    z0 = frame.free(weighted_horn(x, y, w)) if np.count_nonzero(w) >= 3 else np.zeros(frame.k)
    return frame.pose(constrained_horn(apply(frame.T_ref, x), y, w, frame, z0))
