"""Simplex simulated annealing (core.anneal) on a function with many minima, and its config."""

from __future__ import annotations

import numpy as np
import pytest

from core.anneal import AnnealConfig, anneal
from core.errors import InputError


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
