"""The ``global`` method (beyond the paper): candidates in stages, cheapest first -> each refined by ICP
until one is trusted -> else the paper's hybrid from the best, within a bound -> the lowest score on the
pair's fixed basis.

    setup      (setup.py) cut the overlap under the guess (widened when empty, core.cut), triangulate
               the target; the pair's noise floor, its fixed scoring basis, its pair threshold
               (core.threshold); the stated region (core.guess.Guess.region: what the user said about the guess)
    stages     (stages.py) the guess; KISS-Matcher's hypothesis (beside the guess when the rotation is
               stated wider than ``CandidateConfig.guess_first_deg``); the rotation samples within the
               region (core.candidates), shifted to fit; FPFH + RANSAC
    refine     (refinement.py) no hypothesis is dropped: each stage is scored in one batched query and its
               best few refined by ICP on the paper's robust E (on the overlap cut at the candidate,
               then on the cut at the pose found), those inside the region first
    verdict    the first refined pose the pair threshold trusts inside the region ends the search; one
               trusted beyond it is kept, and returned (``within_region`` False) when no stage finds one
               inside (a symmetric scene's twin inside wins); asked to (``CandidateConfig.end_on_weak``), the
               first weakly pinned pose refined inside ends it too, untrusted
    fallback   (fallback.py) nothing trusted: the paper's hybrid (``--method hybrid``, unchanged) round
               the best refined pose for at most ``CandidateConfig.fallback_steps`` steps; the pose of the
               two with the lower score
    events     (stream.py) every stage's events in one numbered stream, each refinement step charged to
               the budget
    budget     (core.search.budget) the search's work: candidates scored (``CandidateConfig.max_candidates``)
               and steps (``search_steps``: refinement iterations and the hybrid's steps, of them at most
               ``fallback_steps`` the hybrid's), counted from the end of the setup; seconds only when asked for
               (``time_limit``). No stage or leg starts once it is spent; a loaded machine ends at the same pose.
    thinned    a scan of more than core.candidates.SEARCH_POINTS points is searched on a thinned copy
               (core.candidates.for_search); a pose trusted there is refined on the whole scans (ICP legs on
               the converged cut with a larger sample until they settle, core.candidates.WholeLegs' notes; the
               whole target's surface made on a thread meanwhile) and counts as
               trusted only where that pose is too, else the search goes on (measured on the shared Kinect
               frames capture0002 -> capture0001 from 15 deg: the guess's refinement on the thinned frames
               stopped 8 deg off, 33 % matched, misfit 2.5, trusted; on the whole frames it lost the trust);
               a pose found but not trusted is refined on the whole scans alike, kept unless it loses trust
    sized      the feature grids (FPFH, KISS-Matcher) in feature spacings: the point spacing, or the scene's
               span over 400 where that is larger (core.candidates.feature_spacing)
    trust      the pair threshold also asks that the matched overlap pin all six degrees of freedom
               (core.threshold.constraint); the details say which motion it leaves free

With candidates off (``CandidateConfig.enabled=False``) only the guess is a candidate.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import replace

import numpy as np

from ..candidates import SEARCH_POINTS, for_search
from ..config import Config
from ..errors import InputError
from ..events import Cancelled, Listener
from ..frustum import frustum_of
from ..guess import Guess
from ..problem import Problem, prepare
from ..result import GlobalDetails, Result, Stop, StopReason
from ..scan import Scan
from ..surface import Surface
from .fallback import fallback as bounded_hybrid  # (the module's name stays the module's)
from .refinement import Found, best_refined, converge, refine, search_stages
from .setup import Setup, kiss_ahead, prepare_setup
from .stages import Hypotheses, Stage
from .stream import EventStream

__all__ = ["EventStream", "Hypotheses", "Stage", "kiss_ahead", "refine", "register_global"]


def register_global(source: Scan, target: Scan, guess: Guess | np.ndarray | None = None,
                    config: Config = Config(method="global"), listener: Listener | None = None,
                    surface: Surface | None = None) -> Result:
    """Register ``source`` onto ``target`` (T_target_source) with the global pipeline (module notes) from
    ``guess`` (core.guess: its pose and stated region; a (4, 4) pose: the default uncertainty);
    ``config.candidates`` holds its own knobs;
    ``surface``: the target's, when triangulated already."""
    config.validate()
    whole = (source, target, surface)
    source, target = _for_search(source, target)  # thinned when large (core.candidates.SEARCH_POINTS)
    thinned = source is not whole[0] or target is not whole[1]
    if thinned and surface is None:  # the whole target's surface, made on a thread while the search runs
        pool = ThreadPoolExecutor(1, thread_name_prefix="whole-surface")
        views = [w for w, searched in zip(whole[:2], (source, target)) if w is not searched]  # (the search makes its own)
        whole = (whole[0], whole[1], pool.submit(_whole_surface, whole[1], views, config.problem.frustum))
        pool.shutdown(wait=False)
    setup = prepare_setup(source, target, guess, config, surface if target is whole[1] else None)
    run = EventStream(listener, setup.frame, setup.budget())
    found, local_minima = Found(), 0
    try:
        found, sources = search_stages(setup, run, (lambda T: _whole_leg(setup, run, whole, T)) if thinned else None)
        if found.inside is not None:
            best, stop = found.inside, Stop(StopReason.TRUSTED)
        elif found.beyond is not None:
            best, stop = found.beyond, Stop(StopReason.TRUSTED, f"{StopReason.TRUSTED.value}, beyond the stated region")
        elif found.weak:
            best = best_refined(setup, found.refined)[0]
            stop = Stop(StopReason.WEAKLY_PINNED, f"{StopReason.WEAKLY_PINNED.value} (the search was asked to end "
                                                  "there); the best scored pose")
        else:
            best, stop, local_minima = bounded_hybrid(setup, run, found)
    except Cancelled:
        best, stop, sources = setup.T_guess, Stop(StopReason.CANCELLED), {"guess": 1}
    found_by = found.source_of(best) or ("guess" if best is setup.T_guess else "")
    last_cut = found.last_cut if best is found.inside else None
    if any(best is T for T in found.confirmed):
        found_by = f"{found_by}, refined on the whole scans"
    elif thinned and stop.reason is not StopReason.CANCELLED:
        best, last_cut, found_by = _on_the_whole(setup, run, whole, best, last_cut, found_by)
    return _result(setup, run, best, stop, last_cut, sources, found_by, local_minima)


def _for_search(source: Scan, target: Scan) -> tuple[Scan, Scan]:
    """core.candidates.for_search of both scans, side by side where both are thinned (numpy's sorts let go of the
    GIL: two 300-330k-point RGB-D fragments 0.16 s each one after the other)."""
    if min(len(source.points), len(target.points)) <= SEARCH_POINTS:
        return for_search(source), for_search(target)
    with ThreadPoolExecutor(1, thread_name_prefix="thin-target") as pool:
        thinned = pool.submit(for_search, target)
        return for_search(source), thinned.result()


def _whole_surface(target: Scan, views: list[Scan], frustum: str) -> Surface:
    """The whole target's surface, and the views of ``views`` (the whole scans the search does not use itself; each
    view kept with its scan, core.frustum.frustum_of), made on a thread while the thinned scans are searched: the whole
    scans' first overlap cut (:func:`_whole_leg`) then only cuts (on the shared Kinect pair capture0002 -> 0001 the
    views took 0.12 s of that cut's 0.27 s). Where the search ends without asking for it (cancelled, raised, trusted
    on the thinned scans alone) the thread finishes its work unread."""
    surface = Surface.from_scan(target).build()
    for scan in views:
        try:
            frustum_of(scan, frustum)
        except InputError:  # the cut that asks for it says so, in the search's thread
            pass
    return surface


def _whole_leg(setup: Setup, run: EventStream, whole: tuple, T: np.ndarray) -> np.ndarray | None:
    """Pose T found on the thinned scans, refined on the whole ones ``whole`` (source, target, its surface or
    the Future making it): the refinement's legs on the converged cut (core.global_search.refinement.converge)
    as ``CandidateConfig.whole`` says (core.candidates.WholeLegs), not charged to
    the search's budget. None when the whole scans have no overlap cut at T."""
    source, target, surface = whole
    cfg = setup.config
    surface = surface.result() if isinstance(surface, Future) else surface
    surface = surface if surface is not None else Surface.from_scan(target)
    whole_legs = cfg.candidates.whole
    # a cloud more than half of whose points are doubled has spacing 0: the bounds need a length
    spacing = max(target.spacing, 1e-6 * target.size)
    sample = replace(cfg.problem, max_points=max(cfg.problem.max_points, whole_legs.sample))
    try:
        return converge(source, target, surface, T, cfg, sample, lambda T_, E: run.emit("icp", T_, E, charge=False),
                        setup.frame, legs=whole_legs.legs,
                        settled=(whole_legs.settled_deg, whole_legs.settled_spacings * spacing),
                        every_step=(whole_legs.step_deg, whole_legs.step_spacings * spacing))[0]
    except InputError:
        return None


def _on_the_whole(setup: Setup, run: EventStream, whole: tuple, T: np.ndarray, last_cut: Problem | None,
                  found_by: str) -> tuple[np.ndarray, Problem | None, str]:
    """A pose the search did not trust (the best it found), refined on the whole scans (:func:`_whole_leg`);
    kept unless it loses the pair threshold's trust. Returns the pose, its last cut (None: cut it again) and who
    found it."""
    T_whole = _whole_leg(setup, run, whole, T)
    if T_whole is None:  # no overlap cut on the whole scans at this pose: the thinned scans' answer stands
        return T, last_cut, found_by
    if setup.trusted(T) and not setup.trusted(T_whole):
        return T, last_cut, found_by
    return T_whole, None, f"{found_by}, refined on the whole scans" if found_by else "refined on the whole scans"


def _result(setup: Setup, run: EventStream, T: np.ndarray, stop: Stop, last_cut: Problem | None, sources: dict,
            found_by: str, local_minima: int) -> Result:
    """The Result of pose T: E on the overlap cut at T (a trusted refinement's last cut is that already)."""
    cfg = setup.config
    if last_cut is None:
        converged = Guess.converged(T, cfg.search, setup.target.size)
        last_cut = prepare(setup.source, setup.target, converged, cfg.problem, surface=setup.surface, seed=cfg.seed)
    s = setup.basis.evaluate(T[None])
    verdict = setup.judge.verdict(T, s)
    details = GlobalDetails(setup.region, setup.region.inside(T), setup.region.beyond_text(T), float(s.score[0]),
                            run.n["candidates"], sources, found_by)
    return Result(T, last_cut.error(T), run.iterations(), local_minima, run.total(), time.perf_counter() - setup.t0,
                  "global", setup.threshold.value, stop, cut=setup.problem.cut, trusted=verdict.holds, verdict=verdict,
                  details=details)
