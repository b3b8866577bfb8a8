"""The ``global`` method (beyond the paper): candidates in stages, cheapest first -> each refined by ICP
until one is trusted -> else the paper's hybrid from the best, within a bound -> the lowest score on the
pair's fixed basis.

    setup      cut the overlap under the guess (widened when empty, core.cut), triangulate the target;
               the pair's noise floor, its fixed scoring basis, its pair threshold (core.threshold);
               the stated region (core.region: what the user said about the guess, one object)
    stages     the guess; the rotation samples within the region (core.candidates), shifted to fit;
               KISS-Matcher's hypothesis (with the guess, first, when the rotation is stated wider than
               ``CandidateConfig.guess_first_deg``); FPFH + RANSAC. No hypothesis is dropped: each stage
               is scored in one batched query and its best few refined by ICP on the paper's robust E
               (on the overlap cut at the candidate, then on the cut at the pose found), those inside
               the region first
    verdict    the first refined pose the pair threshold trusts inside the region ends the search; one
               trusted beyond it is kept, and returned (``within_region`` False) when no stage finds one
               inside (a symmetric scene's twin inside wins)
    fallback   nothing trusted: the paper's hybrid (``--method hybrid``, unchanged) round the best refined
               pose, for at most ``CandidateConfig.fallback_steps`` steps, and the lower of the two

No new stage or leg starts once ``CandidateConfig.time_limit`` seconds have passed. With candidates off
(``CandidateConfig.enabled=False``) only the guess is a candidate.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from .candidates import Basis, CandidateConfig, fpfh_candidates, make_basis, pair_spacing, rotation_candidates
from .config import Config
from .events import Cancelled, Event, Listener
from .icp import icp
from .kiss import kiss_available, kiss_candidates
from .lock import LockFrame
from .noise import noise_floors
from .problem import Problem, ProblemConfig, prepare
from .region import Region, offsets
from .result import GlobalDetails, Iterations, Result, Stop, StopReason
from .scan import Scan
from .search.run import run_method
from .surface import Surface
from .threshold import PairThreshold, pair_threshold


class TimeBound(Cancelled):
    """The search's bound ran out (CandidateConfig.fallback_steps or time_limit)."""


@dataclass(frozen=True, eq=False)
class Hypotheses:
    """A stage's poses (each (4, 4) T_target_source), or why it has none (``why_none``)."""

    poses: list
    why_none: str = ""

    @property
    def source_note(self) -> int | str:
        """For the result's candidate sources: how many, or why none."""
        return self.why_none or len(self.poses)


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
    def surface(self) -> Surface:
        return self.problem.surface

    @property
    def T_guess(self) -> np.ndarray:
        return self.problem.T_init

    def trusted(self, T: np.ndarray) -> bool:
        return self.threshold.holds(self.basis, T)

    def score(self, T: np.ndarray) -> float:
        return float(self.basis.evaluate(np.asarray(T)[None]).score[0])

    def out_of_time(self) -> bool:
        limit = self.config.candidates.time_limit
        return limit is not None and time.perf_counter() - self.t0 > limit


class _Counter:
    """Numbers the events of every stage in one stream (iteration over the run, phase_iteration within
    the leg, as core.events documents); forwards them to the listener; raises :class:`TimeBound` when
    the fallback's steps or the time run out."""

    def __init__(self, listener: Listener | None, frame: LockFrame | None, setup_t0: float, time_limit: float | None):
        self.listener, self.frame = listener, frame
        self.n = {"candidates": 0, "icp": 0, "sa": 0}  # steps per phase over the run
        self.legs = {"candidates": 0, "icp": 0, "sa": 0}
        self.in_leg = 0
        self.t0, self.time_limit = setup_t0, time_limit
        self.steps_left: int | None = None  # set while the fallback runs

    def leg(self, phase: str) -> None:
        """A new leg of ``phase`` begins (a round's scoring, one candidate's ICP)."""
        self.legs[phase] += 1
        self.in_leg = 0

    def emit(self, phase: str, T: np.ndarray, E: float) -> None:
        self.n[phase] += 1
        self.in_leg += 1
        if self.listener is not None:
            coords = None if self.frame is None else self.frame.coords_of(T)  # as core.search.state's events
            self.listener(Event(phase, self.total(), self.in_leg, self.legs[phase], T, E, coords=coords))

    def forward(self, e: Event) -> None:
        """An event of the fallback hybrid's own run, renumbered into this stream (a local-minimum marker is
        not a step); its legs follow this stream's. Raises :class:`TimeBound` past the bound."""
        if not e.local_minimum:
            self.n[e.phase] += 1
            if self.steps_left is not None:
                self.steps_left -= 1
        if self.listener is not None:
            self.listener(replace_event(e, iteration=self.total(), leg=self.legs[e.phase] + e.leg))
        if (self.steps_left is not None and self.steps_left < 0) or (
                self.time_limit is not None and time.perf_counter() - self.t0 > self.time_limit):
            raise TimeBound()

    def total(self) -> int:
        return self.n["candidates"] + self.n["icp"] + self.n["sa"]

    def iterations(self) -> Iterations:
        return Iterations(self.n["icp"], self.n["sa"], self.n["candidates"])


def replace_event(e: Event, **kw) -> Event:
    d = {k: getattr(e, k) for k in ("phase", "iteration", "phase_iteration", "leg", "T", "error", "temperature",
                                    "accepted", "local_minimum", "coords")}
    d.update(kw)
    return Event(**d)


# ---- the stages: where candidates come from -------------------------------------------------------------
def sampled(setup: Setup) -> Hypotheses:
    """The rotation samples within the region (core.candidates.rotation_candidates), shifted to fit."""
    cc, region = setup.config.candidates, setup.region
    if not cc.enabled:
        return Hypotheses([], "candidates off")
    poses = rotation_candidates(setup.source, setup.target, setup.T_guess, region.rotation + region.slack_rotation,
                                region.translation, cc.rotation_samples)
    return Hypotheses(list(setup.basis.shift_to_fit(np.stack(poses))) if poses else [])


def matched(setup: Setup, method: str, voxels: tuple[float, ...] | None = None) -> Hypotheses:
    """Feature-matching hypotheses of ``method`` ("fpfh-ransac" at ``voxels`` spacings, or "kiss-matcher"),
    wherever they lie (the region orders them, it drops none)."""
    cc, source, target = setup.config.candidates, setup.source, setup.target
    spacing = pair_spacing(source, target)
    if method == "fpfh-ransac":
        return Hypotheses(fpfh_candidates(source, target, spacing, voxels or cc.fpfh_voxels, cc.fpfh_seeds,
                                          setup.config.seed))
    if not kiss_available():
        return Hypotheses([], "not installed (pip kiss-matcher; wheels for Python 3.11/3.12)")
    if setup.ahead is not None:
        return Hypotheses(setup.ahead.result())
    return Hypotheses(kiss_candidates(source, target, spacing, max(cc.fpfh_voxels)))


def kiss_ahead(source: Scan, target: Scan, pc: ProblemConfig, cc: CandidateConfig) -> Future | None:
    """KISS-Matcher's hypotheses, started on a thread of their own when the first stage scores them (a
    rotation stated wider than ``guess_first_deg``); else None. The thread makes the voxel clouds and
    waits on core.kiss's child process, which runs on the other core while this one cuts the overlap,
    takes the noise floor and the basis (the same inputs, so the same hypotheses)."""
    if not (cc.enabled and cc.kiss_matcher and pc.rotation_uncertainty_deg > cc.guess_first_deg and kiss_available()):
        return None
    pool = ThreadPoolExecutor(1, thread_name_prefix="kiss-matcher")
    future = pool.submit(kiss_candidates, source, target, pair_spacing(source, target), max(cc.fpfh_voxels))
    pool.shutdown(wait=False)
    return future


@dataclass(frozen=True)
class Stage:
    """name; make: the stage's hypotheses; refine: how many of them (the best by score) ICP refines;
    features: hypotheses from feature matching, start-free (a pose they give beyond the region they give
    from any guess: once one such is trusted, a later feature stage has nothing new to say)."""

    name: str
    make: Callable[[], Hypotheses]
    refine: int
    features: bool = False


def stages(setup: Setup) -> Iterator[Stage]:
    """The stages, cheapest first. A rotation stated within ``guess_first_deg``: the guess alone, then the
    rotation samples, then KISS-Matcher's one hypothesis (~0.1 s). A wider one: the guess and
    KISS-Matcher's hypothesis scored together (the lower refined first), then the samples. FPFH + RANSAC
    last: it costs about what the whole Open3D pipeline does."""
    cc = setup.config.candidates
    kiss = cc.enabled and cc.kiss_matcher
    guess = Hypotheses([setup.T_guess])
    samples = Stage("rotation samples", lambda: sampled(setup), cc.refine)
    if setup.region.stated_rotation_deg > cc.guess_first_deg and kiss:
        yield Stage("guess, kiss-matcher", lambda: Hypotheses(guess.poses + matched(setup, "kiss-matcher").poses), 2, True)
        yield samples
    else:
        yield Stage("guess", lambda: guess, 1)
        if not cc.enabled:
            return
        yield samples
        if kiss:
            yield Stage("kiss-matcher", lambda: matched(setup, "kiss-matcher"), 1, True)
    for v in sorted(cc.fpfh_voxels, reverse=True):  # coarse first: 5 spacings costs ~1/5 of 2 spacings
        yield Stage(f"fpfh-ransac {v:g} spacings", lambda v=v: matched(setup, "fpfh-ransac", (v,)), cc.fpfh_seeds, True)


# ---- refining a candidate -------------------------------------------------------------------------------
def refine(source: Scan, target: Scan, surface: Surface, T: np.ndarray, pc: ProblemConfig, config: Config,
           on_step=None, frame: LockFrame | None = None, at_T: Problem | None = None) -> tuple[np.ndarray, Problem]:
    """ICP (``config.candidates.refine_metric``) on the robust E from T: on the overlap cut at T (``at_T``,
    when one was cut there already), then on the cut at the pose found (under ``frame``'s lock, when
    given: core.lock). Returns the pose and that last cut."""
    cc, s = config.candidates, config.search
    # the first cut skips the visibility test (a ray per point): the candidate may be 15 deg off anyway
    near = replace(pc, rotation_uncertainty_deg=min(pc.rotation_uncertainty_deg, cc.refine_rotation_deg),
                   visibility=False)
    converged = replace(pc, rotation_uncertainty_deg=s.resegment_rotation_deg,
                        translation_uncertainty=s.resegment_translation * target.size)
    icp_config = replace(config.icp, metric=cc.refine_metric, patience=cc.refine_patience)
    for cfg in (near, converged):
        p = at_T if cfg is near and at_T is not None else prepare(source, target, T, cfg, surface=surface, seed=config.seed)
        T = icp(p.error, T, icp_config, on_step, frame=frame).T
    return T, p


def _near(Ts: list[np.ndarray], T: np.ndarray, center: np.ndarray, rot: float, trans: float) -> bool:
    """Whether T lies within ``rot`` radians and ``trans`` (the move of ``center``) of any of ``Ts``."""
    if not Ts:
        return False
    r, t = offsets(np.stack(Ts), T, center)
    return bool(np.any((r <= rot) & (t <= trans)))


@dataclass
class Found:
    """What the stages found so far: every pose scored, every pose refined, the trusted pose inside the
    region (ends the search) and the first trusted beyond it, and the last cut of a trusted refinement."""

    scored: int = 0
    refined: list | None = None
    inside: np.ndarray | None = None
    beyond: np.ndarray | None = None
    last_cut: Problem | None = None
    by: dict | None = None  # id of a refined pose -> the stage that gave it

    def stage_of(self, T: np.ndarray) -> str:
        return (self.by or {}).get(id(T), "")

    def __post_init__(self):
        self.refined = [] if self.refined is None else self.refined
        self.by = {} if self.by is None else self.by


def run_stage(setup: Setup, run: _Counter, poses: list[np.ndarray], n: int, found: Found, stage: str = "") -> None:
    """Score ``poses`` in one query (events of phase 'candidates'); refine the best ``n`` by score, those
    inside the region first (once each: near-duplicates are skipped), until one is trusted inside."""
    cc = setup.config.candidates
    scores = setup.basis.evaluate(np.stack(poses)).score
    found.scored += len(poses)
    run.leg("candidates")
    for T, s in zip(poses, scores):
        run.emit("candidates", T, float(s))
    inside = setup.region.contains(np.stack(poses))
    order = sorted(range(len(poses)), key=lambda k: (not inside[k], scores[k]))
    done: list[np.ndarray] = []
    trans = cc.distinct_translation * setup.target.size
    for k in order:
        if len(done) >= n or setup.out_of_time():
            return
        if found.beyond is not None and not inside[k]:
            continue  # a pose beyond the region is trusted already: only one inside can say more
        if _near(done, poses[k], setup.source.centroid, np.radians(cc.distinct_rotation_deg), trans):
            continue
        done.append(poses[k])
        run.leg("icp")
        at_guess = setup.problem if poses[k] is setup.T_guess else None
        T, last = refine(setup.source, setup.target, setup.surface, poses[k], setup.config.problem, setup.config,
                         lambda T, E: run.emit("icp", T, E), setup.frame, at_guess)
        found.refined.append(T)
        found.by[id(T)] = stage
        if setup.trusted(T):
            if setup.region.inside(T):
                found.inside, found.last_cut = T, last
                return
            if found.beyond is None:
                found.beyond = T


def best_refined(setup: Setup, poses: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The lowest score among ``poses`` that overlap both ways, those inside the region first."""
    s = setup.basis.evaluate(np.stack(poses))
    valid = setup.basis.valid(s)
    inside = setup.region.contains(np.stack(poses))
    for ok in (valid & inside, valid, np.ones(len(poses), dtype=bool)):
        if ok.any():
            k = int(np.argmin(np.where(ok, s.score, np.inf)))
            return poses[k], float(s.score[k])
    raise AssertionError("unreachable: the last mask holds every pose")


# ---- the run --------------------------------------------------------------------------------------------
def prepare_setup(source: Scan, target: Scan, T_init: np.ndarray | None, config: Config) -> Setup:
    """The cut under the guess, the basis, the pair threshold and the region (module notes: setup)."""
    t0 = time.perf_counter()
    cc, pc = config.candidates, config.problem
    T_init = np.eye(4) if T_init is None else np.asarray(T_init, dtype=np.float64)
    ahead = kiss_ahead(source, target, pc, cc)
    problem = prepare(source, target, T_init, pc, seed=config.seed)
    # A lock (core.lock) is bound once, at the guess: every candidate is moved onto the allowed set
    # before it is scored, and every refinement and the hybrid walk the same free coordinates.
    frame = config.lock.bind(problem.T_init, problem.center, problem.scale) if config.lock.active else None
    rng = np.random.default_rng(config.seed)
    floor = float(np.mean(noise_floors([source, target], rng, len(problem.points))))
    basis = make_basis(source, target, problem.surface, floor, rng, cc, pc.frustum)
    threshold = pair_threshold(floor, basis.angle_floor, cc.min_overlap)
    region = Region.stated(problem.T_init, pc, source, target)
    return Setup(source, target, config, problem, basis, threshold, region, frame, ahead, t0)


def search_stages(setup: Setup, run: _Counter) -> tuple[Found, dict]:
    """Every stage in turn until one refines a pose the pair threshold trusts inside the region (module
    notes: stages, verdict). Returns what was found and, per stage, how many poses it gave or why none."""
    found, sources = Found(), {}
    for stage in stages(setup):
        if setup.out_of_time():
            sources[stage.name] = "not reached within the time limit"
            continue
        if found.beyond is not None and stage.features:
            sources[stage.name] = "not needed (a trusted pose was found; feature matching does not use the guess)"
            continue
        hyp = stage.make()
        if setup.frame is not None:
            hyp = Hypotheses([setup.frame.pose(setup.frame.free(T)) for T in hyp.poses], hyp.why_none)
        sources[stage.name] = hyp.source_note
        if hyp.poses:
            run_stage(setup, run, hyp.poses, stage.refine, found, stage.name)
        if found.inside is not None:
            break
    return found, sources


def fallback(setup: Setup, run: _Counter, found: Found) -> tuple[np.ndarray, float, Stop]:
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
    return (f"nothing trusted within the search's bound ({bound}; {where}): the best scored pose; for the "
            "paper's full search from it run --method hybrid with this pose as --init, or --full-search")


def register_global(source: Scan, target: Scan, T_init: np.ndarray | None = None,
                    config: Config = Config(method="global"), listener: Listener | None = None) -> Result:
    """Register ``source`` onto ``target`` (T_target_source) with the global pipeline (module notes);
    ``config.candidates`` holds its own knobs, ``config.problem`` the stated region (core.region)."""
    config.validate()
    setup = prepare_setup(source, target, T_init, config)
    run = _Counter(listener, setup.frame, setup.t0, config.candidates.time_limit)
    try:
        found, sources = search_stages(setup, run)
        if found.inside is not None:
            best, stop = found.inside, Stop(StopReason.TRUSTED)
        elif found.beyond is not None:
            best, stop = found.beyond, Stop(StopReason.TRUSTED, f"{StopReason.TRUSTED.value}, beyond the stated region")
        else:
            best, _, stop = fallback(setup, run, found)
        scored = found.scored
    except Cancelled:
        best, stop, sources, scored, found = setup.T_guess, Stop(StopReason.CANCELLED), {"guess": 1}, 1, Found()
    return _result(setup, run, best, stop, found.last_cut if best is found.inside else None, scored, sources,
                   found.stage_of(best) or ("guess" if best is setup.T_guess else ""))


def _result(setup: Setup, run: _Counter, T: np.ndarray, stop: Stop, last_cut: Problem | None, scored: int,
            sources: dict, found_by: str) -> Result:
    """The Result of pose T: E on the overlap cut at T (a trusted refinement's last cut is that already)."""
    cfg = setup.config
    if last_cut is None:
        converged = replace(cfg.problem, rotation_uncertainty_deg=cfg.search.resegment_rotation_deg,
                            translation_uncertainty=cfg.search.resegment_translation * setup.target.size)
        last_cut = prepare(setup.source, setup.target, T, converged, surface=setup.surface, seed=cfg.seed)
    s = setup.basis.evaluate(T[None])
    misfit = setup.threshold.misfit(setup.basis, T, s)
    trusted = setup.trusted(T)
    details = GlobalDetails(setup.threshold, misfit if np.isfinite(misfit) else None, setup.region,
                            setup.region.inside(T), setup.region.beyond_text(T), float(s.score[0]), scored, sources,
                            found_by)
    return Result(T, last_cut.error(T), run.iterations(), 0, run.total(), time.perf_counter() - setup.t0, "global",
                  setup.threshold.value, stop, cut=setup.problem.cut, trusted=trusted, details=details)
