"""When no candidate is trusted: the paper's hybrid round the best one, on its share of the search's budget."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..guess import Guess
from ..problem import prepare
from ..result import Stop, StopReason
from ..search.run import run_method
from .refinement import Found, best_refined
from .setup import Setup
from .stream import EventStream

BOUNDS = (StopReason.WORK_BOUND, StopReason.TIME_BOUND)


def fallback(setup: Setup, run: EventStream, found: Found) -> tuple[np.ndarray, Stop, int]:
    """Nothing trusted: the paper's hybrid round the best refined pose on at most ``fallback_steps`` of what
    the budget has left; the lower score (a pose the hybrid found is recorded in ``found`` as its). Returns the
    pose, why the search stopped and the local minima the hybrid's ICP ended in."""
    cc = setup.config.candidates
    best, best_s = best_refined(setup, found.refined or [setup.T_guess])
    spent = found.stopped or run.budget.spent()
    if cc.fallback_steps == 0 or spent is not None:
        why = spent or Stop(StopReason.WORK_BOUND, f"{StopReason.WORK_BOUND.value}: the hybrid has no steps")
        return best, Stop(why.reason, f"{why}; before the hybrid could start: the best scored pose"), 0
    # the candidates covered the stated region; the paper's hybrid searches round the best of them
    local = Guess(best, min(setup.guess.rotation_deg, cc.refine_rotation_deg),
                  min(setup.problem.translation_uncertainty, cc.local_translation * setup.target.size))
    hybrid = replace(setup.config, method="hybrid")
    problem = prepare(setup.source, setup.target, local, hybrid.problem, surface=setup.surface, seed=hybrid.seed)
    where = "the hybrid from the best candidate"
    share = run.budget.share(cc.fallback_steps, where)
    res = run_method(setup.source, setup.target, local, hybrid, run.forward, problem=problem, frame=setup.frame,
                     budget=share, judged=False)
    if setup.score(res.transform) < best_s:
        best = res.transform
        found.note(best, "hybrid")
        if setup.trusted(best):  # the bounded hybrid crossed the pair threshold after all
            return best, Stop(StopReason.TRUSTED, f"{StopReason.TRUSTED.value} by {where}"), res.local_minima
        text = f"{res.stop_text}" if res.stop_reason in BOUNDS else f"{where}: {res.stop_text}"
    else:
        text = (f"{res.stop_text}" if res.stop_reason in BOUNDS else f"{where}: {res.stop_text}") + \
            "; the refined candidate scores lower on the fixed basis"
    return best, Stop(res.stop_reason, text), res.local_minima
