"""The public front core.register: determinism, bad input, events, one prepared problem shared
read-only, the one seed, cancelling; and the bunny end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.core import Config, prepare, register
from rangereg.core.anneal import AnnealConfig
from rangereg.core.errors import InputError
from rangereg.core.transforms import apply, from_params, perturb, pose_error

from tests.conftest import ESCAPE


def _same(r1, r2):
    return (r1.error == r2.error and np.array_equal(r1.transform, r2.transform) and r1.iterations == r2.iterations
            and r1.evaluations == r2.evaluations and r1.stop_text == r2.stop_text)


def test_every_event_of_every_method_writes_as_json(scene_start):
    # the --trace file and the workbench's trace export: annealing's moves included
    from rangereg.core.events import Event

    a, b, _, T0 = scene_start(*ESCAPE)
    short = AnnealConfig(max_evaluations=60)
    for method in ("hybrid", "sa", "icp-restarts", "basin-hopping"):
        events = []
        register(b, a, T0, Config(method=method, seed=4, threshold=0, hops=3, restarts=3, anneal=short,
                                  sa_alone=short), events.append)
        assert any(e.phase == "sa" for e in events) or method == "icp-restarts"
        for e in events:
            back = Event.from_json(json.loads(json.dumps(e.to_json())))
            assert back.phase == e.phase and back.accepted == e.accepted and np.allclose(back.T, e.T)


def test_registration_is_deterministic_for_a_seed(scene_start):
    a, b, _, T0 = scene_start("bowl", 5.0, 100.0, 1)
    r1 = register(b, a, T0, Config(method="hybrid", seed=3))
    r2 = register(b, a, T0, Config(method="hybrid", seed=3))
    assert r1.error == r2.error and np.array_equal(r1.transform, r2.transform)


def test_no_overlap_is_a_clear_error(scene):
    a, b = scene("corner")
    far = from_params([1e6, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="do not overlap"):
        register(b, a, far)


def test_nonsense_settings_are_refused(scene):
    from rangereg.core.problem import ProblemConfig

    a, b = scene("corner")
    for cfg in (Config(method="magic"), Config(threshold=-1), Config(anneal=AnnealConfig(cooling=1.5)),
                Config(anneal=AnnealConfig(settle_below=2.0)),
                Config(hops=-1), Config(hop_size=0), Config(recut_rounds=0),
                Config(problem=ProblemConfig(max_points=2)), Config(problem=ProblemConfig(frustum="round"))):
        with pytest.raises(InputError):
            register(b, a, None, cfg)


@pytest.mark.slow
def test_bunny_hybrid_from_15_degrees(bunny):
    from rangereg.core.transforms import invert, random_perturbation

    src, tgt = bunny("bun045"), bunny("bun000")
    Tt = invert(tgt.pose) @ src.pose
    c = src.points.mean(0)
    t, r = random_perturbation(np.random.default_rng(11), 15.0, 0.025)
    T0 = perturb(Tt, np.r_[t, r], apply(Tt, c[None])[0])
    res = register(src, tgt, T0, Config(method="hybrid", seed=1))
    rot, tr = pose_error(res.transform, Tt, c)
    assert rot < 2 and tr < 0.002


def test_one_prepared_problem_serves_many_runs(scene_start):
    # RobustError is read-only: a run counts its own evaluations and widens E on a copy, so two runs
    # (coarse-to-fine included) on one prepared problem give what two runs on fresh problems give.
    a, b, _, T0 = scene_start(*ESCAPE)
    short = AnnealConfig(max_evaluations=100)
    configs = (Config(method="hybrid", seed=4, anneal=short, coarse_to_fine=True), Config(method="icp", seed=4))
    shared = prepare(b, a, T0, configs[0].problem, seed=4)
    on_shared = [register(b, a, T0, c, problem=shared) for c in configs]
    fresh = [register(b, a, T0, c) for c in configs]
    assert all(_same(s, f) for s, f in zip(on_shared, fresh))
    assert shared.error.widen == 1.0
    assert on_shared[0].evaluations > 0


def test_the_one_seed_draws_the_overlap_sample(scene_start):
    a, b, _, T0 = scene_start(*ESCAPE)
    cfg = Config(method="icp", seed=7)
    by_seed = register(b, a, T0, cfg, problem=prepare(b, a, T0, cfg.problem, seed=7))
    assert _same(register(b, a, T0, cfg), by_seed)
    other = prepare(b, a, T0, cfg.problem, seed=8)
    assert not np.array_equal(other.points, prepare(b, a, T0, cfg.problem, seed=7).points)
    assert not hasattr(cfg.problem, "seed")  # one seed: Config.seed


def test_a_cancelled_run_returns_its_best_pose_with_the_reason(scene_start):
    from rangereg.core.events import Cancelled
    from rangereg.core.result import StopReason

    a, b, _, T0 = scene_start(*ESCAPE)
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


def test_the_front_keeps_its_names():
    import importlib

    front = importlib.import_module("rangereg.core.register")  # the package's `register` is the function

    for name in ("register", "Config", "METHODS", "Result", "estimate_threshold", "recut"):
        assert hasattr(front, name), name
