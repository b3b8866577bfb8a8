"""Rigid transforms and the one convention used everywhere.

Convention: ``T_b_a`` is a (4, 4) float64 homogeneous matrix that maps points written in frame
``a`` into frame ``b``: ``x_b = T_b_a[:3, :3] @ x_a + T_b_a[:3, 3]``. Registration estimates
``T_target_source``. A *pose vector* is ``(tx, ty, tz, rx, ry, rz)``: translation in the scan's
units and a rotation vector in radians (axis times angle).

The optimisers search a *local* 6-D step ``delta`` around a base pose: rotate by ``delta[3:]``
about a fixed centre (the moving scan's centroid, so rotation and translation stay decoupled), then
translate by ``delta[:3]``. Slices of the error surface use the same parametrisation.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

PARAM_NAMES = ("tx", "ty", "tz", "rx", "ry", "rz")


def rotation_matrix(rotvec: np.ndarray) -> np.ndarray:
    """(3,) rotation vector (radians) -> (3, 3) matrix (Rodrigues; the optimisers call this per
    evaluation, where scipy's Rotation object costs more than the whole matrix)."""
    r = np.asarray(rotvec, dtype=np.float64)
    theta = float(np.sqrt(r @ r))
    if theta < 1e-12:
        return np.eye(3)
    x, y, z = r / theta
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(theta) * K + (1.0 - np.cos(theta)) * (K @ K)


def rotation_angle(R: np.ndarray) -> float:
    """The angle (radians) of the (3, 3) rotation R."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def from_params(params: np.ndarray) -> np.ndarray:
    """(6,) pose vector -> (4, 4) transform."""
    p = np.asarray(params, dtype=np.float64).reshape(6)
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(p[3:])
    T[:3, 3] = p[:3]
    return T


def to_params(T: np.ndarray) -> np.ndarray:
    """(4, 4) transform -> (6,) pose vector."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_rotvec()])


def apply(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Map (N, 3) points by the (4, 4) transform T."""
    return points @ T[:3, :3].T + T[:3, 3]


def invert(T: np.ndarray) -> np.ndarray:
    Ti = np.eye(4)
    Ti[:3, :3] = T[:3, :3].T
    Ti[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return Ti


def perturb(T_base: np.ndarray, delta: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Apply the local step ``delta`` (6,) to ``T_base``: rotate about ``center`` (target frame), translate."""
    d = np.asarray(delta, dtype=np.float64)
    D = np.eye(4)
    R = rotation_matrix(d[3:])
    D[:3, :3] = R
    D[:3, 3] = center - R @ center + d[:3]
    return D @ T_base


def delta_between(T: np.ndarray, T_base: np.ndarray, center: np.ndarray) -> np.ndarray:
    """Inverse of :func:`perturb`: the step that takes ``T_base`` to ``T``."""
    D = T @ invert(T_base)
    R = D[:3, :3]
    rot = Rotation.from_matrix(R).as_rotvec()
    trans = D[:3, 3] - center + R @ center
    return np.concatenate([trans, rot])


def check_rigid(T: np.ndarray, what: str = "transform", tol: float = 1e-4) -> np.ndarray:
    """Return T as (4, 4) float64 or raise ValueError if it is not a proper rigid transform."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"{what} must be a 4 x 4 matrix, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise ValueError(f"{what} contains NaN or infinite values")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=tol):
        raise ValueError(f"{what} has a last row {T[3].tolist()}, expected [0, 0, 0, 1]")
    R = T[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):  # entries of 1e300 square to inf: said below, not warned
        det = np.linalg.det(R)
        if abs(det) < 1e-9:
            raise ValueError(f"{what} is singular (its rotation part has determinant {det:.3g})")
        if not np.allclose(R.T @ R, np.eye(3), atol=tol) or det < 0:
            raise ValueError(f"{what} is not rigid: its 3 x 3 part {_not_a_rotation(R, det, tol)}")
    return T


def quaternion_matrix(q: np.ndarray) -> np.ndarray | None:
    """The (3, 3) rotation of quaternion ``q`` (4,) in scipy's order (x, y, z, w), of any length (it is
    normalised); None when it has no direction: a non-finite entry, or a length below 1e-9. Scaled by its
    largest entry first, so that 1e300 (whose square overflows) is a direction like any other."""
    q = np.asarray(q, dtype=np.float64)
    if not np.all(np.isfinite(q)):
        return None
    scale = float(np.max(np.abs(q)))
    if not scale > 0:
        return None
    unit = q / scale
    length = float(np.linalg.norm(unit))
    if scale * length < 1e-9:
        return None
    return Rotation.from_quat(unit / length).as_matrix()


def _not_a_rotation(R: np.ndarray, det: float, tol: float) -> str:
    """What a 3 x 3 matrix that is not a rotation is instead, in words (its singular values say it)."""
    s = np.linalg.svd(R, compute_uv=False)
    if det < 0 and np.allclose(s, 1, atol=tol):
        return "is a reflection (det -1), not a rotation"
    if np.ptp(s) <= tol * max(1.0, s.max()):
        kind = f"is a rotation scaled by {s.mean():.6g} (a rigid transform has scale 1)"
        return kind + (" and mirrored (det < 0)" if det < 0 else "")
    return (f"is not a rotation: it stretches by {', '.join(f'{v:.6g}' for v in s)} along its axes "
            f"(det {det:.3g})")


def pose_error(T_est: np.ndarray, T_true: np.ndarray, center: np.ndarray | None = None) -> tuple[float, float]:
    """(rotation error in degrees, translation error in units) between two transforms.

    The translation error is measured at ``center`` (source frame; default the origin): the distance
    between where the two transforms put that point. Measuring at the scan's centroid keeps a small
    rotation error from showing up as a large translation error when the origin is far away.
    """
    D = T_est @ invert(T_true)
    rot = float(np.degrees(rotation_angle(D[:3, :3])))
    c = np.zeros(3) if center is None else np.asarray(center, dtype=np.float64)
    trans = float(np.linalg.norm(apply(T_est, c[None])[0] - apply(T_true, c[None])[0]))
    return rot, trans


def random_perturbation(rng: np.random.Generator, rotation_deg: float, translation: float) -> tuple[np.ndarray, np.ndarray]:
    """A random rotation vector of exactly ``rotation_deg`` and translation of length ``translation``."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    return direction * translation, axis * np.radians(rotation_deg)
