"""The merge's rounds step (core.merge): the pairs the next round registers, under the poses found.

1. Again: a pair not used, registered once, whose scans match by at least ``min_overlap`` under the
   poses found, is registered again from the graph's pose before it is given up; one whose last
   registration ended at a weakly pinned pose (core.merge.MergeConfig.guess_ends_on_weak) and that no
   loop corroborated, where the graph's poses do not give it that try, is registered again as last
   asked, with every stage of the search (once a pair).
2. Fresh: pairs that now overlap, each scan's best partners under the poses found, not registered yet (half of
   them long links in the first round chosen by overlap after the cue's: core.merge_pairs.partners).
Both from the graph's pose, between scans it places: each ends at the first weakly pinned pose it refines, as
round 1's from a guess (``guess_ends_on_weak``), and the next graph judges it; not in the last regular round
(``max_rounds``), after which no round could give it every stage.
3. Groups: scans the used pairs do not join to the reference (core.merge_groups).

Only pairs that could overlap under the poses found are measured (bounding spheres that meet, each
scan's ``measure_partners`` likeliest: core.merge_pairs.likeliest); a pair that matches by less than
``min_overlap`` under them is not registered (the pair threshold asks 30 % of the source's sample to
match: it could not be trusted).
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from .merge_groups import join_tasks
from .merge_pairs import Candidate, choose, likeliest
from .merge_progress import Step
from .merge_result import Start
from .merge_tasks import PairTask, share_task
from .posegraph import Graph
from .result import StopReason
from .transforms import invert

if TYPE_CHECKING:
    from .merge_graph import Screened

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any



def near_pairs(c: _Campaign, g: Graph, used: set, partners: int | None = None) -> list[tuple[int, int]]:
    """Pairs of placed scans, not used, whose bounding spheres meet under the graph's poses (each scan's
    ``partners`` likeliest partners, default ``measure_partners``)."""
    P = g.poses
    out = []
    for i, j in likeliest(c, P, partners or c.mc.measure_partners, rotation=0.0):
        if (i, j) not in used and close(c, P, i, j):
            out.append((i, j))
    return out


def close(c: _Campaign, P: list, i: int, j: int) -> bool:
    """Whether scans i and j could overlap under poses P: their bounding spheres meet."""
    ci = P[i][:3, :3] @ c.centers[i] + P[i][:3, 3]
    cj = P[j][:3, :3] @ c.centers[j] + P[j][:3, 3]
    return float(np.linalg.norm(ci - cj)) < c.radius[i] + c.radius[j]


def next_tasks(c: _Campaign, g: Graph, screened: Screened) -> list[PairTask]:
    """The next round's registrations (module notes)."""
    P = g.poses
    used = {screened.usable[k] for k in g.kept}
    found = c.mc.found_rotation_deg
    long = c.mode == "features" and not c.long_links
    near = near_pairs(c, g, used, c.mc.long_measure_partners if long else None)
    shares = c.measure(share_task, [(i, j, invert(P[i]) @ P[j]) for i, j in near], Step.OVERLAPS) if near else []
    over = dict(zip(near, shares))
    c.shares.update(over)
    # (ended at a weakly pinned pose, such a registration is given every stage in the round after, if there is one)
    weak_ends = c.mc.guess_ends_on_weak and c.round + 1 < c.mc.max_rounds
    tasks = []
    for (i, j), f in over.items():
        if (i, j) in c.pairs and c.tried[i, j] == 1 and f >= c.mc.min_overlap:
            tasks.append(PairTask(i, j, invert(P[i]) @ P[j], found, None, attempt=1, start=Start.GRAPH_POSE,
                                  end_on_weak=weak_ends))
    again = {(t.i, t.j) for t in tasks}
    weak = [replace(c.tasks[k], attempt=c.tried[k], end_on_weak=False) for k, p in sorted(c.pairs.items())
            if k not in used and k not in again and k not in c.weak_again and p.stop is not None
            and p.stop.reason is StopReason.WEAKLY_PINNED]
    c.weak_again |= {(t.i, t.j) for t in weak}
    tasks += weak
    fresh = [Candidate(i, j, f) for (i, j), f in over.items() if (i, j) not in c.pairs]
    # the best by overlap, the used pairs counting as the best; half of them long links in the first round chosen
    # by overlap (round 1's, under rough poses; the round after the cue's, from none: its pairs are each scan's
    # nearest, and 500 stops of a turntable chained by them drifted, 179 scans placed 2.0-3.1 mm off)
    c.long_links |= long
    for x in choose(fresh + [Candidate(i, j, 1.0) for i, j in used], c.n, "init", c.mc, long=long):
        if x.key not in c.pairs and x.key in over:
            tasks.append(PairTask(x.i, x.j, invert(P[x.i]) @ P[x.j], found, None, start=Start.GRAPH_POSE,
                                  end_on_weak=weak_ends))
    c.skipped |= {p for p, f in over.items() if p not in c.pairs and f < c.mc.min_overlap}
    mine = {(t.i, t.j) for t in tasks}  # a pair once a round: a weakly pinned one's try with every stage before a join's
    return tasks + [t for t in join_tasks(c, g, sorted(used)) if (t.i, t.j) not in mine]


def join_only(c: _Campaign, g: Graph, screened: Screened) -> list[PairTask]:
    """Past the regular rounds: only the pairs that could join a group left apart (core.merge_groups)."""
    return join_tasks(c, g, sorted(screened.usable[k] for k in g.kept))
