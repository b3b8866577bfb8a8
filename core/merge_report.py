"""The merge's report step (core.merge): every registered pair's status and why, every scan's placement
and why not, and the loops the final graph closes with their closing residuals."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any

from . import merge_graph
from .merge_result import PairResult, PairStatus, Rejection, Ring, ScanReport, ScanStatus
from .posegraph import Graph, residual

if TYPE_CHECKING:
    from .merge_graph import Screened

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any



def pair_statuses(c: _Campaign, g: Graph, screened: Screened) -> list[PairResult]:
    """Each registered pair's last registration with its status, the kind of why not and the why."""
    index = {k: e for e, k in enumerate(screened.usable)}
    out = []
    for key, p in sorted(c.pairs.items()):
        e = index.get(key)
        status, kind, reason = PairStatus.REJECTED, None, ""
        if key in screened.why:
            kind, reason = screened.why[key]
        elif e in g.rejected:
            kind, reason = Rejection.DOES_NOT_CLOSE, g.rejected[e]
        elif g.poses[p.i] is None or g.poses[p.j] is None:
            loose = [c.scans[k].name for k in (p.i, p.j) if k in c.loose]
            kind, reason = Rejection.NOT_JOINED, (
                f"{' and '.join(loose)} not placed: too uncertain where the chain of pairs that joins it ends"
                if loose else f"its scans are not joined to {c.scans[c.reference].name} (the frame of the poses) "
                              "by used pairs")
        else:
            status, reason = PairStatus.USED, screened.corroborated.get(key, "")
        if status is PairStatus.REJECTED and c.tried[key] == 1 and c.shares.get(key, 1.0) < c.mc.min_overlap:
            reason += (f"; not registered again: under the poses found its scans match by "
                       f"{c.shares[key]:.0%}, too little to be trusted")
        out.append(replace(p, status=status, rejection=kind, reason=reason,
                           cycle=g.cycle.get(e) if e is not None else None))
    return out


def scan_reports(c: _Campaign, g: Graph, pairs: list[PairResult]) -> list[ScanReport]:
    out = []
    for k, s in enumerate(c.scans):
        trusted = tuple(sorted(p.j if p.i == k else p.i for p in pairs if p.trusted and k in (p.i, p.j)))
        placed = g.poses[k] is not None
        out.append(ScanReport(s.name, ScanStatus.PLACED if placed else ScanStatus.NOT_PLACED, trusted,
                              g.scan_cycle[k] if placed else None, "" if placed else why_not(c, k, pairs)))
    return out


def reason_of(c: _Campaign, p: PairResult) -> str:
    """Why pair p, as registered so far, is not used (it is about to be registered again)."""
    if not p.trusted:
        return "not trusted" + ("" if p.misfit is None else f" (misfit {p.misfit:.3g})")
    if c.last is None:
        return "not used"
    g, screened = c.last
    if p.key in screened.why:
        return screened.why[p.key][1]
    e = {k: m for m, k in enumerate(screened.usable)}.get(p.key)
    return g.rejected.get(e, "not used") if e is not None else "not used"


def why_not(c: _Campaign, k: int, pairs: list[PairResult]) -> str:
    """Why scan k is not placed, naming what was tried to join it."""
    if k in c.loose:
        return c.loose[k]
    mine = [p for p in pairs if k in (p.i, p.j)]
    left = next((n for group, n in c.join_left.items() if k in group), 0)
    tail = "" if left == 0 else f"; {left} more pairs could join it but the rounds ran out"
    if not mine:
        return "no pair with it was registered" + tail
    trusted = [p for p in mine if p.trusted]
    if not trusted:
        return f"no trusted pair reaches it ({len(mine)} registered, none trusted)" + tail
    return "its trusted pairs were rejected: " + "; ".join(
        f"with {c.scans[p.j if p.i == k else p.i].name}: {p.reason}" for p in trusted) + tail


def rings(c: _Campaign, g: Graph, screened: Screened) -> tuple[Ring, ...]:
    """The loops the final graph closes among the placed scans, longest first: per kept pair off the graph's
    spanning tree, the scans round its cycle, and by how much it missed the tree's poses (the drift the loop
    had before the graph optimised it as a loop) and misses the final poses. A loop inside a group of scans
    not placed (the graph keeps its pairs, but it has no final poses) is not one of the model's."""
    keys = screened.usable
    es = merge_graph.edges(c, keys)
    tree_keys = [keys[e] for e in g.tree]
    adj: dict[int, list[int]] = {k: [] for k in range(c.n)}
    for i, j in tree_keys:
        adj[i].append(j)
        adj[j].append(i)
    out = []
    for e in g.kept:
        if e in g.tree or e not in g.cycle:
            continue
        i, j = keys[e]
        path = _path(adj, i, j)
        if path is None or g.poses[i] is None or g.poses[j] is None:
            continue
        after = residual(es[e].T_i_j, g.poses[i], g.poses[j], c.centers[j])
        out.append(Ring(tuple(path), (i, j), tuple(g.cycle[e]), after))
    return tuple(sorted(out, key=lambda r: (-len(r.order), r.closing)))


def _path(adj: dict[int, list[int]], a: int, b: int) -> list[int] | None:
    """The scans on the tree's path from a to b (a first), None when not joined."""
    parent = {a: a}
    stack = [a]
    while stack:
        k = stack.pop()
        if k == b:
            break
        for m in adj[k]:
            if m not in parent:
                parent[m] = k
                stack.append(m)
    if b not in parent:
        return None
    path = [b]
    while path[-1] != a:
        path.append(parent[path[-1]])
    return path[::-1]
