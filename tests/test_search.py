"""The search state and methods (core.search): legs, counts, the event stream's numbering."""

from __future__ import annotations

import numpy as np

from core import Config, register
from core.anneal import AnnealConfig
from core.transforms import apply, perturb, random_perturbation


def _escape(scene):
    from core.simulate import true_transform

    a, b = scene("corner")
    Tt = true_transform(b, a)
    t, r = random_perturbation(np.random.default_rng(4), 10.0, 400.0)
    return a, b, perturb(Tt, np.r_[t, r], apply(Tt, b.points.mean(0)[None])[0])


def test_phase_iteration_counts_within_each_leg(scene):
    a, b, T0 = _escape(scene)
    for method in ("hybrid", "basin-hopping"):
        events = []
        register(b, a, T0, Config(method=method, seed=4, hops=3, anneal=AnnealConfig(max_evaluations=100)),
                 events.append)
        steps = [e for e in events if not e.local_minimum]
        assert {e.phase for e in steps} == {"icp", "sa"}
        expected, seen, last = {}, {}, 0
        for e in steps:
            key = (e.phase, e.leg)
            assert e.leg >= 1
            counted = e.iteration != last  # a step; else a report where a leg stands without a step
            last = e.iteration
            expected[key] = expected.get(key, 0) + counted
            assert e.phase_iteration == expected[key], (method, key)
            seen[key] = e.phase_iteration
        assert max(seen.values()) < sum(e.phase == "icp" for e in steps)  # not a count over the whole run
        legs = {p: sorted({e.leg for e in steps if e.phase == p}) for p in ("icp", "sa")}
        assert all(v == list(range(v[0], v[0] + len(v))) for v in legs.values())  # legs numbered in order
