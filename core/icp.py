"""ICP on the robust error surface (paper sections 1 and 2.3).

Each iteration: closest points on the target surface, robust weights (eq. 2), weighted Horn,
apply. It stops when E changes by less than ``tolerance`` (relative, either way) or at
``max_iterations``, and returns the best pose it visited.

Point-to-point ICP creeps along shallow valleys (planes sliding past each other). As Besl and
McKay's accelerated ICP (paper ref. [5], section IV) does, when the last steps point the same
way we also try the step taken 2, 4, 8... times over and keep the longest that lowers E.

Beyond the paper, ``IcpConfig(metric="plane")`` (the global pipeline's refinement) takes Gauss-Newton
steps on the distances along the closest triangles' normals (Chen and Medioni's point-to-plane ICP)
with the same robust weights, on the same E: a few iterations where Horn's steps take dozens.

``IcpConfig(step_tolerance=(deg, units))`` walks every step: each is taken (no test that it lowers E, no
backtracking, no acceleration), as the paper's ICP takes its Horn steps, but it stops when a step moves the pose
less than that (the paper stops when E changes little, which E's wobble here never settles) and returns the last
pose. Near E's minimum on noisy depth the test that a step lowers E rejects most point-to-plane steps (the
closest triangles and the robust weights shift under them, so E wobbles by a few per mille), and the Horn steps
taken instead creep: measured on the shared Kinect frames capture0003 -> 0004, 10000 source points on one cut,
168 of 300 descent iterations fell back to Horn's step and the pose was still moving 0.003 deg an iteration
after 100; every step taken, ICP stops in 9-44 iterations (the point-to-plane step's fixed point).

Optionally ICP is kept inside a region of poses (``inside``): the hybrid searches only where the
initial guess allows (paper section 2.1), so an ICP step that would leave it ends the leg there,
a local minimum on the region's wall, and annealing takes over from a pose it may search around.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .horn import constrained_horn, weighted_horn
from .lock import LockFrame
from .robust_error import ErrorFunction
from .rows import cross
from .transforms import apply, invert

METRICS = ("point", "plane")
BACKTRACK = (0.5, 0.25, 0.125)  # the fractions of a "plane" step tried when the whole step raises E


@dataclass(frozen=True)
class IcpConfig:
    max_iterations: int = 100
    tolerance: float = 1e-3  # stop when |E_prev - E| < tolerance * E_prev
    accelerate: bool = True  # extrapolate along consistent steps (Besl and McKay)
    unweighted: bool = False  # the paper's suggested final polish: outliers (d^2 >= t) dropped, others weight 1
    # "point": the paper's step (weighted Horn on the closest points); "plane": a Gauss-Newton step on
    # the distances along the closest triangles' normals (Chen and Medioni), the global pipeline's
    # refinement: the same robust weights and E, several times fewer iterations. Free poses only.
    metric: str = "point"
    # Stop when the best E has not fallen by ``tolerance`` for this many iterations (None: never). Near a
    # minimum the point-to-plane steps can cycle among poses whose E differs by a few per cent (the
    # closest triangles and the robust weights change under them) and the change test never holds:
    # measured on bun315->bun045, a refinement reached 0.05 deg in 4 iterations and cycled for 96 more.
    patience: int | None = None
    # None: descent (above). (degrees, units): every step is taken, and ICP stops when a step turns the pose less
    # than the degrees and moves the sample's centroid less than the units (module notes: the every-step walk)
    step_tolerance: tuple[float, float] | None = None

    def validate(self) -> None:
        if self.max_iterations < 1 or not self.tolerance >= 0:
            raise InputError("ICP needs at least 1 iteration and a tolerance >= 0")
        if self.step_tolerance is not None and not _two_positive(self.step_tolerance):
            raise InputError(f"ICP's step tolerance must be two numbers > 0 (degrees, units), "
                             f"got {self.step_tolerance!r}")
        if self.patience is not None and self.patience < 1:
            raise InputError(f"ICP's patience must be at least 1 iteration (or None), got {self.patience}")
        if self.metric not in METRICS:
            raise InputError(f"ICP metric must be one of {', '.join(METRICS)}, not {self.metric!r}")


def _two_positive(value) -> bool:
    """Whether ``value`` is two finite numbers > 0."""
    try:
        a, b = (float(x) for x in value)
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0)


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


class _RigidSteps:
    """Free 6-DOF steps: weighted Horn on the correspondences; a step taken s times over is a screw
    about the moved points' centroid. ``v``: the step in (units, units) for the acceleration test."""

    def __init__(self, T_start: np.ndarray):
        self.T = T_start

    def propose(self, terms, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self._dT = weighted_horn(terms.moved, terms.closest, w)
        self._center = terms.moved.mean(0)
        radius = float(np.sqrt(np.mean(np.sum((terms.moved - self._center) ** 2, axis=1)))) or 1.0
        return _step_vector(self._dT, self._center, radius), self._dT @ self.T

    def scaled(self, s: float) -> np.ndarray:
        return _scaled_step(self._dT, self._center, s) @ self.T

    def take(self, T_new: np.ndarray, s: float) -> None:
        self.T = T_new


class _PlaneSteps(_RigidSteps):
    """Free 6-DOF Gauss-Newton steps on the point-to-plane distances n_i . (T p_i - c_i), weighted by the
    robust weights: the small rotation w and translation v about the moved points' centroid that
    minimise sum w_i (n_i . (p_i + w x (p_i - centre) + v - c_i))^2. Directions the planes do not
    constrain (a flat patch sliding along itself) get no step: the least-norm solution."""

    def point_step(self, terms, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The paper's Horn step from the same correspondences (:class:`_RigidSteps`)."""
        return super().propose(terms, w)

    def propose(self, terms, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if terms.normals is None:
            return super().propose(terms, w)
        n = terms.normals
        self._center = terms.moved.mean(0)
        q = terms.moved - self._center
        radius = float(np.sqrt(np.mean(np.sum(q * q, axis=1)))) or 1.0
        J = np.hstack([cross(q, n) / radius, n])  # rotations scaled by the radius: a well-conditioned system
        r = np.einsum("ij,ij->i", terms.moved - terms.closest, n)
        A = J.T @ (w[:, None] * J)
        b = -J.T @ (w * r)
        x = np.linalg.lstsq(A, b, rcond=1e-9)[0]
        rot, shift = x[:3] / radius, x[3:]
        R = Rotation.from_rotvec(rot).as_matrix()
        self._dT = np.eye(4)
        self._dT[:3, :3] = R
        self._dT[:3, 3] = self._center + shift - R @ self._center
        return np.r_[shift, rot * radius], self._dT @ self.T


class _LockedSteps:
    """Steps on the free coordinates z of a lock frame (core.lock): the constrained Horn step
    (core.horn.constrained_horn); a step taken s times over is z + s v, so locked values stay exact."""

    def __init__(self, frame: LockFrame, T_start: np.ndarray):
        self.frame, self.z = frame, frame.free(T_start)
        self.T = frame.pose(self.z)

    def propose(self, terms, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        y = apply(invert(self.frame.delta(self.z)), terms.moved)  # the sample at the frame's reference pose
        self._z_new = constrained_horn(y, terms.closest, w, self.frame, self.z)
        self._v = self._z_new - self.z  # translations in search units, rotations in radians
        return self._v, self.frame.pose(self._z_new)

    def scaled(self, s: float) -> np.ndarray:
        return self.frame.pose(self.z + s * self._v)

    def take(self, T_new: np.ndarray, s: float) -> None:
        self.z, self.T = (self._z_new if s == 1 else self.z + s * self._v), T_new


def icp(error: ErrorFunction, T_start: np.ndarray, config: IcpConfig = IcpConfig(),
        on_iteration: Callable[[np.ndarray, float], None] | None = None,
        inside: Callable[[np.ndarray], bool] | None = None, frame: LockFrame | None = None) -> IcpResult:
    """Run ICP from ``T_start`` (4, 4) T_target_source; ``on_iteration(T, E)`` after each step.

    ``inside(T)``, when given, bounds the walk: a step to a pose outside ends ICP where it stands.
    ``frame`` (a :class:`core.lock.LockFrame`), when given, locks degrees of freedom: ICP starts
    at ``T_start`` projected onto the allowed set and each Horn step is solved on the free
    coordinates only (:func:`core.horn.constrained_horn`); ``config.metric`` then does not apply.
    """
    if frame is not None:
        steps = _LockedSteps(frame, T_start)
    else:
        steps = _PlaneSteps(T_start) if config.metric == "plane" else _RigidSteps(T_start)
    if config.step_tolerance is not None:
        return _every_step(error, steps, config, on_iteration, inside)
    terms = error.terms(steps.T)
    best_T, best_E = steps.T, terms.error
    it = improved_at = 0
    previous = None
    while it < config.max_iterations:
        proposed = _propose(steps, terms, config, inside)
        if proposed is None:
            break
        v, T_new, w = proposed
        new = error.terms(T_new)
        taken = 1.0
        if isinstance(steps, _PlaneSteps) and new.error >= terms.error:
            # A Gauss-Newton step may overshoot where the weights or the closest triangles change
            # (it then cycles between two poses): take a fraction of it, else the paper's Horn step.
            for s in BACKTRACK:
                T_try = steps.scaled(s)
                tried = error.terms(T_try)
                if tried.error < terms.error and (inside is None or inside(T_try)):
                    T_new, new, taken = T_try, tried, s
                    break
            else:
                v, T_new = steps.point_step(terms, w)
                if inside is not None and not inside(T_new):
                    break
                new = error.terms(T_new)
        if config.accelerate and previous is not None and np.linalg.norm(v) > 0:
            cos = v @ previous / (np.linalg.norm(v) * np.linalg.norm(previous) + 1e-300)
            s = 2.0
            while cos > 0.9 and s <= 64 and new.error < terms.error:
                T_try = steps.scaled(s)
                if inside is not None and not inside(T_try):
                    break
                tried = error.terms(T_try)
                if tried.error >= new.error:
                    break
                T_new, new, taken = T_try, tried, s
                s *= 2
        previous = v
        it += 1
        if on_iteration is not None:
            on_iteration(T_new, new.error)
        if new.error < best_E * (1 - config.tolerance):
            improved_at = it
        if new.error < best_E:
            best_T, best_E = T_new, new.error
        # Stop on a small change either way; robust weights shift, so E may rise a little mid-walk.
        converged = abs(terms.error - new.error) < config.tolerance * terms.error or (
            config.patience is not None and it - improved_at >= config.patience)
        steps.take(T_new, taken)
        terms = new
        if converged:
            break
    return IcpResult(best_T, best_E, it)


def _propose(steps, terms, config: IcpConfig, inside: Callable[[np.ndarray], bool] | None):
    """The next step from ``terms`` (the step vector, the pose, the weights used), or None where ICP ends: fewer
    than three pairs carry weight (no rigid step is defined), or the step leaves the region ``inside``."""
    w = (terms.d2 < terms.t).astype(float) if config.unweighted else terms.weights
    if np.count_nonzero(w) < 3:
        w = terms.weights
    if np.count_nonzero(w) < 3:
        return None
    v, T_new = steps.propose(terms, w)
    if inside is not None and not inside(T_new):
        return None
    return v, T_new, w


def _every_step(error: ErrorFunction, steps, config: IcpConfig,
                on_iteration: Callable[[np.ndarray, float], None] | None,
                inside: Callable[[np.ndarray], bool] | None) -> IcpResult:
    """The every-step walk (module notes): each step taken, until one is below ``config.step_tolerance``; the last
    pose and its E."""
    max_deg, max_move = config.step_tolerance
    terms = error.terms(steps.T)
    it = 0
    while it < config.max_iterations:
        proposed = _propose(steps, terms, config, inside)
        if proposed is None:
            break
        T_new = proposed[1]
        dT = T_new @ invert(steps.T)
        center = terms.moved.mean(0)
        turn = np.degrees(np.linalg.norm(Rotation.from_matrix(dT[:3, :3]).as_rotvec()))
        move = float(np.linalg.norm(dT[:3, :3] @ center + dT[:3, 3] - center))
        steps.take(T_new, 1.0)
        terms = error.terms(T_new)
        it += 1
        if on_iteration is not None:
            on_iteration(T_new, terms.error)
        if turn < max_deg and move < max_move:
            break
    return IcpResult(steps.T, terms.error, it)
