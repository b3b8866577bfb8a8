"""The error landscape (paper Fig. 3 and 7): E over a grid of two of the six pose parameters
around a pose, the other four held fixed, and a run's path projected onto it.

Parameters are the local step of :func:`core.transforms.perturb` about the moving scan's
overlap centroid: ``tx, ty, tz`` in the scan's units, ``rx, ry, rz`` in degrees.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .problem import Problem
from .transforms import PARAM_NAMES, apply, invert


@dataclass(frozen=True, eq=False)
class Slice:
    """values: (steps, steps) E with [i, j] at (axis_a[i], axis_b[j]); axes in units or degrees."""

    params: tuple[str, str]
    axis_a: np.ndarray
    axis_b: np.ndarray
    values: np.ndarray
    T_center: np.ndarray

    def __repr__(self) -> str:
        return (f"Slice({self.params[0]} x {self.params[1]}, {len(self.axis_a)} x {len(self.axis_b)}, "
                f"E from {np.nanmin(self.values):.4g} to {np.nanmax(self.values):.4g})")

    def minima(self) -> np.ndarray:
        """(M, 2) the grid's local minima, (axis_a, axis_b) values: inner grid points lower than their eight
        neighbours (paper Fig. 3's "local minima contained in a larger pit"), lowest first."""
        v = np.where(np.isfinite(self.values), self.values, np.inf)
        if min(v.shape) < 3:
            return np.zeros((0, 2))
        inner = v[1:-1, 1:-1]
        lowest = np.ones(inner.shape, bool)
        for di in (-1, 0, 1):
            for dj in (-1, 0, 1):
                if di or dj:
                    lowest &= inner < v[1 + di:v.shape[0] - 1 + di, 1 + dj:v.shape[1] - 1 + dj]
        i, j = np.nonzero(lowest)
        order = np.argsort(inner[i, j])
        return np.c_[self.axis_a[i[order] + 1], self.axis_b[j[order] + 1]]


def parse_params(text: str) -> tuple[str, str]:
    names = tuple(t.strip() for t in text.split(","))
    if len(names) != 2 or any(n not in PARAM_NAMES for n in names) or names[0] == names[1]:
        raise InputError(f"--params needs two different names from {', '.join(PARAM_NAMES)}, got {text!r}")
    return names  # type: ignore[return-value]


def default_span(problem: Problem, name: str) -> float:
    """Half-width covering the initial uncertainty: units for translations, degrees for rotations."""
    return problem.translation_uncertainty if name.startswith("t") else float(np.degrees(problem.rotation_uncertainty))


def delta_vector(problem: Problem, values: dict[str, float]) -> np.ndarray:
    """Search coordinates (6,) for named parameter values (units, degrees)."""
    x = np.zeros(6)
    for name, v in values.items():
        i = PARAM_NAMES.index(name)
        x[i] = v / problem.scale if i < 3 else np.radians(v)
    return x


def project(problem: Problem, T_center: np.ndarray, params: tuple[str, str], poses: list[np.ndarray]) -> np.ndarray:
    """(K, 2) coordinates of poses on the slice's axes (units or degrees): ``problem.coords`` of each, in one
    batch (the page projects a run's events as they arrive)."""
    from scipy.spatial.transform import Rotation

    Ts = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    if not len(Ts):
        return np.zeros((0, 2))
    center = apply(T_center, problem.center[None])[0]
    D = Ts @ invert(T_center)  # as core.transforms.delta_between, for K poses at once
    trans = D[:, :3, 3] - center + D[:, :3, :3] @ center
    x = np.c_[trans, np.degrees(Rotation.from_matrix(D[:, :3, :3]).as_rotvec())]
    return x[:, [PARAM_NAMES.index(p) for p in params]]


def check_spans(params: tuple[str, str], spans: tuple[float, float]) -> None:
    """Refuse half-widths that are not positive, a rotation's beyond 180 degrees (it would go round again)
    or a translation's beyond core.scan.MAX_COORDINATE units (no precision left for the geometry)."""
    from .scan import MAX_COORDINATE

    for name, s in zip(params, spans):
        if not (np.isfinite(s) and s > 0):
            raise InputError(f"the half-width of {name} must be a positive number, got {s:g}")
        if name.startswith("r") and s > 180:
            raise InputError(f"the half-width of {name} is {s:g} deg, more than 180 (a rotation beyond goes round again)")
        if name.startswith("t") and s > MAX_COORDINATE:
            raise InputError(f"the half-width of {name} is {s:g} units, beyond what the geometry can use "
                             f"(<= {MAX_COORDINATE:.0e})")


def compute_slice(problem: Problem, T_center: np.ndarray, params: tuple[str, str], spans: tuple[float, float],
                  steps: int = 61, progress: Callable[[float], None] | None = None) -> Slice:
    """E on a ``steps`` x ``steps`` grid over +-spans of two parameters around ``T_center``."""
    if steps < 2:
        raise InputError(f"steps must be at least 2, got {steps}")
    if steps > 1001:
        raise InputError(f"steps must be at most 1001, got {steps}")
    check_spans(params, spans)
    a = np.linspace(-spans[0], spans[0], steps)
    b = np.linspace(-spans[1], spans[1], steps)
    values = np.empty((steps, steps))
    for i, va in enumerate(a):
        for j, vb in enumerate(b):
            values[i, j] = problem.error(problem.pose(T_center, delta_vector(problem, {params[0]: va, params[1]: vb})))
        if progress is not None:
            progress((i + 1) / steps)
    return Slice(params, a, b, values, T_center)
