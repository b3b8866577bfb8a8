"""The robust error, Horn, ICP, annealing, the hybrid and its event stream (optimiser issue)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from core import Config, prepare, register
from core.anneal import AnnealConfig, anneal
from core.error import RobustError, robust_weights
from core.horn import weighted_horn
from core.icp import IcpConfig, icp
from core.register import recut
from core.surface import Surface
from core.transforms import apply, from_params, perturb, pose_error


def test_robust_error_by_hand():
    # One triangle in z = 0; points at heights 1, 1, 2, 10 -> d2 = 1, 1, 4, 100.
    surf = Surface(np.array([[-50.0, -50, 0], [50, -50, 0], [0, 50, 0]]), np.array([[0, 1, 2]]))
    pts = np.array([[0, 0, 1.0], [1, 0, 1], [0, 1, 2], [1, 1, 10]])
    e = RobustError(pts, surf)
    t = 2 * np.median([1, 1, 4, 100])  # = 5
    expect = (1 + 1 + 4 + t) / 4  # the outlier adds t, not 100 and not 0
    assert e(np.eye(4)) == pytest.approx(expect)
    w, tt = robust_weights(np.array([1.0, 1, 4, 100]))
    assert tt == 5 and w.tolist() == [1, 1, 1, 0.05]


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 100_000))
def test_horn_recovers_any_rigid_transform(seed):
    rng = np.random.default_rng(seed)
    T = from_params(np.r_[rng.normal(0, 100, 3), rng.normal(0, 1.5, 3)])
    x = rng.normal(0, 10, (int(rng.integers(3, 50)), 3))
    w = rng.uniform(0.1, 2, len(x))
    np.testing.assert_allclose(weighted_horn(x, apply(T, x), w), T, atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 100_000))
def test_horn_ignores_zero_weight_pairs(seed):
    rng = np.random.default_rng(seed)
    T = from_params(np.r_[rng.normal(0, 5, 3), rng.normal(0, 1, 3)])
    x = rng.normal(0, 3, (20, 3))
    y = apply(T, x)
    y[:8] += rng.normal(0, 50, (8, 3))  # garbage pairs...
    w = np.r_[np.zeros(8), np.ones(12)]  # ...with zero weight
    np.testing.assert_allclose(weighted_horn(x, y, w), weighted_horn(x[8:], y[8:]), atol=1e-8)
    np.testing.assert_allclose(weighted_horn(x, y, w), T, atol=1e-7)


def _truth_and_start(scene, name, rot_deg, trans, seed=0):
    from core.simulate import true_transform
    from core.transforms import random_perturbation

    a, b = scene(name)
    Tt = true_transform(b, a)
    t, r = random_perturbation(np.random.default_rng(seed), rot_deg, trans)
    c = apply(Tt, b.points.mean(0)[None])[0]
    return a, b, Tt, perturb(Tt, np.r_[t, r], c)


def test_icp_converges_from_a_small_offset(scene):
    a, b, Tt, T0 = _truth_and_start(scene, "corner", 0.5, 5.0)
    p = prepare(b, a, T0)
    res = icp(p.error, T0)
    rot, tr = pose_error(res.T, Tt, b.points.mean(0))
    assert rot < 0.2 and tr < 2.0
    assert res.error < p.error(T0)


def _rastrigin(x):
    return float(np.sum(x * x) + 2 * np.sum(1 - np.cos(2 * np.pi * x)))


@pytest.mark.parametrize("seed", range(5))
def test_annealing_finds_the_global_minimum_of_a_multi_minimum_function(seed):
    x0 = np.full(2, 2.0)  # a local minimum of Rastrigin's function; the global one is at 0
    res = anneal(_rastrigin, x0, np.full(2, 2.0), np.random.default_rng(seed),
                 AnnealConfig(t_start=20, t_min_ratio=1e-5, moves_per_temperature=40))
    assert np.all(np.abs(res.x) < 0.05) and res.value < 0.01
    # plain downhill simplex from the same place stays stuck
    descent = anneal(_rastrigin, x0, np.full(2, 0.2), np.random.default_rng(seed), AnnealConfig(t_start=1e-12))
    assert descent.value > 3


def test_annealing_is_deterministic_for_a_seed():
    runs = [anneal(_rastrigin, np.full(3, 1.5), np.ones(3), np.random.default_rng(7)) for _ in range(2)]
    assert runs[0].value == runs[1].value and np.array_equal(runs[0].x, runs[1].x)
    other = anneal(_rastrigin, np.full(3, 1.5), np.ones(3), np.random.default_rng(8))
    assert other.evaluations != runs[0].evaluations or not np.array_equal(other.x, runs[0].x)


def test_annealing_hands_back_a_better_point_at_once():
    start = np.ones(3)  # a local minimum; moving one coordinate to 0 gets below start - 0.5
    cfg = AnnealConfig(t_start=10)
    full = anneal(_rastrigin, start, np.ones(3), np.random.default_rng(0), cfg)
    res = anneal(_rastrigin, start, np.ones(3), np.random.default_rng(0), cfg, stop_below=_rastrigin(start) - 0.5)
    assert res.improved and res.value < _rastrigin(start) - 0.5
    assert res.evaluations < full.evaluations


# A start where ICP ends 15 degrees off in a local minimum; found by trying seeds 0-11 at 10 deg / 400 mm.
ESCAPE = ("corner", 10.0, 400.0, 4)


def test_hybrid_escapes_a_local_minimum_where_icp_stays(scene):
    name, deg, mm, seed = ESCAPE
    a, b, Tt, T0 = _truth_and_start(scene, name, deg, mm, seed)
    c = b.points.mean(0)
    # one overlap cut, as in the paper: the escape must come from annealing, not from re-cutting
    icp_res = register(b, a, T0, Config(method="icp", seed=seed, recut_rounds=1))
    assert icp_res.local_minima >= 1
    icp_rot, icp_tr = pose_error(icp_res.transform, Tt, c)
    assert icp_rot > 10
    events = []
    hyb = register(b, a, T0, Config(method="hybrid", seed=seed, recut_rounds=1), events.append)
    rot, tr = pose_error(hyb.transform, Tt, c)
    # annealing gets the rotation out of ICP's well; the translation along the corner stays partly off
    assert rot < 1 and tr < icp_tr, (rot, tr)
    assert hyb.error < icp_res.error
    assert hyb.local_minima >= 1 and hyb.iterations["sa"] > 0
    # the event stream agrees with the reported counts
    assert sum(e.phase == "icp" and not e.local_minimum for e in events) >= hyb.iterations["icp"] - 2
    assert sum(e.phase == "sa" for e in events) == hyb.iterations["sa"]
    assert sum(e.local_minimum for e in events) == hyb.local_minima
    assert [e.iteration for e in events if not e.local_minimum] == sorted(e.iteration for e in events if not e.local_minimum)
    assert events[-1].iteration == hyb.iterations["icp"] + hyb.iterations["sa"]
    assert all(e.temperature is not None for e in events if e.phase == "sa")


def test_basin_hopping_finds_the_bowls_true_well_where_icp_stays_out(scene):
    # Beyond the paper. The bowl at its benchmark spread (5 deg, 123 mm): ICP slides into the valley
    # a bowl has (tilting it mimics a shift) and stops ~20 deg off; the true well is narrow and at the
    # valley's end. Seed 5: one of the starts tried (0-7: 6 of 8 home).
    a, b, Tt, T0 = _truth_and_start(scene, "bowl", 5.0, 123.0, 5)
    c = b.points.mean(0)
    stuck = register(b, a, T0, Config(method="icp", seed=5))
    assert pose_error(stuck.transform, Tt, c)[0] > 10 and stuck.local_minima >= 1
    events = []
    hop = register(b, a, T0, Config(method="basin-hopping", seed=5), events.append)
    rot, tr = pose_error(hop.transform, Tt, c)
    assert rot < 1 and tr < 0.01 * a.size, (rot, tr)
    assert hop.error < stuck.error and hop.local_minima >= 1
    # every hop is one 'sa' event without a temperature, followed by an ICP leg
    assert sum(e.phase == "sa" for e in events) == hop.iterations["sa"] > 0
    assert all(e.temperature is None for e in events if e.phase == "sa")
    assert sum(e.local_minimum for e in events) == hop.local_minima
    assert events[-1].iteration == hop.iterations["icp"] + hop.iterations["sa"]


def test_every_event_of_every_method_writes_as_json(scene):
    # the --trace file and the workbench's trace export: annealing's moves included
    import json

    from core.events import Event

    a, b, _, T0 = _truth_and_start(scene, "corner", 10.0, 400.0, 4)
    short = AnnealConfig(max_evaluations=60)
    for method in ("hybrid", "sa", "icp-restarts", "basin-hopping"):
        events = []
        register(b, a, T0, Config(method=method, seed=4, threshold=0, hops=3, restarts=3, anneal=short,
                                  sa_alone=short), events.append)
        assert any(e.phase == "sa" for e in events) or method == "icp-restarts"
        for e in events:
            back = Event.from_json(json.loads(json.dumps(e.to_json())))
            assert back.phase == e.phase and back.accepted == e.accepted and np.allclose(back.T, e.T)


def test_registration_is_deterministic_for_a_seed(scene):
    a, b, _, T0 = _truth_and_start(scene, "bowl", 5.0, 100.0, 1)
    r1 = register(b, a, T0, Config(seed=3))
    r2 = register(b, a, T0, Config(seed=3))
    assert r1.error == r2.error and np.array_equal(r1.transform, r2.transform)


def test_no_overlap_is_a_clear_error(scene):
    from core.errors import InputError

    a, b = scene("corner")
    far = from_params([1e6, 0, 0, 0, 0, 0])
    with pytest.raises(InputError, match="do not overlap"):
        register(b, a, far)


def test_nonsense_settings_are_refused(scene):
    from core.errors import InputError
    from core.problem import ProblemConfig

    a, b = scene("corner")
    for cfg in (Config(method="magic"), Config(threshold=-1), Config(anneal=AnnealConfig(cooling=1.5)),
                Config(anneal=AnnealConfig(settle_below=2.0)),
                Config(hops=-1), Config(hop_size=0), Config(recut_rounds=0),
                Config(problem=ProblemConfig(max_points=2)), Config(problem=ProblemConfig(frustum="round"))):
        with pytest.raises(InputError):
            register(b, a, None, cfg)


@pytest.mark.slow
def test_bunny_hybrid_from_15_degrees(bunny):
    from core.transforms import invert, random_perturbation

    src, tgt = bunny("bun045"), bunny("bun000")
    Tt = invert(tgt.pose) @ src.pose
    c = src.points.mean(0)
    t, r = random_perturbation(np.random.default_rng(11), 15.0, 0.025)
    T0 = perturb(Tt, np.r_[t, r], apply(Tt, c[None])[0])
    res = register(src, tgt, T0, Config(seed=1))
    rot, tr = pose_error(res.transform, Tt, c)
    assert rot < 2 and tr < 0.002


def test_recutting_the_overlap_at_the_found_pose_gets_icp_out(scene):
    # Beyond the paper: the overlap cut under a poor guess holds ICP in the ESCAPE start's wrong
    # well; cut again at the pose ICP found (what the hybrid's outer loop does), and ICP from there
    # reaches the truth.
    name, deg, mm, seed = ESCAPE
    a, b, Tt, T0 = _truth_and_start(scene, name, deg, mm, seed)
    c = b.points.mean(0)
    cfg = Config(method="icp", seed=seed)
    stuck = register(b, a, T0, cfg).transform
    again = icp(recut(prepare(b, a, T0, cfg.problem), stuck, cfg, converged=False).error, stuck).T
    assert pose_error(stuck, Tt, c)[0] > 10
    assert pose_error(again, Tt, c)[0] < 1


def test_bounded_icp_stays_in_its_region(scene):
    a, b, Tt, T0 = _truth_and_start(scene, "corner", 10.0, 400.0, 4)
    problem = prepare(b, a, T0)
    center = apply(T0, problem.center[None])[0]

    def inside(T):
        return np.linalg.norm(apply(T, problem.center[None])[0] - center) < 20.0

    res = icp(problem.error, T0, IcpConfig(), inside=inside)
    free = icp(problem.error, T0, IcpConfig())
    assert inside(res.T)
    assert not inside(free.T)  # unbounded, ICP walks farther than the region allows
