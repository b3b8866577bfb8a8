"""The merge's sequence step (core.merge, ``pairs="sequence"``): a chain of frames in capture order (RGB-D
frames, a LiDAR's turns along a path) merges as odometry plus loop closure.

1. Odometry: each consecutive pair (k, k+1) registered from the initial poses' relative pose (none
   given: the identity, consecutive frames lie close) in the stated region (``Config.problem``: how far
   one frame may move from the next; with initial poses, twice the per-scan region as for any pair).
2. Loop candidates: under the odometry's poses (the graph of the consecutive pairs), the pairs that are
   not consecutive and overlap by at least ``min_overlap`` by the scans' kind of overlap (a frustum for a
   single view, the panorama's own; core.merge_tasks.overlap_task), measured only for each frame's
   likeliest partners (core.merge_pairs.likeliest), each frame keeping its ``loop_partners`` best. They
   are registered from the odometry's relative pose in ``found_rotation_deg`` and go to the pose graph
   (core.posegraph) with the odometry: a loop that closes is optimised as a loop, one that does not is
   rejected, and the report gives each loop's closing residual (core.merge_report.rings).
"""

from __future__ import annotations

from typing import Any

from .merge_pairs import Candidate, likeliest
from .merge_progress import Step
from .merge_result import Start
from .merge_tasks import PairTask, overlap_task
from .posegraph import Graph
from .transforms import invert

# core.merge's campaign state, by name only: core.merge imports this module
_Campaign = Any


def odometry_tasks(c: _Campaign) -> list[PairTask]:
    """Round 1: the consecutive pairs from the initial poses (the identity when none) in the step's region."""
    rot, trans = c.region() if c.have else (c.stated.rotation_deg, c.stated.translation)
    start = Start.ROUGH_POSES if c.have else Start.IDENTITY
    return [PairTask(k, k + 1, c.rel(k, k + 1), rot, trans, start=start) for k in range(c.n - 1)]


def loop_candidates(c: _Campaign, g: Graph) -> list[Candidate]:
    """The non-consecutive pairs of placed frames that overlap by ``min_overlap`` under the graph's poses
    (module notes, step 2), each frame's ``loop_partners`` best by overlap (a pair kept when either frame keeps it)."""
    P = g.poses
    near = [(i, j) for i, j in likeliest(c, P, c.mc.measure_partners, rotation=0.0)
            if j - i > 1 and (i, j) not in c.pairs]
    if not near:
        return []
    c.note(Step.OVERLAPS, f"measuring the overlap of {len(near)} loop candidates under the odometry's poses")
    fracs = c.measure(overlap_task, [(i, j, invert(P[i]) @ P[j]) for i, j in near], Step.OVERLAPS)
    over = [Candidate(i, j, f) for (i, j), f in zip(near, fracs) if f >= c.mc.min_overlap]
    c.skipped |= {p for p, f in zip(near, fracs) if f < c.mc.min_overlap}
    keep: set[tuple[int, int]] = set()
    for k in range(c.n):
        mine = sorted((x for x in over if k in x.key), key=lambda x: (-x.overlap, x.key))
        keep |= {x.key for x in mine[:c.mc.loop_partners]}
    return sorted((x for x in over if x.key in keep), key=lambda x: x.key)


def loop_tasks(c: _Campaign, g: Graph) -> list[PairTask]:
    """Round 2: the loop candidates, each from the odometry's relative pose (module notes)."""
    P = g.poses
    return [PairTask(x.i, x.j, invert(P[x.i]) @ P[x.j], c.mc.found_rotation_deg, None, start=Start.GRAPH_POSE)
            for x in loop_candidates(c, g)]

