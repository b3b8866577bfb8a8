"""The robust error function (paper section 2.2, eq. 1-2), shared by ICP, annealing, slices and GUI.

    E(T) = (1/N) sum_i w_i d_i^2,   d_i = |C(T(p_i), Q) - T(p_i)|,   t = 2 median(d_i^2),
    w_i = 1 if d_i^2 < t else t / d_i^2.

So w_i d_i^2 = min(d_i^2, t): an outlier adds the constant t, never zero, so a whole surface can
not be tagged as outliers to lower the score (the paper's corner example).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from .surface import Surface
from .transforms import apply


def robust_weights(d2: np.ndarray, widen: float = 1.0) -> tuple[np.ndarray, float]:
    """Weights (N,) for squared distances (N,) and the threshold t = 2 median(d2) (paper eq. 2).

    ``widen`` > 1 multiplies t: a smoother error surface whose wells are wider (coarse-to-fine).
    """
    t = 2.0 * widen * float(np.median(d2))
    w = np.ones_like(d2)
    far = d2 >= t
    if t > 0:
        w[far] = t / d2[far]
    else:  # a perfect fit of at least half the points: the others add t = 0
        w[far & (d2 > 0)] = 0.0
    return w, t


@dataclass(frozen=True, eq=False)
class ErrorTerms:
    """One evaluation: E, moved points (N, 3), their closest surface points (N, 3), d2 (N,), w (N,), t,
    and the unit normals (N, 3) of the triangles the closest points lie on (None when not known)."""

    error: float
    moved: np.ndarray
    closest: np.ndarray
    d2: np.ndarray
    weights: np.ndarray
    t: float
    normals: np.ndarray | None = None


class ErrorFunction(Protocol):
    """What ICP and the search evaluate: a :class:`RobustError` or a view of one (a run's counter)."""

    def terms(self, T_target_source: np.ndarray) -> ErrorTerms: ...

    def __call__(self, T_target_source: np.ndarray) -> float: ...


class RobustError:
    """E(T) for fixed source points (N, 3, source frame) against a target surface. Read-only, so one
    prepared problem can serve many runs: a run counts its own evaluations (``core.search.state``)."""

    def __init__(self, points: np.ndarray, surface: Surface, widen: float = 1.0):
        self._points = np.array(points, dtype=np.float64)  # a copy: nobody else can change it
        self._points.flags.writeable = False
        self._surface = surface
        self._widen = float(widen)

    @property
    def points(self) -> np.ndarray:
        return self._points

    @property
    def surface(self) -> Surface:
        return self._surface

    @property
    def widen(self) -> float:
        """The factor on the outlier cap t (see :func:`robust_weights`)."""
        return self._widen

    def widened(self, widen: float) -> RobustError:
        """The same error with its outlier cap t widened ``widen`` times (coarse-to-fine, paper section 4)."""
        return self if widen == self._widen else RobustError(self._points, self._surface, widen)

    def terms(self, T_target_source: np.ndarray) -> ErrorTerms:
        moved = apply(T_target_source, self._points)
        closest, d2, normals = self._surface.closest_with_normals(moved)
        w, t = robust_weights(d2, self._widen)
        return ErrorTerms(float(np.mean(w * d2)), moved, closest, d2, w, t, normals)

    def __call__(self, T_target_source: np.ndarray) -> float:
        return self.terms(T_target_source).error
