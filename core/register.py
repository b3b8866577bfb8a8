"""Register one scan onto another: the public front (Luck et al., ICRA 2000, Fig. 6 and around it).

    global     method "global" (the CLI's default): candidates -> the best few ICP-refined -> the
               hybrid from the best, within a bound -> the lowest on the pair's fixed basis
               (core.global_search), in the region the user's guess states (core.guess, core.region)
    paper      any other method: prepare (section 2.1), threshold (2.3), the search of Fig. 6 or a
               baseline, in rounds over overlap cuts (core.search.run)

The knobs are in core.config, one frozen config per concern.
"""

from __future__ import annotations

import numpy as np

from .config import METHODS, Config
from .events import Listener
from .global_search import register_global
from .guess import Guess
from .lock import LockFrame
from .problem import Problem, prepare
from .result import Result, Stop, StopReason
from .scan import Scan
from .search import recut
from .search.run import run_method
from .surface import Surface
from .threshold import estimate_threshold

__all__ = ["METHODS", "Config", "Guess", "Result", "Stop", "StopReason", "estimate_threshold", "recut", "register"]


def register(source: Scan, target: Scan, guess: Guess | np.ndarray | None = None, config: Config = Config(),
             listener: Listener | None = None, problem: Problem | None = None,
             frame: LockFrame | None = None, surface: Surface | None = None) -> Result:
    """Register ``source`` onto ``target`` from ``guess`` (core.guess: the pose T_target_source and how far off
    it may be; a (4, 4) pose: with the default uncertainty; None: the identity).

    ``listener`` receives every :class:`~core.events.Event`; it may raise :class:`Cancelled` to stop
    early (the result is then the best pose so far). ``problem``: one prepared already for this pair
    and guess (the paper's methods; it is only read, so it may be shared by several runs). ``frame``:
    ``config.lock`` bound elsewhere (the paper's methods). ``surface``: the target's triangulated surface,
    when made already.
    """
    config.validate()
    guess = Guess.of(guess)
    if config.method == "global":
        return register_global(source, target, guess, config, listener, surface)
    if problem is None and surface is not None:
        problem = prepare(source, target, guess, config.problem, surface=surface, seed=config.seed)
    return run_method(source, target, guess, config, listener, problem, frame)
