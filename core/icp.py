"""ICP on the robust error surface (paper sections 1 and 2.3).

Each iteration: closest points on the target surface, robust weights (eq. 2), weighted Horn,
apply. It stops when E changes by less than ``tolerance`` (relative, either way) or at
``max_iterations``, and returns the best pose it visited.

Point-to-point ICP creeps along shallow valleys (planes sliding past each other). As Besl and
McKay's accelerated ICP (paper ref. [5], section IV) does, when the last steps point the same
way we also try the step taken 2, 4, 8... times over and keep the longest that lowers E.

Optionally ICP is kept inside a region of poses (``inside``): the hybrid searches only where the
initial guess allows (paper section 2.1), so an ICP step that would leave it ends the leg there,
a local minimum on the region's wall, and annealing takes over from a pose it may search around.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .error import ErrorFunction
from .errors import InputError
from .horn import weighted_horn


@dataclass(frozen=True)
class IcpConfig:
    max_iterations: int = 100
    tolerance: float = 1e-3  # stop when |E_prev - E| < tolerance * E_prev
    accelerate: bool = True  # extrapolate along consistent steps (Besl and McKay)
    unweighted: bool = False  # the paper's suggested final polish: outliers (d^2 >= t) dropped, others weight 1

    def validate(self) -> None:
        if self.max_iterations < 1 or not self.tolerance >= 0:
            raise InputError("ICP needs at least 1 iteration and a tolerance >= 0")


@dataclass(frozen=True, eq=False)
class IcpResult:
    T: np.ndarray
    error: float
    iterations: int

    def __repr__(self) -> str:
        return f"IcpResult(error={self.error:.6g}, iterations={self.iterations})"


def _scaled_step(dT: np.ndarray, center: np.ndarray, s: float) -> np.ndarray:
    """The rigid step dT (4, 4) taken s times over, as a screw about ``center``."""
    r = Rotation.from_matrix(dT[:3, :3]).as_rotvec()
    t = dT[:3, :3] @ center + dT[:3, 3] - center  # where the centre moves
    R = Rotation.from_rotvec(s * r).as_matrix()
    out = np.eye(4)
    out[:3, :3] = R
    out[:3, 3] = center + s * t - R @ center
    return out


def _step_vector(dT: np.ndarray, center: np.ndarray, radius: float) -> np.ndarray:
    r = Rotation.from_matrix(dT[:3, :3]).as_rotvec()
    t = dT[:3, :3] @ center + dT[:3, 3] - center
    return np.r_[t, r * radius]


def icp(error: ErrorFunction, T_start: np.ndarray, config: IcpConfig = IcpConfig(),
        on_iteration: Callable[[np.ndarray, float], None] | None = None,
        inside: Callable[[np.ndarray], bool] | None = None) -> IcpResult:
    """Run ICP from ``T_start`` (4, 4) T_target_source; ``on_iteration(T, E)`` after each step.

    ``inside(T)``, when given, bounds the walk: a step to a pose outside ends ICP where it stands.
    """
    terms = error.terms(T_start)
    T, best_T, best_E = T_start, T_start, terms.error
    it = 0
    previous = None
    while it < config.max_iterations:
        w = (terms.d2 < terms.t).astype(float) if config.unweighted else terms.weights
        if np.count_nonzero(w) < 3:
            w = terms.weights
        dT = weighted_horn(terms.moved, terms.closest, w)
        center = terms.moved.mean(0)
        radius = float(np.sqrt(np.mean(np.sum((terms.moved - center) ** 2, axis=1)))) or 1.0
        v = _step_vector(dT, center, radius)
        T_new = dT @ T
        if inside is not None and not inside(T_new):
            break
        new = error.terms(T_new)
        if config.accelerate and previous is not None and np.linalg.norm(v) > 0:
            cos = v @ previous / (np.linalg.norm(v) * np.linalg.norm(previous) + 1e-300)
            s = 2.0
            while cos > 0.9 and s <= 64 and new.error < terms.error:
                T_try = _scaled_step(dT, center, s) @ T
                if inside is not None and not inside(T_try):
                    break
                tried = error.terms(T_try)
                if tried.error >= new.error:
                    break
                T_new, new = T_try, tried
                s *= 2
        previous = v
        it += 1
        if on_iteration is not None:
            on_iteration(T_new, new.error)
        if new.error < best_E:
            best_T, best_E = T_new, new.error
        # Stop on a small change either way; robust weights shift, so E may rise a little mid-walk.
        converged = abs(terms.error - new.error) < config.tolerance * terms.error
        T, terms = T_new, new
        if converged:
            break
    return IcpResult(best_T, best_E, it)
