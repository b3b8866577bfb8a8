"""Simplex simulated annealing (core.anneal) on a function with many minima, and its config."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.anneal import AnnealConfig, anneal
from rangereg.core.errors import InputError


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


@pytest.mark.parametrize("bad, message", [
    (dict(cooling=1.5), "cooling"), (dict(cooling=0.0), "cooling"),
    (dict(t_min_ratio=1.0), "minimum temperature ratio"),
    (dict(moves_per_temperature=0), "at least 1 move"), (dict(max_evaluations=6), "7 evaluations"),
    (dict(settle_below=2.0), "settle_below"), (dict(t_start=0.0), "start temperature"),
])
def test_anneal_config_refuses_nonsense(bad, message):
    with pytest.raises(InputError, match=message):
        AnnealConfig(**bad).validate()
    AnnealConfig().validate()


def test_annealing_works_on_a_one_dimensional_simplex():
    # a lock leaves k < 6 free coordinates: annealing runs on a k-D simplex (core.lock), k = 1 included
    res = anneal(_rastrigin, np.array([2.0]), np.array([2.0]), np.random.default_rng(0),
                 AnnealConfig(t_start=20, t_min_ratio=1e-5, moves_per_temperature=40))
    assert res.x.shape == (1,) and abs(res.x[0]) < 0.05 and res.value < 0.01


def test_a_locked_search_anneals_over_the_free_coordinates_only(monkeypatch, scene_start):
    import rangereg.core.search.state as state_module
    from rangereg.core import Config, register
    from rangereg.core.lock import Lock

    starts = []

    def spy(f, x0, steps, *args, **kwargs):
        starts.append((np.array(x0), np.array(steps)))
        return anneal(f, x0, steps, *args, **kwargs)

    monkeypatch.setattr(state_module, "anneal", spy)
    a, b, Tt, T0 = scene_start("corner", 5.0, 100.0)
    short = AnnealConfig(max_evaluations=40)
    for lock, k in ((Lock.parse("rx,ry,tz"), 3), (Lock.parse("turntable:0,0,0,0,0,1"), 1), (Lock(), 6)):
        starts.clear()
        register(b, a, T0, Config(method="sa", sa_alone=short, lock=lock))
        assert starts and {len(x0) for x0, _ in starts} == {k}  # every leg, the refining one too
        assert all(np.all(steps > 0) for _, steps in starts)  # no flat (zero-step) direction
