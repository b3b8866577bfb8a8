"""When no candidate is trusted: the paper's hybrid round the best one, within a bound on its steps."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..result import Stop, StopReason
from ..search.run import run_method
from .refine import Found, best_refined
from .setup import Setup
from .stream import EventStream


def fallback(setup: Setup, run: EventStream, found: Found) -> tuple[np.ndarray, float, Stop]:
    """Nothing trusted: the paper's hybrid round the best refined pose within the bound; the lower score
    (a pose the hybrid found is recorded in ``found.by`` as its)."""
    cc, pc = setup.config.candidates, setup.config.problem
    best, best_s = best_refined(setup, found.refined or [setup.T_guess])
    if cc.fallback_steps == 0 or setup.out_of_time():
        return best, best_s, Stop(StopReason.TIME_BOUND, _bound_text(setup, "before the hybrid could start"))
    # the candidates covered the stated region; the paper's hybrid searches round the best of them
    local = replace(pc, rotation_uncertainty_deg=min(pc.rotation_uncertainty_deg, cc.refine_rotation_deg),
                    translation_uncertainty=min(setup.problem.translation_uncertainty,
                                                cc.local_translation * setup.target.size))
    run.steps_left = cc.fallback_steps
    res = run_method(setup.source, setup.target, best, replace(setup.config, method="hybrid", problem=local),
                     run.forward, frame=setup.frame)
    bounded = res.stop_reason is StopReason.CANCELLED and (
        (run.steps_left is not None and run.steps_left < 0) or setup.out_of_time())
    run.steps_left = None
    s_h = setup.score(res.transform)
    where = "the hybrid from the best candidate"
    text = _bound_text(setup, where) if bounded else f"{where}: {res.stop_text}"
    if s_h < best_s:
        best, best_s = res.transform, s_h
        found.by[id(best)] = "hybrid"
    else:
        text += "; the refined candidate scores lower on the fixed basis"
    return best, best_s, Stop(StopReason.TIME_BOUND if bounded else res.stop_reason, text)


def _bound_text(setup: Setup, where: str) -> str:
    cc = setup.config.candidates
    bound = " and ".join(([f"{cc.fallback_steps} steps"] if cc.fallback_steps is not None else [])
                         + ([f"{cc.time_limit:g} s"] if cc.time_limit is not None else []))
    return f"nothing trusted within the search's bound ({bound}; {where}): the best scored pose"


