"""The hybrid optimiser (paper Fig. 6) and its baselines, over one shared robust error.

    hybrid:  ICP -> E < threshold? stop : anneal from there -> better point? ICP again : stop
    icp:     ICP alone
    sa:      simplex annealing alone, from the initial pose down to the minimum temperature
    icp-restarts: ICP from random poses within the initial uncertainty until E < threshold or the
             restart budget runs out (Besl and McKay's suggestion, paper section 3)
    basin-hopping: beyond the paper. Annealing's job in the hybrid, new starting points for ICP, done
             by random hops from the best local minimum found so far, each followed by ICP; a lower
             minimum is kept (monotonic basin hopping, Wales and Doye 1997). Where the hybrid's
             annealing must find a pose *lower* than ICP's minimum, a hop only has to land in the
             catchment of a lower one: on the bowl, whose true well is narrow and sits at the end of a
             long valley (a bowl slides over itself by tilting), that is what succeeds.

Beyond the paper, off by default: ``polish`` (a final ICP with outliers dropped and no weights,
paper section 4) and ``coarse_to_fine`` (paper section 4: the search first runs on a smoother error
surface, here E with its outlier cap t widened 100 and then 10 times, so that a well whose walls
are flat beyond sqrt(t) - a plane hovering off its partner - pulls from farther away).

Beyond the paper, on by default: the overlap is cut again (section 2.1's frustum) at the pose the
search found and the search refines there with the small uncertainty left (``resegment``); annealing
and ICP stay within SEARCH_BOUND times the guess's uncertainty around the pose the cut was made at,
except the first ICP leg, which walks wherever E leads (as the paper's) and is taken again inside the
region only when it ends outside above the threshold (``_Run.first_icp``).

Off by default: ``recut_rounds`` > 1 (hybrid only) searches again with the full uncertainty from a
cut at the pose found, unless that cut is nearly the old one; the round whose pose has the lowest E
on the cut at its own pose wins. Measured (10 starts): bun090 -> bun000 (15 deg / 25 mm) 9/10 in
2.2 s median with 1 round or 2; bowl 0/10 either way, 2.4 -> 5.8 s. (Before annealing's simplex was
let roam: bun090 -> bun000 5/10 with 1 round, 6/10 with 2.)
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from .anneal import AnnealConfig, anneal
from .errors import InputError
from .events import Cancelled, Event, Listener
from .icp import IcpConfig, icp
from .noise import noise_floor
from .problem import Problem, ProblemConfig, prepare
from .scan import Scan
from .transforms import pose_error, random_perturbation, rotation_angle

METHODS = ("hybrid", "icp", "sa", "icp-restarts", "basin-hopping")
# threshold = this x the error two noisy samplings of one surface give. Measured E at the true pose:
# 0.6-0.9 x that floor on the simulated scenes, 4-5.5 x on the real Stanford scans (a view-dependent
# range bias between two scans that one scan's own noise cannot show); wrong minima: >= 24 x on bowl,
# >= 2000 x on the bunny pairs. 6 stops at the truth on both kinds of data and nowhere else measured.
THRESHOLD_FACTOR = 6.0
MIN_GAIN = 0.01  # annealing hands back a point at least 1 % below ICP's (no ping-pong on a plateau)
RESEGMENT_ROTATION_DEG = 2.0  # uncertainty assumed once a registration has converged
RESEGMENT_TRANSLATION = 0.02  # ... as a fraction of the target's size
COARSE_TO_FINE = (100.0, 10.0, 1.0)  # widenings of the robust cap t, coarse first
COARSE_THRESHOLD = 3.0  # coarse levels only need to come near: they stop below 3 x the threshold
SAME_CUT = 0.9  # a re-cut keeping this share of the points (Jaccard) is the same error: no new round
SEARCH_BOUND = 2.0  # ICP and annealing search within this many times the initial uncertainty of the guess
# basin-hopping hops this many times on the re-cut overlap, whatever E: the threshold sits above the
# near-misses round the true well on the bowl (measured: runs stopped 1-3 deg off with E below it);
# hops within the small uncertainty left find the well itself (bowl, 10 starts: 50 % -> 100 %).
CONFIRM_HOPS = 15


@dataclass(frozen=True)
class Config:
    method: str = "hybrid"
    threshold: float | None = None  # None: estimated from the scans' noise; 0: search until SA gives up
    seed: int = 0
    problem: ProblemConfig = field(default_factory=ProblemConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    anneal: AnnealConfig = field(default_factory=AnnealConfig)
    # annealing alone settles later (measured, corner, 10 starts: settle_below 0.1: 20 %, 0.01: 70 %)
    sa_alone: AnnealConfig = field(default_factory=lambda: AnnealConfig(t_min_ratio=1e-5, cooling=0.93, moves_per_temperature=25,
                                                                        settle_below=1e-2))
    restarts: int = 40  # icp-restarts budget (number of ICP runs)
    hops: int = 200  # basin-hopping budget (hops, each followed by ICP)
    # a hop moves up to this x the initial uncertainty in each of rotation and translation. Measured
    # (10 starts, bowl / bun090->bun000): 0.35: 50 / 70 %, 0.5: 90 / 70 %, 0.75: 90 / 70 %, 1: 100 / 70 %
    hop_size: float = 1.0
    simplex_scale: float = 1.0  # first simplex = this x the initial uncertainty
    polish: bool = False
    coarse_to_fine: bool = False
    resegment: bool = True  # re-cut the overlap at the pose found and refine from there
    recut_rounds: int = 1  # hybrid: search again from an overlap cut at the pose found, this many times at most

    def validate(self) -> None:
        if self.method not in METHODS:
            raise InputError(f"unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        if self.threshold is not None and not (np.isfinite(self.threshold) and self.threshold >= 0):
            raise InputError(f"threshold must be a number >= 0, got {self.threshold}")
        for a in (self.anneal, self.sa_alone):
            if not 0 < a.cooling < 1:
                raise InputError(f"cooling must be between 0 and 1, got {a.cooling}")
            if not 0 < a.t_min_ratio < 1:
                raise InputError(f"the minimum temperature ratio must be between 0 and 1, got {a.t_min_ratio}")
            if a.moves_per_temperature < 1 or a.max_evaluations < 7:
                raise InputError("annealing needs at least 1 move per temperature and 7 evaluations")
            if not 0 <= a.settle_below <= 1:
                raise InputError(f"settle_below must be between 0 and 1, got {a.settle_below}")
            if a.t_start is not None and not a.t_start > 0:
                raise InputError(f"the start temperature must be positive, got {a.t_start}")
        if self.icp.max_iterations < 1 or not self.icp.tolerance >= 0:
            raise InputError("ICP needs at least 1 iteration and a tolerance >= 0")
        if self.recut_rounds < 1:
            raise InputError(f"re-cut rounds must be at least 1, got {self.recut_rounds}")
        if self.restarts < 1:
            raise InputError(f"restarts must be at least 1, got {self.restarts}")
        if self.hops < 0 or not (np.isfinite(self.hop_size) and self.hop_size > 0):
            raise InputError(f"basin hopping needs hops >= 0 and a hop size > 0, got {self.hops} and {self.hop_size}")
        self.problem.validate()


@dataclass(frozen=True, eq=False)
class Result:
    """transform: (4, 4) T_target_source; error: final robust E (squared units)."""

    transform: np.ndarray
    error: float
    iterations: dict
    local_minima: int
    evaluations: int
    seconds: float
    method: str
    threshold: float
    stop_reason: str

    def __repr__(self) -> str:
        it = self.iterations
        return (f"Result({self.method}: E={self.error:.6g}, iterations icp={it['icp']} sa={it['sa']}, "
                f"local_minima={self.local_minima}, {self.seconds:.2f} s, stopped: {self.stop_reason})")

    def to_json(self) -> dict:
        return {"transform": self.transform.tolist(), "error": self.error, "iterations": dict(self.iterations),
                "local_minima": self.local_minima, "evaluations": self.evaluations, "seconds": self.seconds,
                "method": self.method, "threshold": self.threshold, "stop_reason": self.stop_reason}


def estimate_threshold(problem: Problem, seed: int = 0) -> float:
    """E expected at perfect registration: two noisy samplings of one surface (see core.noise)."""
    rng = np.random.default_rng(seed)
    floors = [noise_floor(s, rng, len(problem.points)) for s in (problem.source, problem.target)]
    return THRESHOLD_FACTOR * float(np.mean(floors))


class _Run:
    """One optimisation: counts iterations, emits events, keeps the best pose."""

    def __init__(self, problem: Problem, config: Config, listener: Listener | None):
        self.p, self.cfg, self.listener = problem, config, listener
        self.rng = np.random.default_rng(config.seed)
        self.n = {"icp": 0, "sa": 0}
        self.legs = {"icp": 0, "sa": 0}
        self.local_minima = 0
        self.start = problem.T_init  # where the method begins
        self.refining = False  # searching again on the overlap re-cut at the pose found (resegment)
        self.best_T, self.best_E = problem.T_init, np.inf

    def emit(self, phase, T, E, temperature=None, accepted=True, local_minimum=False, count=True):
        if count:
            self.n[phase] += 1
        if E < self.best_E:
            self.best_T, self.best_E = T, E
        if self.listener is not None:
            self.listener(Event(phase, self.n["icp"] + self.n["sa"], self.n[phase], self.legs[phase], T, E,
                                temperature, accepted, local_minimum))

    def inside(self, T) -> bool:
        """Whether pose T lies in the search region: SEARCH_BOUND x the guess's uncertainty around it."""
        p = self.p  # the norms of p.coords(T, p.T_init), without its matrix logarithm
        moved = (T[:3, :3] - p.T_init[:3, :3]) @ p.center + T[:3, 3] - p.T_init[:3, 3]
        return bool(np.linalg.norm(moved) <= SEARCH_BOUND * p.translation_uncertainty
                    and rotation_angle(T[:3, :3] @ p.T_init[:3, :3].T) <= SEARCH_BOUND * p.rotation_uncertainty)

    def icp(self, T, icp_config=None, bounded=True):
        self.legs["icp"] += 1
        start = self.n["icp"]
        res = icp(self.p.error, T, icp_config or self.cfg.icp, lambda T_, E: self.emit("icp", T_, E),
                  self.inside if bounded else None)
        if self.n["icp"] == start:  # no step taken: still report where ICP stands
            self.emit("icp", res.T, res.error, count=False)
        return res.T, res.error

    def first_icp(self, threshold):
        """ICP from the start, free to walk wherever E leads, as the paper's; a leg that ends outside
        the search region above the threshold is a minimum the guess rules out (bun090 -> bun000: 40-50
        deg off, where E on the cut under a poor guess can prefer it), so ICP again, kept inside."""
        T, E = self.icp(self.start, bounded=False)
        if E >= threshold and not self.inside(T):
            self.mark_local_minimum(T, E)
            self.best_T, self.best_E = self.start, np.inf  # ruled out: never the answer
            T, E = self.icp(self.start)
        return T, E

    def random_step(self, T, size: float):
        """T moved in a random direction by up to ``size`` x the guess's uncertainty in each of
        translation and rotation (uniform in length)."""
        t, r = random_perturbation(self.rng, 1.0, 1.0)
        steps = self.p.steps
        x = np.r_[t * self.rng.uniform(0, size) * steps[0], r * self.rng.uniform(0, size) * steps[3]]
        return self.p.pose(T, x)

    def sa(self, T_base, E_base, stop_below, config):
        self.legs["sa"] += 1
        p = self.p

        def f(x):
            T = p.pose(T_base, x)
            # Annealing may roam, but only over poses the initial guess allows (paper section 2.1
            # assumes the guess is good enough); farther out E is taken as infinite.
            return p.error(T) if self.inside(T) else np.inf

        def report(x, y, temp, accepted):
            if np.isfinite(y):
                self.emit("sa", p.pose(T_base, x), y, temp, accepted)

        res = anneal(f, np.zeros(6), self.cfg.simplex_scale * p.steps, self.rng, config, stop_below=stop_below,
                     on_eval=report, f0=E_base)
        return p.pose(T_base, res.x), res.value, res.improved

    def mark_local_minimum(self, T, E):
        self.local_minima += 1
        self.emit("icp", T, E, local_minimum=True, count=False)


def _hybrid(run: _Run, threshold: float) -> str:
    T, E = run.first_icp(threshold)
    while True:
        if E < threshold:
            return "error below threshold"
        run.mark_local_minimum(T, E)
        T_sa, E_sa, better = run.sa(T, E, E * (1 - MIN_GAIN), run.cfg.anneal)
        if not better:
            return "annealing found no better point"
        T, E = run.icp(T_sa)


def _icp_alone(run: _Run, threshold: float) -> str:
    T, E = run.icp(run.start, bounded=False)  # the classic baseline walks wherever E leads
    if E >= threshold:
        run.mark_local_minimum(T, E)
        return "ICP converged above the threshold"
    return "error below threshold"


def _sa_alone(run: _Run, threshold: float) -> str:
    E0 = run.p.error(run.start)
    run.sa(run.start, E0, None, run.cfg.sa_alone)
    return "minimum temperature reached"


def _icp_restarts(run: _Run, threshold: float) -> str:
    for k in range(run.cfg.restarts):
        T, E = run.icp(run.random_step(run.start, 1.0)) if k else run.first_icp(threshold)
        if E < threshold:
            return f"error below threshold after {k + 1} ICP runs"
        run.mark_local_minimum(T, E)
    return f"restart budget ({run.cfg.restarts} ICP runs) spent"


def _basin_hopping(run: _Run, threshold: float) -> str:
    p = run.p
    T, E = run.first_icp(threshold)
    if E >= threshold:
        run.mark_local_minimum(T, E)
    # Refining (on the overlap re-cut at the pose found, with the small uncertainty left) always hops
    # a few times: the threshold sits above near-misses round the true well (see CONFIRM_HOPS).
    budget = min(CONFIRM_HOPS, run.cfg.hops) if run.refining else run.cfg.hops
    for hop in range(budget):
        if E < threshold and not run.refining:
            return f"error below threshold ({hop} hops)"
        T_hop = run.random_step(T, run.cfg.hop_size)
        if not run.inside(T_hop):
            continue
        run.emit("sa", T_hop, p.error(T_hop))  # a hop counts as an annealing iteration: a stochastic move
        T_new, E_new = run.icp(T_hop)
        if E_new >= threshold:
            run.mark_local_minimum(T_new, E_new)
        if E_new < E:
            T, E = T_new, E_new
    return "error below threshold" if E < threshold else f"hop budget ({budget} hops) spent"


_METHODS = {"hybrid": _hybrid, "icp": _icp_alone, "sa": _sa_alone, "icp-restarts": _icp_restarts,
            "basin-hopping": _basin_hopping}


def register(source: Scan, target: Scan, T_init: np.ndarray | None = None, config: Config = Config(),
             listener: Listener | None = None, problem: Problem | None = None) -> Result:
    """Register ``source`` onto ``target`` from the guess ``T_init`` (T_target_source, default identity).

    ``listener`` receives every :class:`Event`; it may raise :class:`Cancelled` to stop early.
    """
    config.validate()
    t0 = time.perf_counter()
    problem = problem or prepare(source, target, T_init, replace(config.problem, seed=config.seed))
    threshold = config.threshold if config.threshold is not None else estimate_threshold(problem, config.seed)
    run = _Run(problem, config, listener)
    reason = ""
    evaluations = 0
    rounds = []  # (E on the overlap cut at the round's pose, pose, why it stopped)
    cut = problem  # the cut the current round searches
    try:
        # the outer re-cut loop belongs to our hybrid; the baselines search one cut, as in the paper
        for k in range(config.recut_rounds if config.method == "hybrid" else 1):
            if k:
                # Beyond the paper: section 2.1 cuts the overlap under the first guess; where that guess
                # is poor and the overlap low, most cut points have no partner at the truth and E can
                # prefer a wrong pose. Cut again at the pose found (with the full uncertainty) and search
                # again from there, unless the new cut is nearly the old one (the same error again).
                new = recut(problem, run.best_T, config, converged=False)
                if _jaccard(new.used, cut.used) >= SAME_CUT:
                    break
                evaluations += problem.error.evaluations
                problem = new
                run.p, run.start, run.best_E = problem, run.best_T, np.inf
            cut = problem
            problem.error.evaluations = 0
            T_round = problem.T_init
            reason = _search(run, config, threshold)
            if config.resegment and reason != "cancelled":
                # Once the pose is good the cut is too (fewer points without a partner): refine there.
                evaluations += problem.error.evaluations
                problem = recut(problem, run.best_T, config, converged=True)
                run.p, run.start, run.best_E = problem, run.best_T, np.inf
                problem.error.evaluations = 0
                run.refining = True
                reason = _METHODS[config.method](run, threshold)
                run.refining = False
            E = problem.error(run.best_T)
            rounds.append((E, run.best_T, reason))
            rot, tr = pose_error(run.best_T, T_round, problem.center)
            if reason == "cancelled" or E < threshold or (
                    rot < RESEGMENT_ROTATION_DEG and tr < RESEGMENT_TRANSLATION * target.size):
                break
        if config.polish and reason != "cancelled":
            run.icp(run.best_T, replace(config.icp, unweighted=True))
            rounds.append((problem.error(run.best_T), run.best_T, rounds[-1][2]))
    except Cancelled:
        reason = "cancelled"
        rounds.append((problem.error(run.best_T), run.best_T, reason))
    finally:
        problem.error.widen = 1.0
    # Each round is scored on the overlap cut at its own pose; the lowest wins.
    E, T, reason = min(rounds, key=lambda r: r[0]) if reason != "cancelled" else rounds[-1]
    evaluations += problem.error.evaluations
    if len(rounds) > 1 and reason != "cancelled":
        reason += f" (best of {len(rounds)} overlap cuts)"
    return Result(T, E, dict(run.n), run.local_minima, evaluations, time.perf_counter() - t0, config.method,
                  threshold, reason)


def _jaccard(a: np.ndarray, b: np.ndarray) -> float:
    """Overlap of two (N,) bool point selections: |a and b| / |a or b|."""
    union = np.count_nonzero(a | b)
    return np.count_nonzero(a & b) / union if union else 1.0


def _search(run: _Run, config: Config, threshold: float) -> str:
    """The method on the current problem; with coarse-to-fine, first on smoother error surfaces."""
    reason = ""
    for widen in COARSE_TO_FINE if config.coarse_to_fine else (1.0,):
        # Coarse-to-fine (paper section 4): the same search on a smoother error surface first.
        run.p.error.widen = widen
        run.start, run.best_E = run.best_T, np.inf
        reason = _METHODS[config.method](run, threshold if widen == 1.0 else COARSE_THRESHOLD * threshold)
    run.p.error.widen = 1.0
    return reason


def recut(problem: Problem, T: np.ndarray, config: Config, converged: bool) -> Problem:
    """The overlap cut again at pose T: with the guess's full uncertainty, or, once ``converged``,
    with the small uncertainty left after a registration."""
    pc = replace(config.problem, seed=config.seed)
    if converged:
        pc = replace(pc, rotation_uncertainty_deg=RESEGMENT_ROTATION_DEG,
                     translation_uncertainty=RESEGMENT_TRANSLATION * problem.target.size)
    else:
        pc = replace(pc, rotation_uncertainty_deg=float(np.degrees(problem.rotation_uncertainty)),
                     translation_uncertainty=problem.translation_uncertainty)
    return prepare(problem.source, problem.target, T, pc, surface=problem.surface)

