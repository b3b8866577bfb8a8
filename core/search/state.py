"""One search's state: the overlap cut it searches, where it starts, its counts, its best pose,
its event stream and its region; and the legs every method is made of (an ICP leg, an annealing
leg, a random step), each reporting through :meth:`SearchState.emit`.

Under a lock (``Config.lock``, core.lock) the legs walk the lock's free coordinates, bound once to
the start pose and the first cut's centroid so that the locked values stay the same all run long
(re-cuts included); every event then carries the coordinates its pose was made from.

The prepared :class:`~core.problem.Problem` is only read: the run counts its own evaluations of E
and widens E (coarse-to-fine) by viewing a widened copy, so one problem may serve many runs.
"""

from __future__ import annotations

import numpy as np

from ..anneal import AnnealConfig, anneal
from ..config import Config
from ..events import Event, Listener
from ..icp import IcpConfig, icp
from ..lock import LockFrame
from ..problem import Problem
from ..robust_error import ErrorTerms, RobustError
from ..transforms import random_perturbation, rotation_angle
from .budget import Budget


class CountedError:
    """E of one problem as the run sees it (maybe widened), counting evaluations into the run."""

    def __init__(self, error: RobustError, state: SearchState):
        self.error, self.state = error, state

    def terms(self, T_target_source: np.ndarray) -> ErrorTerms:
        self.state.evaluations += 1
        return self.error.terms(T_target_source)

    def __call__(self, T_target_source: np.ndarray) -> float:
        return self.terms(T_target_source).error


class SearchState:
    """One optimisation: counts iterations and evaluations, emits events, keeps the best pose."""

    def __init__(self, problem: Problem, config: Config, listener: Listener | None, frame: LockFrame | None = None,
                 budget: Budget | None = None):
        """``frame``: the lock bound elsewhere (a stage that runs several searches from one guess);
        by default ``config.lock`` bound to ``problem``'s guess and overlap centroid. ``budget``: the bound on
        this run's steps (core.search.budget), consulted before each step; None: the method's own stops only."""
        self.config, self.listener, self.budget = config, listener, budget
        self.rng = np.random.default_rng(config.seed)
        # per phase ("icp", "sa"; a new stage emits its own phase and gets its own key):
        self.n = {"icp": 0, "sa": 0}  # iterations over the run (Result.iterations)
        self.legs = {"icp": 0, "sa": 0}  # legs begun so far
        self.in_leg = {"icp": 0, "sa": 0}  # iterations of the current leg
        self.local_minima = 0
        self.evaluations = 0
        self.refining = False  # searching again on the overlap re-cut at the pose found (resegment)
        lock = config.lock
        if frame is None and lock.active:
            frame = lock.bind(problem.T_init, problem.center, problem.scale)
        self.frame = frame
        self.use(problem)
        self.start_at(problem.T_init)

    # --- what is searched, and from where -------------------------------------------------------

    def use(self, problem: Problem) -> None:
        """Search ``problem``'s overlap cut (E as prepared, not widened)."""
        self.problem = problem
        self.widen(1.0)

    def widen(self, widen: float) -> None:
        """Search E with its outlier cap widened ``widen`` times (coarse-to-fine); the problem is not touched."""
        self.error = CountedError(self.problem.error.widened(widen), self)

    def start_at(self, T: np.ndarray) -> None:
        """The method begins at pose T, which is also the best pose so far, with no E yet."""
        self.start, self.best_T, self.best_E = T, T, np.inf

    def restart(self) -> None:
        """Search again from the best pose so far (a new level or a new cut): its old E no longer counts."""
        self.start_at(self.best_T)

    # --- the event stream -----------------------------------------------------------------------

    def begin_leg(self, phase: str) -> None:
        self.legs[phase] = self.legs.get(phase, 0) + 1
        self.in_leg[phase] = 0

    def emit(self, phase: str, T: np.ndarray, E: float, temperature: float | None = None, accepted: bool = True,
             local_minimum: bool = False, count: bool = True) -> None:
        if count:
            if self.budget is not None:
                self.budget.take_or_stop("steps")  # the step is not taken past the bound
            self.n[phase] = self.n.get(phase, 0) + 1
            self.in_leg[phase] = self.in_leg.get(phase, 0) + 1
        if E < self.best_E:
            self.best_T, self.best_E = T, E
        if self.listener is not None:
            coords = None if self.frame is None else self.frame.coords_of(T)
            self.listener(Event(phase, sum(self.n.values()), self.in_leg.get(phase, 0), self.legs.get(phase, 0), T, E,
                                temperature, accepted, local_minimum, coords))

    def mark_local_minimum(self, T: np.ndarray, E: float) -> None:
        self.local_minima += 1
        self.emit("icp", T, E, local_minimum=True, count=False)

    # --- the region and the legs ----------------------------------------------------------------

    def inside(self, T: np.ndarray) -> bool:
        """Whether pose T lies in the search region: ``search.bound`` x the guess's uncertainty around it."""
        p, bound = self.problem, self.config.search.bound  # the norms of p.coords(T, p.T_init), without its matrix logarithm
        moved = (T[:3, :3] - p.T_init[:3, :3]) @ p.center + T[:3, 3] - p.T_init[:3, 3]
        return bool(np.linalg.norm(moved) <= bound * p.translation_uncertainty
                    and rotation_angle(T[:3, :3] @ p.T_init[:3, :3].T) <= bound * p.rotation_uncertainty)

    def icp(self, T: np.ndarray, icp_config: IcpConfig | None = None, bounded: bool = True) -> tuple[np.ndarray, float]:
        """One ICP leg from T; returns (pose, E) where it ended."""
        self.begin_leg("icp")
        start = self.n["icp"]
        res = icp(self.error, T, icp_config or self.config.icp, lambda T_, E: self.emit("icp", T_, E),
                  self.inside if bounded else None, self.frame)
        if self.n["icp"] == start:  # no step taken: still report where ICP stands
            self.emit("icp", res.T, res.error, count=False)
        return res.T, res.error

    def first_icp(self, threshold: float) -> tuple[np.ndarray, float]:
        """ICP from the start, free to walk wherever E leads, as the paper's; a leg that ends outside
        the search region above the threshold is a minimum the guess rules out (bun090 -> bun000: 40-50
        deg off, where E on the cut under a poor guess can prefer it), so ICP again, kept inside."""
        T, E = self.icp(self.start, bounded=False)
        if E >= threshold and not self.inside(T):
            self.mark_local_minimum(T, E)
            self.best_T, self.best_E = self.start, np.inf  # ruled out: never the answer
            T, E = self.icp(self.start)
        return T, E

    def project(self, T: np.ndarray) -> np.ndarray:
        """T itself, or under a lock the pose of the allowed set nearest to it (core.lock): a stage
        that makes poses of its own (candidates, pair alignment) hands them to the legs through this."""
        return T if self.frame is None else self.frame.pose(self.frame.free(T))

    def random_step(self, T: np.ndarray, size: float) -> np.ndarray:
        """T moved in a random direction by up to ``size`` x the guess's uncertainty in each of
        translation and rotation (uniform in length)."""
        if self.frame is not None:  # only the free coordinates move
            t_unc, r_unc = self._uncertainty()
            return self.frame.pose(self.frame.free(T) + self.frame.random_step(self.rng, size * t_unc, size * r_unc))
        t, r = random_perturbation(self.rng, 1.0, 1.0)
        steps = self.problem.steps
        x = np.r_[t * self.rng.uniform(0, size) * steps[0], r * self.rng.uniform(0, size) * steps[3]]
        return self.problem.pose(T, x)

    def hop(self, T: np.ndarray) -> None:
        """A random hop to T (basin hopping): a one-move annealing leg, a stochastic move."""
        self.begin_leg("sa")
        self.emit("sa", T, self.error(T))

    def sa(self, T_base: np.ndarray, E_base: float, stop_below: float | None,
           config: AnnealConfig) -> tuple[np.ndarray, float, bool]:
        """One annealing leg around T_base; returns (best pose, its E, whether it got below ``stop_below``)."""
        self.begin_leg("sa")
        error, frame = self.error, self.frame
        if frame is None:  # the six search coordinates around T_base
            x0, steps = np.zeros(6), self.problem.steps

            def pose(x):
                return self.problem.pose(T_base, x)
        else:  # a k-D simplex over the lock's free coordinates (flat directions in a 6-D one would
            # break the convergence test and the start temperature)
            x0, steps, pose = frame.free(T_base), frame.steps(*self._uncertainty()), frame.pose

        def f(x):
            T = pose(x)
            # Annealing may roam, but only over poses the initial guess allows (paper section 2.1
            # assumes the guess is good enough); farther out E is taken as infinite.
            return error(T) if self.inside(T) else np.inf

        def report(x, y, temp, accepted):
            if np.isfinite(y):
                self.emit("sa", pose(x), y, temp, accepted)

        res = anneal(f, x0, self.config.simplex_scale * steps, self.rng, config, stop_below=stop_below,
                     on_eval=report, f0=E_base)
        return pose(res.x), res.value, res.improved

    def _uncertainty(self) -> tuple[float, float]:
        """The current cut's uncertainty in the lock's coordinates: (translation in its search units, radians)."""
        return self.problem.translation_uncertainty / self.frame.scale, self.problem.rotation_uncertainty
