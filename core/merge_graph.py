"""The merge's graph step (core.merge): which registered pairs the pose graph may use, and the graph.

A pair the pose graph may use is trusted, and not an outlier among the campaign's trusted pairs (its E
or its misfit far above their median: the scans of one campaign share a sensor, so right pairs agree
at much the same level). The graph (core.posegraph) keeps the pairs that close; the poses are in the
first scan's frame when its group is the largest, else in the largest group's first scan's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .merge_pairs import labels
from .merge_result import PairResult, Rejection
from .posegraph import Edge, Graph, Tolerance, information_matrix, solve

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any



@dataclass(frozen=True)
class Screened:
    """The pairs (keys) the graph may use, and for each other registered pair (kind, why in words)."""

    usable: list
    why: dict

    def rejected(self, key: tuple[int, int]) -> bool:
        return key in self.why


def screen(c: _Campaign) -> Screened:
    """The trusted pairs the graph may use, and why the others may not (module notes)."""
    why: dict[tuple[int, int], tuple[Rejection, str]] = {}
    trusted = [k for k, p in c.pairs.items() if p.trusted]
    for k, p in c.pairs.items():
        if not p.registered:
            why[k] = (Rejection.NOT_REGISTERED, p.stop_text)
        elif not p.trusted:
            why[k] = (Rejection.NOT_TRUSTED, "not trusted: too little of the pair overlaps to judge it" if p.misfit is None
                      else f"not trusted (misfit {p.misfit:.3g})")
    if len(trusted) >= 3:
        median = float(np.median([c.pairs[k].error for k in trusted]))
        misfits = [c.pairs[k].misfit for k in trusted if c.pairs[k].misfit is not None]
        typical = float(np.median(misfits)) if misfits else None
        for k in trusted:
            p = c.pairs[k]
            if p.error > c.mc.outlier_error * median:
                why[k] = (Rejection.OUTLIER, f"E far above the other trusted pairs' ({p.error / median:.3g} x their median)")
            elif typical and p.misfit is not None and p.misfit > c.mc.outlier_misfit * typical:
                why[k] = (Rejection.OUTLIER, f"misfit far above the other trusted pairs' ({p.misfit:.3g}, "
                                             f"{p.misfit / typical:.3g} x their median)")
    return Screened([k for k in trusted if k not in why], why)


def weight(p: PairResult) -> float:
    """A trusted pair's weight in the pose graph's consensus: its matching share over its misfit (the pair
    threshold's, about 1 at the noise level), so a pair that fits at the noise level outweighs one the
    threshold passed near its bound (simulated turntable, crops: right pairs misfit 0.4-0.6, wrong ones
    the threshold trusted 1.8-4.4; bunny, right pairs 1.3-3.2)."""
    return max(p.overlap, 1e-3) / max(p.misfit if p.misfit is not None else 1.0, 0.25)


def edges(c: _Campaign, keys: list[tuple[int, int]]) -> list[Edge]:
    """The pose graph's edges of the pairs ``keys`` (their information matrices computed once per registration)."""
    out = []
    for i, j in keys:
        p = c.pairs[i, j]
        info_key = (i, j, c.tried[i, j])
        if info_key not in c.infos:
            c.infos[info_key] = information_matrix(c.scans[j].points, c.scans[i], 3 * c.spacing, p.T_i_j)
        out.append(Edge(i, j, p.T_i_j, weight(p), c.infos[info_key]))
    return out


def build(c: _Campaign) -> tuple[Graph, Screened]:
    """The pose graph of the usable pairs, in the reference's frame (module notes); sets ``c.reference``."""
    screened = screen(c)
    keys = screened.usable
    es = edges(c, keys)
    tol = Tolerance(c.mc.cycle_rotation_deg, c.mc.cycle_translation * c.spacing)
    g = solve(c.n, es, c.centers, tol, 3 * c.spacing, c.config.seed)
    label = labels(c.n, [keys[k] for k in g.kept])
    size = {lab: label.count(lab) for lab in set(label)}
    best = max(size.values())
    c.reference = 0 if size[label[0]] == best else min(k for k in range(c.n) if size[label[k]] == best)
    if c.reference != 0:
        g = solve(c.n, es, c.centers, tol, 3 * c.spacing, c.config.seed, c.reference)
    return g, screened
