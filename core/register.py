"""Register one scan onto another: the public front (Luck et al., ICRA 2000, Fig. 6 and around it).

    global     method "global" (the CLI's default): candidates -> the best few ICP-refined -> the
               hybrid from the best, within a bound -> the lowest on the pair's fixed basis
               (core.global_search), in the region the user stated (core.region)
    paper      any other method: prepare (section 2.1), threshold (2.3), the search of Fig. 6 or a
               baseline, in rounds over overlap cuts (core.search.run)

The knobs are in core.config, one frozen config per concern.
"""

from __future__ import annotations

import numpy as np

from .config import METHODS, Config
from .events import Listener
from .global_search import register_global
from .lock import LockFrame
from .problem import Problem
from .result import Result, Stop, StopReason
from .scan import Scan
from .search import recut
from .search.run import run_method
from .threshold import estimate_threshold

__all__ = ["METHODS", "Config", "Result", "Stop", "StopReason", "estimate_threshold", "recut", "register"]


def register(source: Scan, target: Scan, T_init: np.ndarray | None = None, config: Config = Config(),
             listener: Listener | None = None, problem: Problem | None = None,
             frame: LockFrame | None = None) -> Result:
    """Register ``source`` onto ``target`` from the guess ``T_init`` (T_target_source, default identity).

    ``listener`` receives every :class:`~core.events.Event`; it may raise :class:`Cancelled` to stop
    early (the result is then the best pose so far). ``problem``: one prepared already for this pair
    and guess (it is only read, so it may be shared by several runs; the paper's methods only).
    ``frame``: ``config.lock`` bound elsewhere (the paper's methods only).
    """
    config.validate()
    if config.method == "global":
        return register_global(source, target, T_init, config, listener)
    return run_method(source, target, T_init, config, listener, problem, frame)
