"""Rounds of search, each on one overlap cut, and the refinements around them.

Beyond the paper, on by default: the overlap is cut again (section 2.1's frustum) at the pose the
search found and the search refines there with the small uncertainty left (``resegment``); annealing
and ICP stay within ``search.bound`` times the guess's uncertainty around the pose the cut was made
at, except the first ICP leg, which walks wherever E leads (as the paper's) and is taken again inside
the region only when it ends outside above the threshold (``SearchState.first_icp``).

Off by default: ``recut_rounds`` > 1 (hybrid only) searches again with the full uncertainty from a
cut at the pose found, unless that cut is nearly the old one; the round whose pose has the lowest E
on the cut at its own pose wins. Measured (10 starts): bun090 -> bun000 (15 deg / 25 mm) 9/10 in
2.2 s median with 1 round or 2; bowl 0/10 either way, 2.4 -> 5.8 s. (Before annealing's simplex was
let roam: bun090 -> bun000 5/10 with 1 round, 6/10 with 2.)

Also off by default: ``polish`` (a final ICP with outliers dropped and no weights, paper section 4)
and ``coarse_to_fine`` (paper section 4: the search first runs on a smoother error surface, here E
with its outlier cap t widened 100 and then 10 times, so that a well whose walls are flat beyond
sqrt(t) - a plane hovering off its partner - pulls from farther away).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..config import Config
from ..guess import Guess
from ..problem import Problem, prepare
from ..result import Stop, StopReason
from ..transforms import pose_error
from .methods import METHODS
from .state import SearchState


@dataclass(frozen=True, eq=False)
class Round:
    """One round's outcome: E on the overlap cut at its own pose, the pose (4, 4), why it stopped."""

    error: float
    T: np.ndarray
    stop: Stop


def recut(problem: Problem, T: np.ndarray, config: Config, converged: bool) -> Problem:
    """The overlap cut again at pose T: with the guess's full uncertainty, or, once ``converged``,
    with the small uncertainty left after a registration."""
    guess = Guess.converged(T, config.search, problem.target.size) if converged else problem.guess.at(T)
    return prepare(problem.source, problem.target, guess, config.problem, surface=problem.surface, seed=config.seed)


def jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """Overlap of two (N,) bool point selections: |a and b| / |a or b|."""
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 1.0


def search_levels(state: SearchState, threshold: float) -> Stop:
    """The method on the current cut; with coarse-to-fine, first on smoother error surfaces."""
    cfg = state.config
    for widen in cfg.search.coarse_widenings if cfg.coarse_to_fine else (1.0,):  # never empty: validated
        # Coarse-to-fine (paper section 4): the same search on a smoother error surface first.
        state.widen(widen)
        state.restart()
        stop = METHODS[cfg.method](state, threshold if widen == 1.0 else cfg.search.coarse_threshold * threshold)
    state.widen(1.0)
    return stop


def refine(state: SearchState, threshold: float) -> Stop:
    """Once the pose is good the cut is too (fewer points without a partner): cut again there, with
    the small uncertainty left, and search again from the pose found."""
    state.use(recut(state.problem, state.best_T, state.config, converged=True))
    state.restart()
    state.refining = True
    try:
        return METHODS[state.config.method](state, threshold)
    finally:
        state.refining = False


def search_rounds(state: SearchState, threshold: float, rounds: list[Round]) -> None:
    """Search, refine and score each overlap cut in turn, appending a :class:`Round` for each. The
    outer re-cut loop belongs to our hybrid; the baselines search one cut, as in the paper."""
    cfg = state.config
    cut = state.problem  # the cut the current round searches
    for k in range(cfg.recut_rounds if cfg.method == "hybrid" else 1):
        if k:
            # Beyond the paper: section 2.1 cuts the overlap under the first guess; where that guess
            # is poor and the overlap low, most cut points have no partner at the truth and E can
            # prefer a wrong pose. Cut again at the pose found (with the full uncertainty) and search
            # again from there, unless the new cut is nearly the old one (the same error again).
            new = recut(state.problem, state.best_T, cfg, converged=False)
            if jaccard(new.used, cut.used) >= cfg.search.same_cut:
                break
            state.use(new)
            state.restart()
        cut = state.problem
        T_round = cut.T_init
        stop = search_levels(state, threshold)
        if cfg.resegment:
            stop = refine(state, threshold)
        E = state.error(state.best_T)
        rounds.append(Round(E, state.best_T, stop))
        rot, tr = pose_error(state.best_T, T_round, state.problem.center)
        if E < threshold or (rot < cfg.search.resegment_rotation_deg
                             and tr < cfg.search.resegment_translation * state.problem.target.size):
            break


def polish(state: SearchState, rounds: list[Round]) -> None:
    """Beyond the paper (section 4's suggestion): a last ICP leg, outliers dropped and no weights."""
    state.icp(state.best_T, replace(state.config.icp, unweighted=True))
    rounds.append(Round(state.error(state.best_T), state.best_T, rounds[-1].stop))


def cancelled(state: SearchState) -> Round:
    """The best pose so far, when a listener cancelled the run."""
    return Round(state.error(state.best_T), state.best_T, Stop(StopReason.CANCELLED))


def best_round(rounds: list[Round]) -> Round:
    """Each round is scored on the overlap cut at its own pose; the lowest wins (a run cancelled or stopped by its
    budget: the last, its best pose so far)."""
    if rounds[-1].stop.reason in (StopReason.CANCELLED, StopReason.WORK_BOUND, StopReason.TIME_BOUND):
        return rounds[-1]
    best = min(rounds, key=lambda r: r.error)
    if len(rounds) > 1:
        best = Round(best.error, best.T, Stop(best.stop.reason, f"{best.stop} (best of {len(rounds)} overlap cuts)"))
    return best
