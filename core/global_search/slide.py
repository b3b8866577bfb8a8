"""Along the free motion: a refined pose tested against the poses it could slide to.

A scene of planes (a room, a street, a fused fragment of walls) leaves a pose that ICP reaches from a start a
metre off fitted at the noise level while slid along the walls: the capped robust error gives the few points
that would pull it home (the end walls, furniture) no gradient once they lie beyond the cap, and the surfaces
it matches agree anywhere along themselves. The matched point-to-plane system (core.threshold.constraint) says
which motion the matched points pin least; this step walks the pose along that translation, both ways, in
steps of one cap width (the distance within which a point counts as matched), scores every slid pose on the
fixed basis in one query, and refines from the best when it beats the pose by a clear margin. The truth, once
reached, is pinned: no slide scores lower, and the pose comes back unchanged (no event, no work beyond the
scoring). A pose whose weakest motion is a rotation is left as it is.

facing  where the whole score is flat along the walk (a fused room's walls match 86 % of the source at the truth and
        slid 0.8 m alike), the slides are scored again by the points facing the motion alone (the pair threshold's
        stable rise, core.threshold.MIN_STABLE_RISE: 1.46-1.63 at sim-fragments-0's truth, 0.98-1.00 at its slides),
        and the pose refined from the best is kept where the pair threshold trusts it and not the pose walked from:
        one more candidate, judged as every other (measured 2026-12-08: sim-fragments-0 from start 1, 12-22 cm
        along the room and doubted at every angle, docs/benchmarks.md).
"""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..problem import Problem
from ..search.budget import BudgetSpent
from ..threshold import constraint, facing_scores, facing_weights
from .setup import Setup
from .stream import EventStream

# Slid poses scored per test: a street's cap (0.7 spacing of ~0.1 m) over a quarter of its size would be ~700
# steps; beyond this the steps widen (a slid pose that near the truth still scores lower: its far walls match).
MAX_SLIDES = 400
# The farthest slide tried, as a share of the target's size, when the region does not bound it closer (no
# guess): the slides seen were 0.18-0.93 m in rooms 7 x 5 m (diagonal ~9 m) and 0.29-0.56 m on streets.
MAX_SLIDE_SHARE = 0.25
# A slid pose must score this much lower than the pose to be refined: at a converged pose the score moves by
# well under 1 % between neighbouring slides (measured on sim-room-2 from the identity: the slid pose 9.8e-5,
# the truth 6.0e-5: 39 % lower), so 10 % leaves the noise of a converged truth alone.
MARGIN = 0.9
# Facing (module notes): the slides whose facing score is lowest are refined, at most this many, each at least two
# steps from those tried: the facing score is not one valley (on sim-fragments-0 a slide 1.6 m along the room, where
# other furniture faces the motion, scores 4.1e-5 and the truth's neighbour 4.3e-5; the first is refused, 8 % of its
# points where the other's sensor saw empty space).
FACING_TRIES = 3
# Its cost bounded: at most FACING_POSES slides (every k-th of the walk's, both ways), scored on the points carrying
# FACING_MASS of the facing weight (at least FACING_MIN_POINTS). Scoring every slide on all 1500 constraint points took
# 5-18 s on a simulated street slid 36 m (400 slides of a panorama's frustum), where the refinement settles the pose
# within a few cap widths anyway.
FACING_POSES = 100
FACING_MASS = 0.95
FACING_MIN_POINTS = 30
ROUNDS = 2  # a refined slide is tested again (the second finds what the first's refinement left)
# The walk is taken only where the overlap pins the pose weakly (the constraint's smallest / largest eigenvalue
# below WALK_BELOW): the slid poses it was measured on score 0.008 (sim-fragments-0) and 0.013 (sim-room-2), the
# truths of the bunny pairs 0.047-0.119, rooms 0.047-0.077, the LiDAR pair 0.089 (core.threshold's notes). A walk
# at a truth is harmless but not free (~0.5 s on a bunny pair with no guess: 400 slides of a quarter of its size).
# (core.threshold.WEAK_BELOW, where the trust asks a rise, was this bound until a slid pose at 0.036 was trusted.)
WALK_BELOW = 0.03


def slides(setup: Setup, T: np.ndarray) -> np.ndarray:
    """(S, 4, 4) pose T translated along its weakest matched motion (target frame), both ways, one cap width
    apart up to the region's translation bound (MAX_SLIDE_SHARE of the target's size at most); (0, 4, 4) when
    the overlap pins T (WALK_BELOW), the weakest motion is a rotation or too few points match to say."""
    c = constraint(setup.basis, T, setup.threshold.free)
    t, r = c.weakest[:3], c.weakest[3:]
    if not c.matched or c.ratio >= WALK_BELOW or np.linalg.norm(t) < np.linalg.norm(r):
        return np.zeros((0, 4, 4))
    d = t / np.linalg.norm(t)
    reach = min(setup.region.translation + setup.region.slack_translation, MAX_SLIDE_SHARE * setup.target.size)
    step = max(float(np.sqrt(setup.basis.cap)), 2 * reach / MAX_SLIDES)
    k = np.arange(1, int(reach // step) + 1) * step
    if not len(k):
        return np.zeros((0, 4, 4))
    shifts = np.concatenate([k, -k])[:, None] * d
    poses = np.repeat(np.asarray(T, dtype=np.float64)[None], len(shifts), axis=0)
    poses[:, :3, 3] += shifts
    return poses


def along_the_free_motion(setup: Setup, run: EventStream, T: np.ndarray, last: Problem,
                          refine_from) -> tuple[np.ndarray, Problem]:
    """Pose T (4, 4), or the pose refined from its best slide where that scores lower (module notes), and its
    last cut. ``refine_from(T0)`` -> (T, cut): the stage's refinement (its ICP steps charged as the stage's; the cut
    None where it settled nowhere).
    The slid poses are charged as candidates scored; a budget spent inside returns what was found so far."""
    poses = None
    for _ in range(ROUNDS):
        poses = slides(setup, T)
        poses = poses[:run.budget.grant("candidates", len(poses))]
        if not len(poses):
            return T, last
        scores = setup.basis.evaluate(np.concatenate([np.asarray(T)[None], poses])).score
        k = int(np.argmin(scores[1:]))
        if not scores[1 + k] < MARGIN * scores[0]:
            break
        run.leg("icp")
        try:
            T2, last2 = refine_from(poses[k])
        except BudgetSpent:  # spent: what was found so far, nothing more scored
            return T, last
        except InputError:  # the slide's refinement left the overlap: keep the pose
            break
        if last2 is None:  # the slide's refinement settled nowhere: keep the pose
            break
        if not setup.basis.evaluate(T2[None]).score[0] < scores[0]:
            break
        T, last, poses = T2, last2, None
    return _facing(setup, run, T, last, poses, refine_from)


def _facing(setup: Setup, run: EventStream, T: np.ndarray, last: Problem, poses: np.ndarray | None,
            refine_from) -> tuple[np.ndarray, Problem]:
    """Where the whole score no longer leads the walk from pose T (its slides ``poses`` (S, 4, 4), or None: made
    here), the slides scored by the points facing T's weakest motion alone (core.threshold.facing_scores: the end walls, the
    furniture, whose rise pins a truth, MIN_STABLE_RISE); the pose refined from the best of them where it beats T's
    by MARGIN (the lowest FACING_TRIES valleys, the lowest first), the first the pair threshold trusts, where it does
    not trust T (module notes: facing)."""
    if setup.basis.constraint_normals is None or setup.trusted(T):
        return T, last
    c = constraint(setup.basis, T, setup.threshold.free)
    weights = facing_weights(setup.basis, T, c)
    if not c.matched or not weights.sum() > 0:
        return T, last
    poses = slides(setup, T) if poses is None else poses
    poses = poses[::-(-len(poses) // FACING_POSES)] if len(poses) else poses
    poses = poses[:run.budget.grant("candidates", len(poses))]
    if not len(poses):
        return T, last
    order = np.argsort(weights)[::-1]  # the points that carry FACING_MASS of the weight: the rest barely count
    keep = np.sort(order[:max(FACING_MIN_POINTS, int(np.searchsorted(np.cumsum(weights[order]),
                                                                      FACING_MASS * weights.sum())) + 1)])
    scores = facing_scores(setup.basis, weights, np.concatenate([np.asarray(T)[None], poses]), keep)
    shifts = poses[:, :3, 3] - np.asarray(T)[:3, 3]
    apart = 2.0 * np.sqrt(setup.basis.cap)  # two of the walk's steps at least
    tried: list[np.ndarray] = []
    for k in np.argsort(scores[1:], kind="stable"):
        if not scores[1 + k] < MARGIN * scores[0] or len(tried) == FACING_TRIES:
            break
        if any(np.linalg.norm(shifts[k] - d) < apart for d in tried):
            continue  # a neighbour of a slide tried: the same basin
        tried.append(shifts[k])
        run.leg("icp")
        try:
            T2, last2 = refine_from(poses[k])
        except BudgetSpent:
            break
        except InputError:
            continue
        if last2 is not None and setup.trusted(T2):
            return T2, last2
    return T, last
