"""Refining candidates: ICP on the robust E from each (the overlap cut at the candidate, then at the pose
found), inside the stated region first, until the pair threshold trusts one; and the search through the
stages."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np

from ..config import Config
from ..errors import InputError
from ..guess import Guess
from ..icp import IcpConfig, icp
from ..intrusion import clear
from ..lock import LockFrame
from ..problem import Problem, ProblemConfig, prepare, resample
from ..region import offsets
from ..result import Stop
from ..scan import Scan, ScanKind
from ..search.budget import BudgetSpent
from ..surface import Surface
from ..threshold import ALONG_THE_FREE_MOTION, constraint
from ..transforms import pose_error
from .setup import Setup
from .slide import along_the_free_motion
from .stages import Hypotheses, stages
from .stream import EventStream

# The converged cut assumes the pose within core.config.SearchConfig's resegment uncertainty (2 deg, 2 % of the
# size); a leg on it that moves the pose by half of that or more is cut again where it ended, at most this many
# times. Measured on the shared Kinect frames capture0002 -> capture0001 from 6 degrees about the sensor: the
# first cut, made 6 degrees off, let the leg stop 1.5 degrees short (a second run from there moved 1.6 degrees
# and scored 11 % lower). On the bunny sweep (63 converged legs) the leg moved a median 0.10 degrees, p90 1.35,
# so about one leg in five is cut again; the sweep stayed 95 of 95 right and trusted with it.
RECUTS = 2


def _refine_icp(config: Config) -> IcpConfig:
    """The refinement's ICP: ``config.candidates``' metric, patience and iterations on ``config.icp``."""
    cc = config.candidates
    return replace(config.icp, metric=cc.refine_metric, patience=cc.refine_patience,
                   max_iterations=min(config.icp.max_iterations, cc.refine_iterations))


def refine(source: Scan, target: Scan, surface: Surface, guess: Guess, config: Config, on_step=None,
           frame: LockFrame | None = None, at_T: Problem | None = None,
           settled_somewhere: Callable[[np.ndarray], bool] = lambda T: True) -> tuple[np.ndarray, Problem | None]:
    """ICP (``config.candidates.refine_metric``) on the robust E from the pose of ``guess`` (its stated
    uncertainty, the rotation at most ``refine_rotation_deg``): on the overlap cut there (``at_T``, when one was
    cut there already), then, where ``settled_somewhere(T)`` says the pose found has settled somewhere (a share of
    the basis matched: :class:`core.candidates.CandidateConfig`'s ``settle_share``), on the converged cut at it (under
    ``frame``'s lock, when given: core.lock). Returns the pose and that last cut; None for the cut where the pose
    settled nowhere (no converged cut was made: the pose as the first leg left it, which trust cannot take)."""
    cc = config.candidates
    icp_config = _refine_icp(config)
    T = guess.T_target_source
    # the first cut tests visibility from the target's sensor, as the guess's own cut does: a frustum alone holds the
    # whole of an object seen from afar, and on two turntable stops 72 deg apart (a third of the source seen by both)
    # the robust E over the whole source was lowest 22 deg from the truth, where KISS-Matcher's pose 1.5 deg off
    # walked (the 10-scan campaign's scan03 -> scan05: 37.8k of 38.6k points cut; 26.1k with the test, refined to
    # 0.14 deg). A fused cloud has no sensor: there the test would widen its closeness cut by the guess's reach.
    near = config.problem if target.kind is not ScanKind.UNSTRUCTURED else replace(config.problem, visibility=False)
    p = at_T if at_T is not None else prepare(source, target, guess.narrowed(cc.refine_rotation_deg), near,
                                              surface=surface, seed=config.seed)
    T = icp(p.error, T, icp_config, on_step, frame=frame).T
    if not settled_somewhere(T):
        return T, None
    return converge(source, target, surface, T, config, config.problem, on_step, frame)


def converge(source: Scan, target: Scan, surface: Surface, T: np.ndarray, config: Config, problem: ProblemConfig,
             on_step=None, frame: LockFrame | None = None, legs: int = 1 + RECUTS,
             settled: tuple[float, float] | None = None,
             every_step: tuple[float, float] | None = None) -> tuple[np.ndarray, Problem]:
    """The refinement's ICP legs from pose T (4, 4) on the overlap cut at the pose (``problem``: its sample): each
    leg on a new cut where the pose has moved half the uncertainty the cut assumes or more, else on a fresh sample of
    the same cut, until a leg moves the pose less than ``settled`` (degrees, units at the source's centroid; default:
    that half, so every leg but the first starts on a new cut), ``legs`` at most. ``every_step`` (degrees, units): the
    legs take every ICP step until one is below it (core.icp: step_tolerance). Returns the pose and the last cut;
    raises InputError when there is no overlap at T."""
    icp_config = _refine_icp(config)
    if every_step is not None:
        icp_config = replace(icp_config, step_tolerance=every_step)
    rot_half, trans_half = (config.search.resegment_rotation_deg / 2,
                            config.search.resegment_translation * target.size / 2)
    rot_ok, trans_ok = settled or (rot_half, trans_half)
    p, T_cut = None, T
    for leg in range(legs):
        rot, trans = pose_error(T, T_cut, source.centroid)
        if p is None or rot >= rot_half or trans >= trans_half:  # the pose left what the cut assumed: cut again
            p, T_cut = prepare(source, target, Guess.converged(T, config.search, target.size), problem,
                               surface=surface, seed=config.seed), T
        else:  # the cut holds: a fresh sample of it (the same one would stop where the last leg did)
            p = resample(p, problem.max_points, [config.seed, leg])
        T_start, T = T, icp(p.error, T, icp_config, on_step, frame=frame).T
        rot, trans = pose_error(T, T_start, source.centroid)
        if rot < rot_ok and trans < trans_ok:
            break  # by default: the pose stayed well inside the uncertainty the cut assumed, so the cut holds at it
    return T, p


def _near(Ts: list[np.ndarray], T: np.ndarray, center: np.ndarray, rot: float, trans: float) -> bool:
    """Whether T lies within ``rot`` radians and ``trans`` (the move of ``center``) of any of ``Ts``."""
    if not Ts:
        return False
    r, t = offsets(np.stack(Ts), T, center)
    return bool(np.any((r <= rot) & (t <= trans)))


@dataclass
class Found:
    """What the stages found so far: every pose refined (with the source that gave it: a stage, the guess,
    the hybrid), the trusted pose inside the region (it ends the search), the first trusted beyond it, and
    the last cut of the trusted refinement inside."""

    refined: list = field(default_factory=list)
    sources: list = field(default_factory=list)  # beside refined
    inside: np.ndarray | None = None
    beyond: np.ndarray | None = None
    last_cut: Problem | None = None
    stopped: Stop | None = None  # the search's budget was spent during a refinement (it is given up)
    weak: bool = False  # a pose refined inside the region passes every test but the score's rise (end_on_weak)
    # a thinned pair's check (module notes in __init__: thinned): a pose trusted on the thinned scans, refined on
    # the whole ones (None: no cut there, the thinned pose stands); it counts as trusted only where that is too
    confirm: Callable[[np.ndarray], np.ndarray | None] | None = None
    confirmed: list = field(default_factory=list)  # the poses refined on the whole scans by ``confirm``

    def note(self, T: np.ndarray, source: str) -> None:
        """Pose T (4, 4) was found by ``source``."""
        self.refined.append(T)
        self.sources.append(source)

    def source_of(self, T: np.ndarray) -> str:
        """Which source gave pose T ('' for a pose never refined)."""
        return next((src for R, src in zip(self.refined, self.sources) if R is T), "")


def run_stage(setup: Setup, run: EventStream, hyp: Hypotheses, n: int, found: Found,
              doubted: Callable[[], None] | None = None) -> None:
    """Score the hypotheses in one query (events of phase 'candidates'); refine the best ``n`` by score,
    those inside the region first (once each: near-duplicates are skipped), until one is trusted inside;
    ``doubted()`` is called after a refined pose that does not end the stage (not trusted inside the region, nor
    weakly pinned where the search ends there)."""
    cc, poses = setup.config.candidates, hyp.poses
    poses = poses[:run.budget.grant("candidates", len(poses))]  # the guess and the cheap first, as they come
    if not poses:
        return
    scores = setup.basis.evaluate(np.stack(poses)).score
    run.leg("candidates")
    for T, s in zip(poses, scores):
        run.emit("candidates", T, float(s))
    inside = setup.region.contains(np.stack(poses))
    order = sorted(range(len(poses)), key=lambda k: (not inside[k], scores[k]))
    done: list[np.ndarray] = []
    trans = cc.distinct_translation * setup.target.size
    for k in order:
        if len(done) >= n or run.budget.spent() is not None:
            return
        if found.beyond is not None and not inside[k]:
            continue  # a pose beyond the region is trusted already: only one inside can say more
        if _near(done, poses[k], setup.source.centroid, np.radians(cc.distinct_rotation_deg), trans):
            continue
        done.append(poses[k])
        run.leg("icp")
        at_guess = setup.problem if poses[k] is setup.T_guess else None

        def refine_from(T0, at=None):
            return refine(setup.source, setup.target, setup.surface, setup.guess.at(T0), setup.config,
                          lambda T_, E_: run.emit("icp", T_, E_), setup.frame, at, setup.settled_somewhere)

        try:
            T, last = refine_from(poses[k], at_guess)
            if last is None:  # its first leg settled nowhere (core.candidates.CandidateConfig.settle_share): no legs,
                found.note(T, hyp.label(k))  # no trust (it has no converged cut), and the search goes on
                if doubted is not None:
                    doubted()
                continue
            T, last = along_the_free_motion(setup, run, T, last, refine_from)
        except BudgetSpent as spent:  # the budget ran out inside this refinement: it is given up, the search ends
            found.stopped = spent.stop
            return
        except InputError:  # its refinement walked to where the scans do not overlap: the candidate is given up
            continue
        if found.confirm is not None and setup.trusted(T):  # (the check first: a trust test costs a basis query)
            T_whole = found.confirm(T)
            if T_whole is not None:
                found.confirmed.append(T_whole)
                T, last = T_whole, None  # its cut is made again on the scans the result reports
        found.note(T, hyp.label(k))
        if setup.trusted(T) and not undercut(setup, found.refined, T):
            if setup.region.inside(T):
                found.inside, found.last_cut = T, last
                return
            if found.beyond is None:
                found.beyond = T
        elif cc.end_on_weak and setup.region.inside(T) and setup.threshold.weakly_pinned(setup.basis, T):
            found.weak = True
            return
        elif doubted is not None:
            doubted()


def undercut(setup: Setup, refined: list[np.ndarray], T: np.ndarray) -> bool:
    """Whether a pose among ``refined``, distinct from T (core.candidates.CandidateConfig's distinct
    rotation and translation) and overlapping both ways, scores lower than T on the basis: T is then not
    the lowest of the robust error found, and the pair threshold's trust is not the error's choice. Seen
    (2026-12-06) on RGB-D fragments fused from 15 frames of a room: KISS-Matcher's pose, the truth to
    0.05 deg but weakly pinned (doubted), scored 1.006e-4; a rotation sample then refined to the room
    turned half a turn, 1.086e-4 and well pinned, and was trusted 180 deg off. Not counted: a pose beyond
    the stated region, where T is inside it (the corner scene's twin 120 deg off scores 18.2, the truth 27.0);
    where T is weakly pinned, its slides (:data:`ALONG_THE_FREE_MOTION`), which may score lower (a room's floor and walls
    fit as well slid) and which the pair threshold's rise tests judged; a pose that puts one scan's points where the
    other's sensor looked through (core.intrusion: a room corner's twin scores below the truth, tsdf-13 8.5e-5
    against 9.1e-5)."""
    cc = setup.config.candidates
    others = [R for R in refined if not _near([R], T, setup.source.centroid, np.radians(cc.distinct_rotation_deg),
                                                cc.distinct_translation * setup.target.size) and _clear(setup, R)]
    if others and setup.region.inside(T):  # what the user stated comes first: only a pose inside it can undercut
        others = [R for R in others if setup.region.inside(R)]
    if not others:
        return False
    s = setup.basis.evaluate(np.stack(others + [T]))
    lower = [R for R, ok, score in zip(others, setup.basis.valid(s)[:-1], s.score[:-1]) if ok and score < s.score[-1]]
    if not lower:
        return False
    c = constraint(setup.basis, T, setup.threshold.free)
    return c.rise is None or any(c.alignment(T, R) < ALONG_THE_FREE_MOTION for R in lower)


def _clear(setup: Setup, T: np.ndarray) -> bool:
    """Whether pose T puts neither scan's points where the other's sensor looked through (core.intrusion)."""
    return clear(setup.basis, T, setup.threshold.max_intrusion)


def best_refined(setup: Setup, poses: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """The lowest score among ``poses`` that overlap both ways, those inside the region first, and before the others
    those that put neither scan's points where the other's sensor looked through (:func:`_clear`: a room corner's
    twin scores below the truth)."""
    s = setup.basis.evaluate(np.stack(poses))
    valid = setup.basis.valid(s)
    inside = setup.region.contains(np.stack(poses))
    apart = np.array([bool(ok) and _clear(setup, T) for T, ok in zip(poses, valid)])  # clear of the other's room
    for ok in (valid & inside & apart, valid & inside, valid & apart, valid, np.ones(len(poses), dtype=bool)):
        if ok.any():
            k = int(np.argmin(np.where(ok, s.score, np.inf)))
            return poses[k], float(s.score[k])
    raise AssertionError("unreachable: the last mask holds every pose")


def search_stages(setup: Setup, run: EventStream, confirm: Callable[[np.ndarray], np.ndarray | None] | None = None
                  ) -> tuple[Found, dict]:
    """Every stage in turn until one refines a pose the pair threshold trusts inside the region (module
    notes: stages, verdict); ``confirm``: :attr:`Found.confirm`. Returns what was found and, per stage, how many
    poses it gave or why none."""
    found, sources = Found(confirm=confirm), {}
    ordered = stages(setup)
    try:
        for stage in ordered:
            if found.stopped is not None or run.budget.spent() is not None or run.budget.left("candidates") == 0:
                sources[stage.name] = "not reached within the search's bound"
                continue
            if found.weak and found.beyond is None:
                sources[stage.name] = "not run: a weakly pinned pose was found, and the search was asked to end there"
                continue
            if found.beyond is not None and stage.start_free:
                sources[stage.name] = ("not run: a pose beyond the stated region is trusted, and this stage "
                                       "ignores the guess (it would give that pose again, not one inside)")
                getattr(stage.make, "cancel", lambda: None)()  # made ahead (stages.Ahead): it stops at its next step
                continue
            hyp = stage.make()
            if setup.frame is not None:
                hyp = Hypotheses([setup.frame.pose(setup.frame.free(T)) for T in hyp.poses], hyp.why_none, hyp.labels)
            sources[stage.name] = hyp.source_note
            if hyp.poses:
                run_stage(setup, run, hyp, stage.refine, found, stage.doubted)
            if found.inside is not None:
                break
    finally:  # the stages started ahead are told the search has ended
        ordered.close()
    return found, sources


