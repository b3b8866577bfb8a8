"""Weighted Horn alignment (core.horn), the step inside every ICP iteration."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from core.horn import weighted_horn
from core.transforms import apply, from_params


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
