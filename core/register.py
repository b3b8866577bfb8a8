"""Register one scan onto another: the public front (Luck et al., ICRA 2000, Fig. 6 and around it).

    prepare    section 2.1: triangulate the target, cut the overlap under the guess, sample the source
    threshold  section 2.3: the E expected at perfect registration (core.threshold)
    start      the pose the search begins at: the guess
    global     method "global" only: candidates -> the best few ICP-refined -> the hybrid from the best
               -> the lowest on the pair's fixed basis (core.global_search; issue 13)
    search     the method per overlap cut - the hybrid of Fig. 6 or a baseline (core.search.methods) -
               refined on a cut at the pose found, in rounds (core.search.rounds)
    polish     optional: a last unweighted ICP leg (section 4)
    result     the round with the lowest E on the cut at its own pose (core.result)

The knobs are in core.config, one frozen config per concern.
"""

from __future__ import annotations

import time

import numpy as np

from .config import METHODS, Config
from .events import Cancelled, Listener
from .lock import LockFrame
from .problem import Problem, prepare
from .result import Result, Stop, StopReason
from .scan import Scan
from .search import Round, SearchState, best_round, cancelled, polish, recut, search_rounds
from .threshold import estimate_threshold, threshold_for

__all__ = ["METHODS", "Config", "Result", "Stop", "StopReason", "estimate_threshold", "recut", "register"]


def register(source: Scan, target: Scan, T_init: np.ndarray | None = None, config: Config = Config(),
             listener: Listener | None = None, problem: Problem | None = None,
             frame: LockFrame | None = None) -> Result:
    """Register ``source`` onto ``target`` from the guess ``T_init`` (T_target_source, default identity).

    ``listener`` receives every :class:`~core.events.Event`; it may raise :class:`Cancelled` to stop
    early (the result is then the best pose so far). ``problem``: one prepared already for this pair
    and guess (it is only read, so it may be shared by several runs). ``frame``: ``config.lock`` bound
    elsewhere (the global pipeline binds it once, at the guess, for every stage).
    """
    config.validate()
    if config.method == "global":
        from .global_search import register_global  # it runs this front's hybrid in its last step

        return register_global(source, target, T_init, config, listener)
    t0 = time.perf_counter()
    problem = problem or prepare(source, target, T_init, config.problem, seed=config.seed)
    threshold = threshold_for(problem, config)
    state = SearchState(problem, config, listener, frame)
    state.start_at(start_pose(problem, config))
    rounds: list[Round] = []
    try:
        search_rounds(state, threshold, rounds)
        if config.polish:
            polish(state, rounds)
    except Cancelled:
        rounds.append(cancelled(state))
    best = best_round(rounds)
    return Result(best.T, best.error, dict(state.n), state.local_minima, state.evaluations,
                  time.perf_counter() - t0, config.method, threshold, best.stop, cut=problem.cut)


def start_pose(problem: Problem, config: Config) -> np.ndarray:
    """Where the search begins: the guess the overlap was cut under (paper section 2.1). The search
    region is centred on the pose the problem was cut at, so a start elsewhere brings its own cut."""
    return problem.T_init
