"""When no candidate is trusted: the paper's hybrid round the best one, within a bound on its steps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..problem import prepare
from ..result import Stop, StopReason
from ..search.run import run_method
from .refinement import Found, best_refined
from .setup import Setup
from .stream import EventStream


def fallback(setup: Setup, run: EventStream, found: Found) -> tuple[np.ndarray, Stop, int]:
    """Nothing trusted: the paper's hybrid round the best refined pose within the bound; the lower score
    (a pose the hybrid found is recorded in ``found`` as its). Returns the pose, why the search stopped and
    the local minima the hybrid's ICP ended in."""
    cc, pc = setup.config.candidates, setup.config.problem
    best, best_s = best_refined(setup, found.refined or [setup.T_guess])
    if cc.fallback_steps == 0 or setup.out_of_time():
        return best, Stop(StopReason.TIME_BOUND, _bound_text(setup, "before the hybrid could start")), 0
    # the candidates covered the stated region; the paper's hybrid searches round the best of them
    local = replace(pc, rotation_uncertainty_deg=min(pc.rotation_uncertainty_deg, cc.refine_rotation_deg),
                    translation_uncertainty=min(setup.problem.translation_uncertainty,
                                                cc.local_translation * setup.target.size))
    hybrid = replace(setup.config, method="hybrid", problem=local)
    problem = prepare(setup.source, setup.target, best, local, surface=setup.surface, seed=hybrid.seed)
    run.steps_left = cc.fallback_steps
    res = run_method(setup.source, setup.target, best, hybrid, run.forward, problem=problem, frame=setup.frame)
    bounded = res.stop_reason is StopReason.CANCELLED and (run.steps_left == 0 or setup.out_of_time())
    run.steps_left = None
    where = "the hybrid from the best candidate"
    if setup.score(res.transform) < best_s:
        best = res.transform
        found.note(best, "hybrid")
        if setup.trusted(best):  # the bounded hybrid crossed the pair threshold after all
            return best, Stop(StopReason.TRUSTED, f"{StopReason.TRUSTED.value} by {where}"), res.local_minima
        text = _bound_text(setup, where) if bounded else f"{where}: {res.stop_text}"
    else:
        text = (_bound_text(setup, where) if bounded else f"{where}: {res.stop_text}") + \
            "; the refined candidate scores lower on the fixed basis"
    return best, Stop(StopReason.TIME_BOUND if bounded else res.stop_reason, text), res.local_minima


def _bound_text(setup: Setup, where: str) -> str:
    cc = setup.config.candidates
    bound = " and ".join(([f"{cc.fallback_steps} steps"] if cc.fallback_steps is not None else [])
                         + ([f"{cc.time_limit:g} s"] if cc.time_limit is not None else []))
    return f"nothing trusted within the search's bound ({bound}; {where}): the best scored pose"


