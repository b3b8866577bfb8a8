"""ICP on the robust error surface (paper sections 1 and 2.3).

Each iteration: closest points on the target surface, robust weights (eq. 2), weighted Horn,
apply. It stops when E changes by less than ``tolerance`` (relative, either way) or at ``max_iterations``,
and returns the best pose it visited.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .error import RobustError
from .horn import weighted_horn


@dataclass(frozen=True)
class IcpConfig:
    max_iterations: int = 100
    tolerance: float = 1e-3  # stop when |E_prev - E| < tolerance * E_prev
    unweighted: bool = False  # the paper's suggested final polish: outliers (d^2 >= t) dropped, others weight 1


@dataclass(frozen=True, eq=False)
class IcpResult:
    T: np.ndarray
    error: float
    iterations: int

    def __repr__(self) -> str:
        return f"IcpResult(error={self.error:.6g}, iterations={self.iterations})"


def icp(error: RobustError, T_start: np.ndarray, config: IcpConfig = IcpConfig(),
        on_iteration: Callable[[np.ndarray, float], None] | None = None) -> IcpResult:
    """Run ICP from ``T_start`` (4, 4) T_target_source; ``on_iteration(T, E)`` after each step."""
    terms = error.terms(T_start)
    T, best_T, best_E = T_start, T_start, terms.error
    it = 0
    while it < config.max_iterations:
        w = (terms.d2 < terms.t).astype(float) if config.unweighted else terms.weights
        if np.count_nonzero(w) < 3:
            w = terms.weights
        T_new = weighted_horn(terms.moved, terms.closest, w) @ T
        new = error.terms(T_new)
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
