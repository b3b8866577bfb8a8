"""The merge's groups step (core.merge): scans the used pairs do not join to the reference, joined.

For each group of them (joined among themselves, or alone), the pairs across to the placed scans and to
the scans of the other groups apart that could join it, likeliest first (two groups apart joined to each
other reach the reference together, or are one larger group the next round reaches: on the 24-stop
turntable's crops from no poses, round 1 joined only scans 0-1 to the reference while the groups 13-14,
15-16, 18-21 and 22-23 were trusted, right and apart; tried only against scans 0 and 1, they stayed apart):

1. by a turntable's order: where the group's poses and the placed scans' share an axis (core.turntable),
   the scans at the ends of each one's arc are where the two meet (a ring missing a link: the ends'
   pairs are the link), with no guess;
2. by the rough poses: pairs that overlap under them, in the stated region about them;
3. by the features' cue (core.merge_cue): each scan of the group with its likeliest partners among the
   scans outside it, with no guess; a pair tried only from the rough poses gets one try with no guess (a
   rough pose may be further off than stated).

A pair between two groups apart is one task a round, not one per group. What joining groups can add,
a scan at the end of a long open chain of pairs whose errors add up, the graph step does not place
(core.merge_graph.drift).

``reach_partners`` of them a round per group, round after round while the group stays apart and
untried pairs that could join it remain (``join_partners`` by the cue per scan of it): a scan is left
not placed only when every one of them was tried and said why.
"""

from __future__ import annotations

from typing import Any

from .merge_pairs import key, labels
from .merge_result import Start
from .merge_tasks import PairTask
from .posegraph import Graph
from .turntable import arc_ends

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any



def groups(c: _Campaign, g: Graph, used: list[tuple[int, int]]) -> list[list[int]]:
    """The groups of scans not placed: each a list of scans joined among themselves by used pairs."""
    label = labels(c.n, used)
    out: dict[int, list[int]] = {}
    for k in range(c.n):
        if not g.placed[k]:
            out.setdefault(label[k], []).append(k)
    return [out[lab] for lab in sorted(out)]


def ring_pairs(c: _Campaign, g: Graph, inside: list[int], placed: list[int]) -> list[tuple[int, int]]:
    """Pairs (keys) between the ends of the group's arc and the placed scans' (a turntable's order), when
    both share an axis; [] otherwise. The group's poses are those among its own scans: the graph places
    only the reference's group, so they are the ring's tree poses solved apart."""
    own = c.group_poses(inside)
    if own is None:
        return []
    mine = arc_ends([own[k][:3, :3] for k in inside])
    theirs = arc_ends([g.poses[k][:3, :3] for k in placed])
    if mine is None or theirs is None:
        return []
    ends_in = {inside[mine[0]], inside[mine[1]]}
    ends_out = {placed[theirs[0]], placed[theirs[1]]}
    return sorted({key(a, b) for a in ends_in for b in ends_out})


def join_tasks(c: _Campaign, g: Graph, used: list[tuple[int, int]]) -> list[PairTask]:
    """The next pairs that could join each group of unplaced scans to the placed ones (module notes)."""
    placed = [m for m in range(c.n) if g.placed[m]]
    rot, trans = c.region()
    tasks = []
    taken: set[tuple[int, int]] = set()  # this round's pairs (a pair between two groups apart is one task)
    c.join_left = {}  # this round's groups only (an earlier round's may have joined since)
    for inside in groups(c, g, used):
        # the scans it could join: the placed ones, and those of the other groups apart (two groups joined
        # to each other join the reference together, or are one larger group the next round can reach)
        others = [m for m in range(c.n) if m not in inside]
        by_ring = ring_pairs(c, g, inside, placed)
        reach = [key(u, m) for u in inside for m in others]
        rough = sorted((p for p in reach if p not in c.pairs and c.init_overlap.get(p, 0.0) >= c.mc.min_overlap_any),
                       key=lambda p: -c.init_overlap[p])
        by_cue = set()
        for u in inside:
            if any(untried(c, key(u, m), Start.NO_GUESS) for m in others):  # the cue's features only when needed
                best = c.cue.rank(u, among=others)[:c.mc.join_partners]
                by_cue |= {key(u, m) for m in best}
        order = ([(p, Start.NO_GUESS) for p in by_ring] + [(p, Start.ROUGH_POSES) for p in rough]
                 + [(p, Start.NO_GUESS) for p in sorted(by_cue, key=lambda p: (-c.cue.score(*p), p))])
        picks, seen = [], set()
        for p, start in order:
            if p in seen or p in taken or not untried(c, p, start):
                continue
            seen.add(p)
            picks.append((p, start))
        c.join_left[tuple(inside)] = max(0, len(picks) - c.mc.reach_partners)  # left after this round's
        for (i, j), start in picks[:c.mc.reach_partners]:
            taken.add((i, j))
            by_pose = start is Start.ROUGH_POSES
            tasks.append(PairTask(i, j, c.rel(i, j), rot if by_pose else 180.0, trans if by_pose else None,
                                  attempt=c.tried.get((i, j), 0), start=start))
    return tasks


def untried(c: _Campaign, p: tuple[int, int], start: Start) -> bool:
    """Whether pair p may still be tried from ``start``: never registered; or, with no guess, registered
    only from the rough poses (and not trusted there)."""
    if p not in c.pairs:
        return True
    if start is not Start.NO_GUESS:
        return False
    done = c.pairs[p]
    rough = 2 if p in c.weak_again else 1  # a weakly pinned try is tried again as asked (core.merge_rounds)
    return c.tried[p] == rough and done.start is Start.ROUGH_POSES and not done.trusted
