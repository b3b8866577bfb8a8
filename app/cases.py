"""A registration case the benchmarks run (``rangereg bench`` and its ``--sweep``): a pair, its truth, the
spread of the starts and the success rule."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from rangereg.core.guess import Guess
from rangereg.core.problem import ProblemConfig
from rangereg.core.scan import Scan


@dataclass(frozen=True, eq=False)
class Case:
    """``source`` registered onto ``target``; ``T_true`` (4, 4) T_target_source. Starts: the truth moved by
    ``rot_deg`` degrees and ``trans`` units; success: within ``ok_rot`` degrees and ``ok_trans`` units
    (at the source's centroid). ``problem``: the overlap cut; ``stated``: the uncertainty the method is told
    (core.guess.Guess, about each start)."""

    name: str
    source: Scan
    target: Scan
    T_true: np.ndarray
    rot_deg: float
    trans: float
    ok_rot: float
    ok_trans: float
    problem: ProblemConfig
    stated: Guess = field(default_factory=Guess.identity)
