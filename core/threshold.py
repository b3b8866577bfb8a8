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


# ---- the pair threshold (method "global") ---------------------------------------------------------------
# A stop threshold from the pair itself, on the candidates' fixed basis (beyond the paper).
#
# "Trust this pose" means: the source overlaps the target by at least the basis's minimum both ways,
# at least MIN_TRUST_OVERLAP of the source sample matches (inside the target's frustum, within the
# basis's cap), and where it matches the two scans agree at the level of the scanner's noise, in
# distance and in shape: the misfit
#     sqrt(median matched d^2 / the pair's noise floor) x (median normal angle / the pair's angle floor)
# is below FACTOR: distance and angle, each over its noise level, multiplied. The floors are two noisy
# samplings of one surface (core.noise: the d^2 of one half of a scan against the other half's surface;
# the angle between normals fitted to interleaved halves of a neighbourhood), so each ratio is ~1 at a
# perfect registration of noise-only scans. The median, because a registration's overlap holds points
# without a partner (holes, the overlap's fringe) whatever the pose.
# The product, because neither ratio alone separates: real scans carry a range bias between views that
# one scan's own noise does not show (distance 1.6-2.4 x at the bunny truths; d^2 2.4-5.8 x) while their
# normals agree (angle 0.9-1.4 x); a twin sliding over itself (the bowl turned about its axis) fits in
# distance (from 2.0 x; d^2 4.0 x) but tilts the normals (2.9 x and more); a surface laid parallel
# beside the right one keeps the normals, and the distance alone must reject it (from 4.5 x its floor).
#
# Measured (benchmarks/threshold_evidence.py --starts 40, which prints every case: per case 40 seeded
# starts 20-120 deg off plus the truth turned about each principal axis by 20-90 deg, refined as the
# pipeline refines; wrong minima counted when >= the basis's minimum overlap (10 %) matches) on the five
# shared bunny pairs and the bowl: the misfit at the truths is 1.0 (bowl) to 3.2 (bun315->bun045); the
# nearest wrong minima lie at 6.3 (bun090->bun045, 12 % matched, distance 3.3 x, angle 1.9 x) and 7.3
# (bowl, 3.8 deg and 19 mm off, 71 % matched: distance 2.5 x, angle 2.9 x). FACTOR is their geometric
# mean (4.46); fitted with each case left out it ranges 4.0-4.8, and every left-out case keeps its truth
# below and its nearest wrong minimum above it. Left out of the fit: the wing (E is flat along its panel
# by design) and the corner (its twin turned 120 deg about the corner's diagonal fits at the noise level:
# no test of one pose tells them apart; the basis's score ranks the truth first).
# - MIN_TRUST_OVERLAP: the matched share at the truth is >= 0.34 on the bunny pairs (bun090->bun000
#   the lowest), >= 0.74 on the bowl; the bunny's wrong minima match <= 0.31 of the sample.
# A pose that fails is not called wrong; it is not promised right. On unseen real scans whose bias is
# larger, the test says "do not trust" more often, and the pipeline then runs the hybrid.
FACTOR = 4.5  # see the notes above and benchmarks/threshold_evidence.py
# A pose is trusted only when this share of the source sample matches (notes above): a wrong pose
# where ICP fitted a small patch well can fit it at the noise level (bun090->bun000 from 165 deg, 5 %
# matched, passes a test of the distance alone)
MIN_TRUST_OVERLAP = 0.3


@dataclass(frozen=True)
class PairThreshold:
    """value: the bound on the median matched d^2 (squared units) where the normals agree at their floor;
    floor: the pair's noise floor (squared units); angle_floor: its normals' (degrees); factor: the bound
    on the misfit (notes above); min_overlap: share of each scan's sample the other must cover."""

    value: float
    floor: float
    factor: float
    min_overlap: float
    angle_floor: float
    derivation: str = ("sqrt(median matched d^2 / noise floor) x (median normal angle / angle floor) < factor on "
                       "the fixed basis; >= 30 % of the source sample matched; overlap both ways")

    def to_json(self) -> dict:
        return {"value": self.value, "floor": self.floor, "angle_floor_deg": self.angle_floor, "factor": self.factor,
                "min_overlap": self.min_overlap, "derivation": self.derivation}

    def misfit(self, basis: Basis, T: np.ndarray, scores: Scores | None = None) -> float:
        """sqrt(median matched d^2 / floor) x (median normal angle / angle floor) at pose T (4, 4), whatever
        its overlap (notes above); inf when fewer than 3 points match or a floor is 0. ``scores``: T's
        on ``basis``, when evaluated already."""
        s = basis.evaluate(np.asarray(T)[None]) if scores is None else scores
        if not (self.floor > 0 and self.angle_floor > 0):  # too few points to measure a noise level
            return float("inf")
        with np.errstate(divide="ignore", invalid="ignore"):
            m = np.sqrt(s.inlier_median[0] / self.floor) * (basis.normal_angle(T) / self.angle_floor)
        return float(m) if np.isfinite(m) else float("inf")

    def holds(self, basis: Basis, T: np.ndarray, scores: Scores | None = None, misfit: float | None = None) -> bool:
        """Whether pose T (4, 4) passes: it overlaps enough (notes above) and its misfit is below the factor
        (``scores``, ``misfit``: T's, when computed already)."""
        s = basis.evaluate(np.asarray(T)[None]) if scores is None else scores
        if not (basis.valid(s)[0] and s.inliers[0] >= MIN_TRUST_OVERLAP):
            return False
        return bool((self.misfit(basis, T, s) if misfit is None else misfit) < self.factor)


def pair_threshold(floor: float, angle_floor: float, min_overlap: float, factor: float = FACTOR) -> PairThreshold:
    return PairThreshold(float(factor ** 2 * floor), float(floor), float(factor), float(min_overlap), float(angle_floor))
