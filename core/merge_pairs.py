"""The merge's pairs step (core.merge): which pairs round 1 registers, as typed candidates.

With informative poses, the pairs that overlap under them: a cheap look first (where each scan's
sensor looks at its scan from, under the poses), so that only each scan's likeliest partners have
their overlap measured (cost in proportion to the scans, not to all pairs of them); with none, every
pair up to ``all_pairs_up_to`` scans, else each scan's likeliest neighbours by the features' cue.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .guess import Guess
from .merge_progress import Step
from .merge_result import Start
from .merge_tasks import PairTask, overlap_task
from .posegraph import components

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any
MergeConfig = Any



@dataclass(frozen=True)
class Candidate:
    """A pair (i < j) that may be registered, with its measured overlap share under some poses."""

    i: int
    j: int
    overlap: float

    @property
    def key(self) -> tuple[int, int]:
        return self.i, self.j


def key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


def labels(n: int, pairs) -> list[int]:
    """A group label per scan under pairs (keys or candidates)."""
    return components(n, [p.key if isinstance(p, Candidate) else tuple(p[:2]) for p in pairs])


def choose(overlaps: list[Candidate], n: int, mode: str, mc: MergeConfig, long: bool = True) -> list[Candidate]:
    """Candidate pairs from measured overlaps: "overlap" every pair above min_overlap; "init" each scan's
    max_partners best (both ways, or either where that leaves separate groups; ``long``: half of them
    long links, :func:`partners`, else all by the largest overlap); "chain" as given above
    min_overlap_any. A scan left with none keeps its best above min_overlap_any."""
    floor = mc.min_overlap_any if mode == "chain" else mc.min_overlap
    chosen = [c for c in overlaps if c.overlap >= floor]
    if mode == "init":
        # a pair both of whose scans count the other among their best partners (the union where that
        # leaves separate groups): a scan seen from behind can look overlapping near its silhouette
        # (12-stop turntable: 48 % "overlap" at 180 degrees, ranked 4th by the far scan alone)
        best = {k: partners(chosen, k, mc, long) for k in range(n)}
        mutual = [c for c in chosen if c.key in best[c.i] and c.key in best[c.j]]
        either = [c for c in chosen if c.key in best[c.i] or c.key in best[c.j]]
        chosen = mutual if len(set(labels(n, mutual))) == 1 else either
    for k in range(n):
        if not any(k in c.key for c in chosen):
            mine = [c for c in overlaps if k in c.key]
            top = max(mine, key=lambda c: c.overlap) if mine else None
            if top is not None and top.overlap >= mc.min_overlap_any:
                chosen.append(top)
    return sorted(chosen, key=lambda c: c.key)


def informative(c: _Campaign, poses: list) -> bool:
    """Whether ``poses`` (T_world_scan) tell the scans apart beyond the pair's stated region: some two
    sensors look at their scans from directions further apart than the region's rotation, or some two
    scans' centres lie further apart than a scan's size. Every pose the identity (a turntable nobody
    calibrated) does not: its scans all lie where the sensor looked, whatever the table's angle."""
    look, centre = _looks(c, poses, list(range(c.n)))
    angle = np.degrees(np.arccos(np.clip(look @ look.T, -1.0, 1.0)))
    gap = np.linalg.norm(centre[:, None] - centre[None], axis=2)
    return bool(angle.max() > c.region()[0] or gap.max() > float(np.median(c.radius)))


def _looks(c: _Campaign, poses: list, ks: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) unit directions each scan's sensor looks at its centroid from, and (K, 3) the centroids,
    under ``poses`` (world)."""
    centre = np.array([poses[k][:3, :3] @ c.centers[k] + poses[k][:3, 3] for k in ks])
    sensor = np.array([poses[k][:3, :3] @ c.scans[k].viewpoint + poses[k][:3, 3] for k in ks])
    look = centre - sensor
    return look / np.maximum(np.linalg.norm(look, axis=1, keepdims=True), 1e-12), centre


def partners(chosen: list[Candidate], k: int, mc: MergeConfig, long: bool = True) -> set[tuple[int, int]]:
    """Scan k's best partners (keys): half its max_partners by the largest overlap, the others the pairs
    that overlap least while still by long_overlap (long links: where the scans stand close, as 500 stops
    of a turntable do, the best by overlap are all within 2 stops and the graph drifts along them)."""
    mine = sorted((c for c in chosen if k in c.key), key=lambda c: (-c.overlap, c.key))
    near = mine[:(mc.max_partners + 1) // 2 if long else mc.max_partners]
    far = [c for c in mine[len(near):] if c.overlap >= mc.long_overlap][::-1][:mc.max_partners - len(near)]
    rest = [c for c in mine[len(near):] if c not in far][:mc.max_partners - len(near) - len(far)]
    return {c.key for c in near + far + rest}


def likeliest(c: _Campaign, poses: list, partners: int, among: list[int] | None = None,
              rotation: float | None = None) -> list[tuple[int, int]]:
    """Pairs (keys) of each scan with its ``partners`` likeliest partners under ``poses`` (T_world_scan,
    None: not posed) by a look that costs no overlap: scans whose bounding spheres meet, nearest first
    by the angle between the directions their sensors look at them from, then by the distance between
    their centres (the spheres may move by what the pair's region allows: ``rotation`` degrees, default
    the stated pair region's, and its translation). All pairs when there are no more than that.
    ``among``: the scans to pair (default all posed)."""
    ks = [k for k in (range(c.n) if among is None else among) if poses[k] is not None]
    if len(ks) <= partners + 1:
        return [(a, b) for x, a in enumerate(ks) for b in ks[x + 1:]]
    look, centre = _looks(c, poses, ks)
    radius = np.array([c.radius[k] for k in ks])
    gap = np.linalg.norm(centre[:, None] - centre[None], axis=2)
    # the region may move a centre: by the chord its rotation sweeps at the sensor's distance, and its translation
    rot, trans = c.region() if rotation is None else (rotation, 0.0)
    reach = np.array([np.linalg.norm(poses[k][:3, :3] @ (c.centers[k] - c.scans[k].viewpoint)) for k in ks])
    slack = 2 * np.sin(np.radians(min(rot, 180.0)) / 2) * np.maximum(reach[:, None], reach[None]) + (trans or 0.0)
    angle = np.degrees(np.arccos(np.clip(look @ look.T, -1.0, 1.0)))
    scale = max(float(np.median(radius)), 1e-12)
    rank = angle + 90.0 * gap / scale  # a sensor turned by 90 degrees weighs as much as a centre moved by a size
    rank[gap >= radius[:, None] + radius[None] + slack] = np.inf
    np.fill_diagonal(rank, np.inf)
    out = set()
    for a in range(len(ks)):
        for b in np.argsort(rank[a], kind="stable")[:partners]:
            if np.isfinite(rank[a, b]):
                out.add(key(ks[a], ks[int(b)]))
    return sorted(out)


def first_tasks(c: _Campaign) -> list[PairTask]:
    """Round 1's registrations (module notes)."""
    n, mode, mc = c.n, c.mode, c.mc
    rot, trans = c.region()
    if mode == "all":
        chosen = [(i, j) for i in range(n) for j in range(i + 1, n)]
    elif mode == "chain":
        chosen = [(i, i + 1) for i in range(n - 1)] + ([(0, n - 1)] if n > 2 else [])
    elif mode == "features":
        chosen = c.cue.pairs(mc.cue_partners)
    else:
        items = likeliest(c, c.initial, mc.measure_partners)
        c.init_overlap = dict(zip(items, initial_overlaps(c, items)))
        chosen = [x.key for x in choose([Candidate(i, j, f) for (i, j), f in c.init_overlap.items()], n, mode, mc)]
    start = Start.ROUGH_POSES if c.have else Start.NO_GUESS
    return [PairTask(i, j, c.rel(i, j), rot, trans, start=start) for i, j in chosen]


def initial_overlaps(c: _Campaign, items: list[tuple[int, int]]) -> list[float]:
    """The overlap of each pair under the initial poses (core.merge_tasks.overlap_task)."""
    if not items:
        return []
    c.note(Step.OVERLAPS, f"measuring the overlap of {len(items)} pairs under the initial poses")
    guesses = [c.rel(i, j) for i, j in items]
    # where the stated region lets a scan move by about its size at its centroid (a rotation about an
    # origin far from the scans: a sensor's, a turntable's), the rough poses say little about where it
    # lies: its overlap is also measured with its centroid on the partner's, counting the points that
    # face the partner's sensor (10-stop turntable, 15 deg about the sensor: round 1 then picks the
    # 20 pairs within 2 stops, all trusted; measured as given, 14 pairs of which 8 far apart)
    aligned = [k for k, ((i, j), T) in enumerate(zip(items, guesses)) if loose(c, i, j, T)]
    fracs = c.measure(overlap_task, [(i, j, T) for (i, j), T in zip(items, guesses)]
                      + [(*items[k], centred(c, *items[k], guesses[k]), True) for k in aligned], Step.OVERLAPS)
    for m, k in enumerate(aligned):
        fracs[k] = max(fracs[k], fracs[len(items) + m])
    return fracs[:len(items)]


def loose(c: _Campaign, i: int, j: int, T: np.ndarray) -> bool:
    """Whether pair (i, j)'s region (guess T_i_j) lets scan j's centroid move by align_from x scan i's size."""
    rot, trans = c.region()
    return Guess(T, rot, trans).region(c.scans[j], c.scans[i]).translation >= c.mc.align_from * c.scans[i].size


def centred(c: _Campaign, i: int, j: int, T: np.ndarray) -> np.ndarray:
    """T_i_j moved so that scan j's centroid lands on scan i's."""
    out = T.copy()
    out[:3, 3] += c.centers[i] - (T[:3, :3] @ c.centers[j] + T[:3, 3])
    return out
