"""The pair threshold's verdict on a pose, whichever method found it (core.threshold).

    judge      the pair's noise floor, its fixed scoring basis and its pair threshold, made once a pair: the
               global method's setup makes it for its search (core.global_search.setup), the paper's methods
               for the pose they end at (:func:`judge_pair`, with the same seeded draws, so one pose of one pair
               gets one verdict whichever method found it)
    verdict    the test at one pose (core.result.Verdict): the misfit at the noise level, the share of points
               where the other's sensor looked through, what the matched overlap pins

The paper trusts a pose whose E ends below the threshold (section 2.3), and its methods stop there as the paper's
do. But E is minimised on its own sample, so it cannot tell a pose the sample fits from one the scans fit: a sample
of 5-20 points (``--max-points``) fits wrong poses of the corner, ribbed and bowl scenes below the threshold (3-4
of 4 seeds from their stored guesses), and an overlap that lets the pose slide fits every slide alike (the wing
5.8 deg / 183 mm along its panel at the default 300 points, a trough along its axis). So the paper's methods say
"trust yes" only where the pair threshold's test, on its fixed basis of other points, holds as well (measured
2026-12-08: docs/benchmarks.md, "Trust, whichever method").
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass

import numpy as np

from .candidates import Basis, Scores, make_basis
from .config import Config
from .intrusion import intrusion, max_intrusion_of
from .lock import LockFrame
from .noise import noise_floors_ahead
from .problem import Problem
from .result import Verdict
from .scan import Scan
from .surface import Surface
from .threshold import FreeMotions, PairThreshold, constraint, min_constraint_of, pair_threshold

# The noise floor behind the pair threshold is measured with at least this many queries (the default sample's size,
# core.problem.ProblemConfig.max_points), or the overlap cut's points where it holds fewer: measured with a
# ``--max-points`` sample of 5-20 points it spread 2.6-8 x across seeds (1.4 x at 300), least calibrated where a
# small sample most needs the test (2026-12-08, on the generated corner).
FLOOR_QUERIES = 300


@dataclass(frozen=True, eq=False)
class Judge:
    """The pair threshold (core.threshold.PairThreshold) and the fixed basis it scores poses on
    (core.candidates.Basis)."""

    basis: Basis
    threshold: PairThreshold

    def verdict(self, T: np.ndarray, scores: Scores | None = None) -> Verdict:
        """The test at pose T (4, 4) T_target_source; ``scores``: T's on the basis, when evaluated already."""
        T = np.asarray(T, dtype=np.float64)
        s = self.basis.evaluate(T[None]) if scores is None else scores
        misfit = self.threshold.misfit(self.basis, T, s)
        holds = self.threshold.holds(self.basis, T, s, misfit)
        return Verdict(self.threshold, misfit if np.isfinite(misfit) else None,
                       constraint(self.basis, T, self.threshold.free), intrusion(self.basis, T), holds)


def floor_queries(max_points: int, cut_points: int | None = None) -> int:
    """How many queries measure the pair's noise floor: ``max_points`` (the sample's size), at least FLOOR_QUERIES,
    at most ``cut_points`` (the overlap cut's points; None: not cut yet)."""
    n = max(int(max_points), FLOOR_QUERIES)
    return n if cut_points is None else min(n, int(cut_points))


def judge(source: Scan, target: Scan, surface: Surface, floor: float, rng: np.random.Generator,
          config: Config, frame: LockFrame | None = None) -> Judge:
    """The Judge of a pair whose noise floor (squared units, core.noise) is measured: the basis drawn with ``rng``
    (after the floor's draws), the target's ``surface``; ``frame``: the lock bound for the search (its free motions
    are all the constraint asks about), or None."""
    cc = config.candidates
    basis = make_basis(source, target, surface, floor, rng, cc, config.problem.frustum)
    threshold = pair_threshold(floor, basis.angle_floor, cc.min_overlap, min_constraint=min_constraint_of(target),
                               max_intrusion=max_intrusion_of(source, target), free=FreeMotions.of(frame))
    return Judge(basis, threshold)


def judge_pair(source: Scan, target: Scan, surface: Surface, config: Config, cut_points: int,
               frame: LockFrame | None = None) -> Judge:
    """The Judge the global method's setup makes for this pair, with its seeded draws in its order (the floor's
    :func:`floor_queries`, then the basis, from ``config.seed``'s generator): ``cut_points`` the overlap cut's
    points; ``frame`` the lock bound for the search. The same as the setup's where the global method searches these
    scans themselves, not copies thinned above core.candidates.SEARCH_POINTS (the paper's methods judge the whole
    scans)."""
    rng = np.random.default_rng(config.seed)
    n = floor_queries(config.problem.max_points, cut_points)
    floor = float(np.mean(noise_floors_ahead([source, target], rng, n)()))
    return judge(source, target, surface, floor, rng, config, frame)


# The Judge of a prepared problem, kept while the problem lives: the workbench shares one problem across the runs of
# a pair (core.register's ``problem=``), and the judge, drawn from the seed alone, is the same for each of them
# (0.1-0.5 s a run on the scenes and the bunny; a run with another seed, lock or sample size makes its own).
_JUDGES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_JUDGES_LOCK = threading.Lock()


def judge_of(problem: Problem, config: Config, frame: LockFrame | None = None) -> Judge:
    """:func:`judge_pair` of ``problem``'s pair, its surface and its overlap cut, made once per problem for each
    seed, candidate config, sample size, frustum and lock."""
    free = FreeMotions.of(frame)
    key = (config.seed, repr(config.candidates), config.problem.max_points, config.problem.frustum,
           None if free is None else free.key)
    with _JUDGES_LOCK:
        made = _JUDGES.setdefault(problem, {}).get(key)
    if made is None:
        made = judge_pair(problem.source, problem.target, problem.surface, config, int(problem.used.sum()), frame)
        with _JUDGES_LOCK:
            _JUDGES.setdefault(problem, {})[key] = made
    return made
