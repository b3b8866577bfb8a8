"""One run of a paper method (hybrid, icp, sa, icp-restarts, basin-hopping) on one pair, start to result.

    prepare    section 2.1: triangulate the target, cut the overlap under the guess, sample the source
    threshold  section 2.3: the E expected at perfect registration (core.threshold)
    search     the method per overlap cut (methods), refined on a cut at the pose found, in rounds
    polish     optional: a last unweighted ICP leg (section 4)
    result     the round with the lowest E on the cut at its own pose
    verdict    E ended below the threshold: trusted only where the pair threshold's test holds too (core.verdict)
"""

from __future__ import annotations

import time

import numpy as np

from ..config import Config
from ..events import Cancelled, Listener
from ..guess import Guess
from ..lock import LockFrame
from ..problem import Problem, prepare
from ..result import Iterations, Result, StopReason
from ..scan import Scan
from ..threshold import threshold_for
from ..verdict import judge_of
from .budget import Budget, BudgetSpent
from .rounds import Round, best_round, cancelled, polish, search_rounds
from .state import SearchState


def run_method(source: Scan, target: Scan, guess: Guess | np.ndarray | None, config: Config,
               listener: Listener | None = None, problem: Problem | None = None, frame: LockFrame | None = None,
               budget: Budget | None = None, judged: bool = True) -> Result:
    """``config.method`` (a paper method) from ``guess`` (core.guess; a (4, 4) T_target_source: the default
    uncertainty); see core.register.
    ``budget``: a bound on its steps (core.search.budget); when it is spent the run returns its best pose so far,
    stopped by the budget's reason. ``judged``: a pose whose E ends below the threshold is judged by the pair
    threshold's test (core.verdict; the global method, which judges its own poses, runs the hybrid unjudged)."""
    t0 = time.perf_counter()
    problem = problem or prepare(source, target, guess, config.problem, seed=config.seed)
    threshold = threshold_for(problem, config)
    state = SearchState(problem, config, listener, frame, budget)
    # the search region is centred on the pose the problem was cut at: the guess (section 2.1)
    state.start_at(problem.T_init)
    rounds: list[Round] = []
    try:
        search_rounds(state, threshold, rounds)
        if config.polish:
            polish(state, rounds)
    except Cancelled:
        rounds.append(cancelled(state))
    except BudgetSpent as spent:
        rounds.append(Round(state.error(state.best_T), state.best_T, spent.stop))
    best = best_round(rounds)
    verdict = None
    if judged and best.error < threshold and best.stop.reason is not StopReason.CANCELLED:
        verdict = judge_of(problem, config, state.frame).verdict(best.T)
    return Result(best.T, best.error, Iterations(state.n["icp"], state.n["sa"]), state.local_minima,
                  state.evaluations, time.perf_counter() - t0, config.method, threshold, best.stop, cut=problem.cut,
                  trusted=None if verdict is None else verdict.holds, verdict=verdict)
