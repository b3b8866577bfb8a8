"""The stop threshold (paper section 2.3: ICP's result is accepted when E falls below it).

Two thresholds live here: the paper's (a multiple of the noise floor on E, for the paper's methods) and
the pair threshold of the ``global`` method, on the candidates' fixed basis (below).

E at perfect registration is not zero: two noisy samplings of one surface leave a floor
(``core.noise``); the threshold is a measured multiple of it (``ThresholdConfig.factor``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .candidates import Basis, Scores
from .config import Config, ThresholdConfig
from .noise import noise_floors
from .problem import Problem


def estimate_threshold(problem: Problem, seed: int = 0, config: ThresholdConfig = ThresholdConfig()) -> float:
    """E expected at perfect registration (squared units): ``config.factor`` x the noise floor of
    two noisy samplings of one surface (see core.noise), drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    floors = noise_floors([problem.source, problem.target], rng, len(problem.points))
    return config.factor * float(np.mean(floors))


def threshold_for(problem: Problem, config: Config) -> float:
    """The run's threshold: as given, or estimated from the scans' noise."""
    if config.threshold is not None:
        return config.threshold
    return estimate_threshold(problem, config.seed, config.threshold_estimate)


# ---- the pair threshold (method "global", issue 13) --------------------------------------------------
# A stop threshold from the pair itself, on the candidates' fixed basis (beyond the paper; issue 13).
#
# "Trust this pose" means: the source overlaps the target by at least the basis's minimum both ways,
# and the points that match (inside the target's frustum, within the basis's cap) match at the level
# of the scanner's noise: their median squared distance is below ``FACTOR`` x the pair's noise floor
# (core.noise: two noisy samplings of one surface, averaged over both scans). The median, because a
# registration's overlap holds points without a partner (holes, the overlap's fringe) whatever the pose.
#
# Two numbers are fitted, on the five shared bunny pairs and the bowl (benchmarks/threshold_evidence.py,
# 20 starts 20-120 deg off per case, a 160-point basis; it prints every case). Left out: the wing (E is
# flat along its panel by design) and the corner (its twin turned 120 deg about the corner's diagonal
# fits at the noise level: no test of one pose tells them apart; the basis's score ranks the truth first).
# - MIN_TRUST_OVERLAP: the matched share at the truth is >= 0.34 on the bunny pairs (bun090->bun000
#   the lowest), >= 0.74 on the bowl; wrong minima match <= 0.19 of the sample on the bunny except one of
#   0.31 on bun090->bun045 (its median is 9.8 x the floor: the median test rejects it).
# - FACTOR: at the truth the matched median is 2.4-5.8 x the floor on the bunny (a range bias between
#   views that one scan's own noise does not show), 0.9 x on the bowl. With 20 starts a case the nearest
#   wrong minimum that passed the overlap test lay at 8.6 x (bowl, 12 deg off: it slides over itself)
#   and 10.2 x (bun090->bun045); FACTOR is the geometric mean of 5.8 and 8.6, and fitted with one case
#   left out it ranged 5.5-7.7. KNOWN TO FAIL ON THE BOWL: with 40 starts a case the bowl has a wrong
#   minimum at 5.7 x (29 deg, 51 mm off; the Horn-step refinement finds one at 5.8 x, 32 deg off), below
#   FACTOR, while no bunny wrong minimum passes the overlap test. The median ratio alone cannot tell the
#   bunny's biased truths (up to 5.8 x) from the bowl's sliding twins (from 5.7 x): a bowl refinement
#   that ends in that valley within REGION x the stated uncertainty is trusted. Kept at 7 for the real
#   scans (the sweep's "trust" was right in every run); a statistic that separates both is open work.
#   (benchmarks/threshold_evidence.py --starts 40 prints all of it.)
# A pose that fails is not called wrong; it is not promised right. On unseen real scans whose bias is
# larger, the test says "do not trust" more often, and the pipeline then runs the hybrid.
FACTOR = 7.0  # see the notes above and benchmarks/threshold_evidence.py
# A pose is trusted only when this share of the source sample matches (notes above): a wrong pose
# where ICP fitted a small patch well passes the median test (bun090->bun000 from 165 deg: 5 % matched)
MIN_TRUST_OVERLAP = 0.3


@dataclass(frozen=True)
class PairThreshold:
    """value: the bound on the median matched d^2 (squared units); floor: the pair's noise floor;
    factor: value / floor; min_overlap: share of each scan's sample the other must cover."""

    value: float
    floor: float
    factor: float
    min_overlap: float
    derivation: str = ("median matched d^2 on the fixed basis < factor x noise floor; >= 30 % of the source "
                        "sample matched; overlap both ways")

    def to_json(self) -> dict:
        return {"value": self.value, "floor": self.floor, "factor": self.factor, "min_overlap": self.min_overlap,
                "derivation": self.derivation}

    def holds(self, basis: Basis, T: np.ndarray) -> bool:
        """Whether pose T (4, 4) passes: trust it."""
        return bool(self.passes(basis.evaluate(np.asarray(T)[None]), basis)[0])

    def passes(self, s: Scores, basis: Basis) -> np.ndarray:
        return basis.valid(s) & (s.inliers >= MIN_TRUST_OVERLAP) & (s.inlier_median < self.value)


def pair_threshold(floor: float, min_overlap: float, factor: float = FACTOR) -> PairThreshold:
    return PairThreshold(float(factor * floor), float(floor), float(factor), float(min_overlap))
