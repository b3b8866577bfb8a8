"""The public front core.register: one prepared problem shared read-only, the result's stop reason."""

from __future__ import annotations

import numpy as np

from core import Config, prepare, register
from core.anneal import AnnealConfig
from core.transforms import apply, perturb, random_perturbation


def _start(scene, name="corner", rot_deg=10.0, trans=400.0, seed=4):
    from core.simulate import true_transform

    a, b = scene(name)
    Tt = true_transform(b, a)
    t, r = random_perturbation(np.random.default_rng(seed), rot_deg, trans)
    return a, b, perturb(Tt, np.r_[t, r], apply(Tt, b.points.mean(0)[None])[0])


def _same(r1, r2):
    return (r1.error == r2.error and np.array_equal(r1.transform, r2.transform) and r1.iterations == r2.iterations
            and r1.evaluations == r2.evaluations and r1.stop_text == r2.stop_text)


def test_one_prepared_problem_serves_many_runs(scene):
    # RobustError is read-only: a run counts its own evaluations and widens E on a copy, so two runs
    # (coarse-to-fine included) on one prepared problem give what two runs on fresh problems give.
    a, b, T0 = _start(scene)
    short = AnnealConfig(max_evaluations=100)
    configs = (Config(method="hybrid", seed=4, anneal=short, coarse_to_fine=True), Config(method="icp", seed=4))
    shared = prepare(b, a, T0, configs[0].problem, seed=4)
    on_shared = [register(b, a, T0, c, problem=shared) for c in configs]
    fresh = [register(b, a, T0, c) for c in configs]
    assert all(_same(s, f) for s, f in zip(on_shared, fresh))
    assert shared.error.widen == 1.0
    assert on_shared[0].evaluations > 0


def test_the_one_seed_draws_the_overlap_sample(scene):
    from core.register import Config as FrontConfig

    a, b, T0 = _start(scene)
    assert FrontConfig is Config
    cfg = Config(method="icp", seed=7)
    by_seed = register(b, a, T0, cfg, problem=prepare(b, a, T0, cfg.problem, seed=7))
    assert _same(register(b, a, T0, cfg), by_seed)
    other = prepare(b, a, T0, cfg.problem, seed=8)
    assert not np.array_equal(other.points, prepare(b, a, T0, cfg.problem, seed=7).points)


def test_a_cancelled_run_returns_its_best_pose_with_the_reason(scene):
    from core.events import Cancelled
    from core.result import StopReason

    a, b, T0 = _start(scene)
    seen = []

    def stop_after_ten(event):
        seen.append(event)
        if len(seen) == 10:
            raise Cancelled

    res = register(b, a, T0, Config(method="hybrid", seed=4), stop_after_ten)
    assert res.stop_reason is StopReason.CANCELLED and res.stop_text == "cancelled"
    best = min(seen, key=lambda e: e.error)
    assert res.error == best.error and np.array_equal(res.transform, best.T)
    assert not res.below_threshold
