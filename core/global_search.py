"""The ``global`` method (beyond the paper; issue 13): candidates in stages, cheapest first -> each
refined by ICP until one is trusted -> else the paper's hybrid from the best -> the lowest score on the
pair's fixed basis.

    1. cut the overlap under the guess (widened when empty, core.cut) and triangulate the target;
    2. the pair's noise floor, its fixed scoring basis and its stop threshold (core.threshold's
       pair threshold);
    3. stages of candidates (``_stages``): the guess; the rotation samples within its uncertainty
       (core.candidates), shifted to fit; KISS-Matcher's hypothesis (with the guess, first, when the
       guess is stated wider than GUESS_FIRST_DEG); FPFH + RANSAC. Each stage is scored in one
       batched query and its best few are refined by ICP on the paper's robust E (on the overlap cut
       at the candidate, then on the cut at the pose found), one by one;
    4. the first refined pose the pair threshold trusts (within REGION x the stated uncertainty) ends
       the search; a later stage runs only when no earlier one gave such a pose;
    5. none trusted: the paper's hybrid (``--method hybrid``, unchanged) from the best refined pose
       (lowest score among those overlapping both ways), and the lower of the two.

With candidates off (``CandidateConfig.enabled=False``) only the guess is a candidate.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from .candidates import (
    Basis,
    CandidateConfig,
    fpfh_candidates,
    make_basis,
    pair_spacing,
    rotation_candidates,
    within,
    within_many,
)
from .config import Config
from .events import Cancelled, Event, Listener
from .icp import icp
from .kiss_matcher_candidates import kiss_available, kiss_candidates
from .lock import LockFrame
from .noise import noise_floors
from .problem import Problem, ProblemConfig, prepare
from .result import Result, Stop, StopReason
from .scan import Scan
from .surface import Surface
from .threshold import pair_threshold

REFINE_ROTATION_DEG = 15.0  # the cut at a candidate assumes it is this close (the rotation samples' spacing)
CONVERGED_ROTATION_DEG = 2.0  # ... and, once ICP has converged, this close (core.register's resegment)
CONVERGED_TRANSLATION = 0.02  # ... as a share of the target's size
LOCAL_TRANSLATION = 0.05  # the hybrid's translation uncertainty round the best candidate (share of size)
DISTINCT_ROTATION_DEG = 2.0  # candidates closer than this (and DISTINCT_TRANSLATION) are refined once
DISTINCT_TRANSLATION = 0.01  # share of the target's size
# A candidate is dropped when it lies farther from the guess than the stated uncertainty plus these: a
# truth on the boundary (the sweep's starts lie exactly at the stated offset) has hypotheses a little
# beyond it (measured on bun090->bun000: RANSAC and KISS-Matcher 0.04-1.7 deg and 0.3-1.5 mm off the truth)
SLACK_ROTATION_DEG = 3.0
SLACK_TRANSLATION = 0.03  # share of the target's size
REGION = 2.0  # a refined pose may end within this x the guess's uncertainty (core.register's SEARCH_BOUND)
# The guess is refined alone first when it is stated within this; a wider guess is scored with
# KISS-Matcher's hypothesis first. Measured on the bunny sweep's starts only (the scenes have no
# KISS-Matcher stage worth timing; the constant orders stages, success does not depend on it): the
# guess alone, refined with the point-to-plane steps, is trusted at 5 and 15 deg, but from 30 deg about
# half of 20 starts fell through to the rotation samples: 0.81-4.11 s, median 1.22 (in process, files ->
# pose, quiet); with KISS-Matcher scored beside the guess (started ahead, kiss_ahead) 0.93-1.53, median 1.01.
GUESS_FIRST_DEG = 20.0


class _Counter:
    """Numbers the events of every stage in one stream (iteration over the run, phase_iteration within
    the leg, as core.events documents); forwards them to the listener."""

    def __init__(self, listener: Listener | None, frame: LockFrame | None = None):
        self.listener, self.frame = listener, frame
        self.n = {"candidates": 0, "icp": 0, "sa": 0}  # steps per phase over the run
        self.legs = {"candidates": 0, "icp": 0, "sa": 0}
        self.in_leg = 0

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
        """An event of the hybrid's own run, renumbered into this stream (a local-minimum marker is
        not a step, as in core.register); its legs follow this stream's."""
        if not e.local_minimum:
            self.n[e.phase] += 1
        if self.listener is not None:
            self.listener(replace_event(e, iteration=self.total(), leg=self.legs[e.phase] + e.leg))

    def total(self) -> int:
        return self.n["candidates"] + self.n["icp"] + self.n["sa"]


def replace_event(e: Event, **kw) -> Event:
    d = {k: getattr(e, k) for k in ("phase", "iteration", "phase_iteration", "leg", "T", "error", "temperature",
                                    "accepted", "local_minimum", "coords")}
    d.update(kw)
    return Event(**d)


def _kept(Ts, T_init, center, r_unc, t_unc, size: float) -> list[np.ndarray]:
    """The poses within the guess's uncertainty, give or take a candidate's own error (SLACK_*)."""
    if not len(Ts):
        return []
    keep = within_many(np.stack(Ts), T_init, center, r_unc + np.radians(SLACK_ROTATION_DEG),
                       t_unc + SLACK_TRANSLATION * size)
    return [T for T, k in zip(Ts, keep) if k]


def sampled(source: Scan, target: Scan, T_init: np.ndarray, pc: ProblemConfig, cc: CandidateConfig) -> list[np.ndarray]:
    """The rotation samples within the guess's uncertainty (core.candidates.rotation_candidates)."""
    if not cc.enabled:
        return []
    r_unc, t_unc = np.radians(pc.rotation_uncertainty_deg), pc.translation_uncertainty_for(target.size)
    return _kept(rotation_candidates(source, target, T_init, r_unc, t_unc, cc.rotation_samples), T_init,
                 source.centroid, r_unc, t_unc, target.size)


def matched(source: Scan, target: Scan, T_init: np.ndarray, pc: ProblemConfig, cc: CandidateConfig, seed: int,
            method: str, ahead: Future | None = None) -> list[np.ndarray] | str:
    """Feature-matching hypotheses of ``method`` ("fpfh-ransac" or "kiss-matcher") within the guess's
    uncertainty (a string: why there are none); ``ahead``: KISS-Matcher's, already started (:func:`kiss_ahead`)."""
    r_unc, t_unc = np.radians(pc.rotation_uncertainty_deg), pc.translation_uncertainty_for(target.size)
    spacing = pair_spacing(source, target)
    if method == "fpfh-ransac":
        Ts = fpfh_candidates(source, target, spacing, cc.fpfh_voxels, cc.fpfh_seeds, seed)
    elif not kiss_available():
        return "not installed (pip kiss-matcher; wheels for Python 3.11/3.12)"
    else:
        Ts = ahead.result() if ahead is not None else kiss_candidates(source, target, spacing, max(cc.fpfh_voxels))
    return _kept(Ts, T_init, source.centroid, r_unc, t_unc, target.size)


def kiss_ahead(source: Scan, target: Scan, pc: ProblemConfig, cc: CandidateConfig) -> Future | None:
    """KISS-Matcher's hypotheses, started on a thread of their own when the first stage scores them (a
    guess stated wider than GUESS_FIRST_DEG); else None. The thread makes the voxel clouds and waits on
    core.kiss_matcher_candidates' child process, which runs on the other core while this one cuts the overlap, takes the
    noise floor and the basis (the same inputs, so the same hypotheses)."""
    if not (cc.enabled and cc.kiss_matcher and pc.rotation_uncertainty_deg > GUESS_FIRST_DEG and kiss_available()):
        return None
    pool = ThreadPoolExecutor(1, thread_name_prefix="kiss-matcher")
    future = pool.submit(kiss_candidates, source, target, pair_spacing(source, target), max(cc.fpfh_voxels))
    pool.shutdown(wait=False)
    return future


def refine(source: Scan, target: Scan, surface: Surface, T: np.ndarray, pc: ProblemConfig, icp_config,
           on_step=None, seed: int = 0, frame: LockFrame | None = None, at_T: Problem | None = None
           ) -> tuple[np.ndarray, Problem]:
    """ICP on the robust E from T: on the overlap cut at T (``at_T``, when one was cut there already),
    then on the cut at the pose found (under ``frame``'s lock, when given: core.lock). Returns the
    pose and that last cut."""
    # the first cut skips the visibility test (a ray per point): the candidate may be 15 deg off anyway
    near = replace(pc, rotation_uncertainty_deg=min(pc.rotation_uncertainty_deg, REFINE_ROTATION_DEG), visibility=False)
    conv = replace(pc, rotation_uncertainty_deg=CONVERGED_ROTATION_DEG,
                   translation_uncertainty=CONVERGED_TRANSLATION * target.size)
    for cfg in (near, conv):
        p = at_T if cfg is near and at_T is not None else prepare(source, target, T, cfg, surface=surface, seed=seed)
        T = icp(p.error, T, icp_config, on_step, frame=frame).T
    return T, p


def register_global(source: Scan, target: Scan, T_init: np.ndarray | None = None, config: Config = Config(method="global"),
                    listener: Listener | None = None) -> Result:
    """Register ``source`` onto ``target`` (T_target_source) with the global pipeline (module notes);
    ``config.candidates`` holds its own knobs, the rest is the paper's hybrid's."""
    from .register import register  # the front runs this pipeline for method "global"

    config.validate()
    t0 = time.perf_counter()
    cc, pc = config.candidates, config.problem
    T_init = np.eye(4) if T_init is None else np.asarray(T_init, dtype=np.float64)
    ahead = kiss_ahead(source, target, pc, cc)
    problem = prepare(source, target, T_init, pc, seed=config.seed)
    T_init, surface = problem.T_init, problem.surface
    # A lock (core.lock) is bound once, at the guess: every candidate is moved onto the allowed set
    # before it is scored, and every refinement and the hybrid walk the same free coordinates.
    frame = config.lock.bind(T_init, problem.center, problem.scale) if config.lock.active else None
    rng = np.random.default_rng(config.seed)
    floor = float(np.mean(noise_floors([source, target], rng, len(problem.points))))
    basis = make_basis(source, target, surface, floor, rng, cc, pc.frustum)
    threshold = pair_threshold(floor, basis.angle_floor, cc.min_overlap)
    run = _Counter(listener, frame)
    r_unc, t_unc = problem.rotation_uncertainty, problem.translation_uncertainty
    hybrid = replace(config, method="hybrid")
    stop = Stop(StopReason.TRUSTED)
    poses: list[np.ndarray] = []  # every candidate scored
    refined: list[np.ndarray] = []  # every candidate refined
    sources: dict[str, int | str] = {}
    trusted, last = False, None

    def in_region(T: np.ndarray) -> bool:
        """Within REGION x the stated uncertainty (beyond it, a twin of a symmetric scene may fit as well)."""
        return within(T, T_init, source.centroid, REGION * r_unc, REGION * t_unc)

    def accept(T: np.ndarray) -> bool:
        return in_region(T) and threshold.holds(basis, T)

    try:
        # Stages, cheapest first; the first refined pose the pair threshold trusts ends the search (it
        # said "trust" only where the pose was right in every sweep run). A stage is a list of poses,
        # scored in one query; the best few are refined by ICP one by one.
        for name, make, n_refine in _stages(source, target, T_init, pc, cc, basis, config.seed, ahead):
            found = make()
            if frame is not None and not isinstance(found, str):
                found = [frame.pose(frame.free(T)) for T in found]
            sources[name] = found if isinstance(found, str) else len(found)
            if isinstance(found, str) or not found:
                continue
            poses += found
            done, last = _round(run, basis, accept, found, n_refine, source, target, surface, pc, hybrid, frame, problem)
            refined += done
            trusted = last is not None
            if trusted:
                best, best_s = done[-1], float(basis.evaluate(done[-1][None]).score[0])
                break
        if not trusted:
            best, best_s = _best(basis, refined, T_init, source.centroid, r_unc, t_unc)
            # the candidates covered the stated region; the paper's hybrid searches round the best of them
            local = replace(pc, rotation_uncertainty_deg=min(pc.rotation_uncertainty_deg, REFINE_ROTATION_DEG),
                            translation_uncertainty=min(t_unc, LOCAL_TRANSLATION * target.size))
            res = register(source, target, best, replace(hybrid, problem=local), run.forward, frame=frame)
            s_h = float(basis.evaluate(res.transform[None]).score[0])
            text = f"hybrid from the best candidate: {res.stop_text}"
            if s_h < best_s:
                best, best_s = res.transform, s_h
            else:
                text += "; the refined candidate scores lower on the fixed basis"
            stop = Stop(res.stop_reason, text)
            trusted = accept(best)
    except Cancelled:
        best, best_s = T_init, float(basis.evaluate(T_init[None]).score[0])
        poses, sources, trusted, stop, last = [T_init], {"guess": 1}, False, Stop(StopReason.CANCELLED), None
    if last is None:  # (a refinement that was taken ends on a cut at the pose it found: E is read there)
        last = prepare(source, target, best, replace(pc, rotation_uncertainty_deg=CONVERGED_ROTATION_DEG,
                                                     translation_uncertainty=CONVERGED_TRANSLATION * target.size),
                       surface=surface, seed=config.seed)
    iterations = {"icp": run.n["icp"], "sa": run.n["sa"], "candidates": run.n["candidates"]}
    misfit = threshold.misfit(basis, best)
    details = {"threshold_derivation": threshold.to_json(), "misfit": misfit if np.isfinite(misfit) else None,
               "within_region": in_region(best),
               "score": best_s, "candidates": len(poses),
               "candidate_sources": sources}
    return Result(best, last.error(best), iterations, 0, run.total(), time.perf_counter() - t0, "global",
                  threshold.value, stop, cut=problem.cut, trusted=trusted, details=details)


def _distinct(poses: list[np.ndarray], order: list[int], center: np.ndarray, trans: float) -> list[int]:
    """``order`` without the poses that lie within DISTINCT_ROTATION_DEG and ``trans`` of an earlier one."""
    kept: list[int] = []
    for k in order:
        if not any(within(poses[k], poses[j], center, np.radians(DISTINCT_ROTATION_DEG), trans) for j in kept):
            kept.append(k)
    return kept


def _stages(source: Scan, target: Scan, T_init: np.ndarray, pc: ProblemConfig, cc: CandidateConfig, basis: Basis,
            seed: int, ahead: Future | None = None):
    """(name, make poses or say why none, how many to refine) per stage, cheapest first.

    A guess stated within GUESS_FIRST_DEG: the guess alone, then the rotation samples, then
    KISS-Matcher's one hypothesis (~0.1 s). A wider one: the guess and KISS-Matcher's hypothesis scored
    together (the lower refined first), then the samples. FPFH + RANSAC last: it costs about what the
    whole Open3D pipeline does."""
    kiss = cc.enabled and cc.kiss_matcher
    samples = ("rotation samples", lambda: _shifted(basis, sampled(source, target, T_init, pc, cc)), cc.refine)
    if pc.rotation_uncertainty_deg > GUESS_FIRST_DEG and kiss:
        def guess_and_kiss():
            found = matched(source, target, T_init, pc, cc, seed, "kiss-matcher", ahead)
            return [T_init] + ([] if isinstance(found, str) else found)

        yield "guess, kiss-matcher", guess_and_kiss, 2
        yield samples
    else:
        yield "guess", lambda: [T_init], 1
        if not cc.enabled:
            return
        yield samples
        if kiss:
            yield "kiss-matcher", lambda: matched(source, target, T_init, pc, cc, seed, "kiss-matcher"), 1
    for v in sorted(cc.fpfh_voxels, reverse=True):  # coarse first: 5 spacings costs ~1/5 of 2 spacings
        yield (f"fpfh-ransac {v:g} spacings",
               lambda v=v: matched(source, target, T_init, pc, replace(cc, fpfh_voxels=(v,)), seed, "fpfh-ransac"),
               cc.fpfh_seeds)


def _shifted(basis: Basis, poses: list[np.ndarray]) -> list[np.ndarray]:
    return list(basis.shift_to_fit(np.stack(poses))) if poses else []


def _round(run: _Counter, basis: Basis, accept, poses: list[np.ndarray], n: int, source: Scan, target: Scan,
           surface: Surface, pc: ProblemConfig, base: Config, frame: LockFrame | None, at_guess: Problem
           ) -> tuple[list[np.ndarray], Problem | None]:
    """Score ``poses`` in one query (events of phase 'candidates'); refine the best ``n`` by score (once
    each: near-duplicates are skipped) with ICP, in order, until ``accept`` takes one. The guess is
    refined from the cut ``at_guess`` made under it. Returns the refined poses and, when the last one
    was taken, its last cut (else None)."""
    scores = basis.evaluate(np.stack(poses))
    run.leg("candidates")
    for T, s in zip(poses, scores.score):
        run.emit("candidates", T, float(s))
    order = [int(k) for k in np.argsort(scores.score, kind="stable")[:n]]
    order = _distinct(poses, order, source.centroid, DISTINCT_TRANSLATION * target.size)
    out = []
    for k in order:
        run.leg("icp")
        T, last = refine(source, target, surface, poses[k], pc, replace(base.icp, metric=base.candidates.refine_metric),
                         lambda T, E: run.emit("icp", T, E), base.seed,
                         frame, at_guess if poses[k] is at_guess.T_init else None)
        out.append(T)
        if accept(T):
            return out, last
    return out, None


def _best(basis: Basis, poses: list[np.ndarray], T_init: np.ndarray, center: np.ndarray, r_unc: float,
          t_unc: float) -> tuple[np.ndarray, float]:
    """The lowest score among ``poses`` that overlap both ways and lie within REGION x the uncertainty."""
    s = basis.evaluate(np.stack(poses))
    ok = basis.valid(s) & np.array([within(T, T_init, center, REGION * r_unc, REGION * t_unc) for T in poses])
    score = np.where(ok, s.score, np.inf)
    k = int(np.argmin(score)) if np.isfinite(score).any() else int(np.argmin(s.score))
    return poses[k], float(s.score[k])
