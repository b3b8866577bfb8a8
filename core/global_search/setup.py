"""The global method's setup, made once a run: the overlap cut under the guess, the pair's noise floor,
its fixed scoring basis and pair threshold (core.threshold), the stated region (core.region), the lock's
frame, and KISS-Matcher's hypotheses started ahead."""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from ..candidates import Basis, CandidateConfig, feature_spacing
from ..config import Config
from ..guess import Guess
from ..kiss_matcher_candidates import kiss_available, kiss_candidates
from ..lock import LockFrame
from ..noise import noise_floors_ahead
from ..problem import Problem, check_registrable, prepare
from ..region import Region
from ..scan import Scan
from ..search.budget import Budget
from ..surface import Surface
from ..threshold import PairThreshold
from ..verdict import Judge, floor_queries, judge


@dataclass(frozen=True, eq=False)
class Setup:
    """Everything the stages share, made once: the pair, the cut under the guess, the basis, the
    threshold, the region, the lock's frame (or None), KISS-Matcher's hypotheses started ahead."""

    source: Scan
    target: Scan
    config: Config
    problem: Problem  # the overlap cut under the guess
    basis: Basis
    threshold: PairThreshold
    region: Region
    frame: LockFrame | None
    ahead: Future | None
    t0: float

    @property
    def judge(self) -> Judge:
        return Judge(self.basis, self.threshold)

    @property
    def surface(self) -> Surface:
        return self.problem.surface

    @property
    def guess(self) -> Guess:
        return self.problem.guess

    @property
    def T_guess(self) -> np.ndarray:
        return self.problem.T_init

    def trusted(self, T: np.ndarray) -> bool:
        return self.threshold.holds(self.basis, T)

    def settled_somewhere(self, T: np.ndarray) -> bool:
        """Whether pose T (4, 4) matches at least ``settle_share`` of the basis (a refinement's first leg has
        settled somewhere: core.candidates.CandidateConfig)."""
        share = self.config.candidates.settle_share
        return share <= 0 or float(self.basis.evaluate(np.asarray(T)[None]).inliers[0]) >= share

    def score(self, T: np.ndarray) -> float:
        return float(self.basis.evaluate(np.asarray(T)[None]).score[0])

    def budget(self, clock=None) -> Budget:
        """The search's bound on work (and seconds, when asked for), from now on: the setup is not charged."""
        cc = self.config.candidates
        return Budget(cc.search_steps, cc.max_candidates, cc.time_limit, **({} if clock is None else {"clock": clock}))


def kiss_ahead(source: Scan, target: Scan, cc: CandidateConfig) -> Future | None:
    """KISS-Matcher's hypotheses, started on a thread of their own (None when it is off or not installed).
    The thread makes the voxel clouds and waits on core.kiss_matcher_candidates' child process, which runs
    on the other core while this one makes the setup (the same inputs, so the same hypotheses); a run
    trusted before its stage leaves them unread."""
    if not (cc.enabled and cc.kiss_matcher and kiss_available()):
        return None
    pool = ThreadPoolExecutor(1, thread_name_prefix="kiss-matcher")
    future = pool.submit(kiss_candidates, source, target, feature_spacing(source, target), max(cc.fpfh_voxels))
    pool.shutdown(wait=False)
    return future


def prepare_setup(source: Scan, target: Scan, guess: Guess | np.ndarray | None, config: Config,
                  surface: Surface | None = None) -> Setup:
    """The cut under the guess, the basis, the pair threshold and the region (module notes: setup);
    ``surface``: the target's, when triangulated already."""
    t0 = time.perf_counter()
    cc, pc = config.candidates, config.problem
    guess = Guess.of(guess)
    check_registrable(source, target)  # before any thread or process starts on them
    # KISS-Matcher's hypothesis is scored beside the guess when the rotation is stated wider than
    # guess_first_deg (.stages): then it starts first, on the other core. Else it is wanted only when the
    # guess alone is not trusted (at 5-15 deg, 6 of 60 sweep runs), and is made then (.stages.matched):
    # started ahead, it took the other core from the setup's threads and the guess's refinement (the
    # bunny's 5-15 deg starts, load ~6: wall median 0.51 s started ahead, 0.47 s made when wanted).
    ahead = kiss_ahead(source, target, cc) if guess.rotation_deg > cc.guess_first_deg else None
    # the pair's noise floors, measured on a thread while this one triangulates the target and cuts the
    # overlap (the surface's query structure built on a third meanwhile); they are measured with as many
    # queries as the cut's sample holds, which is the most a sample holds unless the cut is small
    rng = np.random.default_rng(config.seed)
    n_floor = floor_queries(pc.max_points)
    floors = noise_floors_ahead([source, target], rng, n_floor)
    surface = (surface if surface is not None else Surface.from_scan(target)).warm()
    problem = prepare(source, target, guess, pc, surface=surface, seed=config.seed)
    if floor_queries(pc.max_points, int(problem.used.sum())) != n_floor:
        rng = np.random.default_rng(config.seed)
        floors = noise_floors_ahead([source, target], rng, floor_queries(pc.max_points, int(problem.used.sum())))
    # A lock (core.lock) is bound once, at the guess: every candidate is moved onto the allowed set
    # before it is scored, and every refinement and the hybrid walk the same free coordinates.
    frame = config.lock.bind(problem.T_init, problem.center, problem.scale) if config.lock.active else None
    pair = judge(source, target, problem.surface, float(np.mean(floors())), rng, config, frame)
    region = guess.region(source, target)
    return Setup(source, target, config, problem, pair.basis, pair.threshold, region, frame, ahead, t0)


