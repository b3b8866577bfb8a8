"""The stop threshold (paper section 2.3: ICP's result is accepted when E falls below it).

E at perfect registration is not zero: two noisy samplings of one surface leave a floor
(``core.noise``); the threshold is a measured multiple of it (``ThresholdConfig.factor``).
"""

from __future__ import annotations

import numpy as np

from .config import Config, ThresholdConfig
from .noise import noise_floor
from .problem import Problem


def estimate_threshold(problem: Problem, seed: int = 0, config: ThresholdConfig = ThresholdConfig()) -> float:
    """E expected at perfect registration (squared units): ``config.factor`` x the noise floor of
    two noisy samplings of one surface (see core.noise), drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    floors = [noise_floor(s, rng, len(problem.points)) for s in (problem.source, problem.target)]
    return config.factor * float(np.mean(floors))


def threshold_for(problem: Problem, config: Config) -> float:
    """The run's threshold: as given, or estimated from the scans' noise."""
    if config.threshold is not None:
        return config.threshold
    return estimate_threshold(problem, config.seed, config.threshold_estimate)
