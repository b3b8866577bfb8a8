"""Weighted Horn alignment (core.horn), the step inside every ICP iteration, and its constrained form
for locked degrees of freedom (the minimum over the free parameters only)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rangereg.core.errors import InputError
from rangereg.core.horn import constrained_horn, locked_horn, weighted_horn
from rangereg.core.lock import Lock
from rangereg.core.transforms import apply, from_params


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


SPECS = ("rx,ry,tz", "rotation", "translation", "tx", "ry", "tx,ty,rz", "turntable:1,2,3,0,0.3,1",
         "turntable+translation:1,2,3,0,0.3,1")


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 100_000), st.sampled_from(SPECS))
def test_constrained_horn_finds_the_brute_force_minimum_over_the_free_parameters(seed, spec):
    from scipy.optimize import minimize

    rng = np.random.default_rng(seed)
    T_ref = from_params(np.r_[rng.normal(0, 5, 3), rng.normal(0, 0.5, 3)])
    P = rng.normal(0, 3, (30, 3))
    frame = Lock.parse(spec).bind(T_ref, P.mean(0), float(rng.uniform(0.5, 3)))
    y = apply(T_ref, P)
    q = apply(frame.pose(rng.normal(0, 0.4, frame.k)), P) + rng.normal(0, 0.5, P.shape)  # noisy pairs
    w = rng.uniform(0.1, 2, len(P))

    def cost(z):
        return float(w @ np.sum((frame.motion(z, y)[0] - q) ** 2, axis=1))

    z = constrained_horn(y, q, w, frame, np.zeros(frame.k))
    brute = minimize(cost, np.zeros(frame.k), method="Nelder-Mead",
                     options=dict(xatol=1e-10, fatol=1e-12, maxiter=40_000, maxfev=40_000))
    assert cost(z) <= brute.fun * (1 + 1e-9) + 1e-12
    np.testing.assert_allclose(z, brute.x, atol=1e-4)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 100_000))
def test_constrained_horn_with_nothing_locked_is_horn(seed):
    rng = np.random.default_rng(seed)
    T_ref = from_params(np.r_[rng.normal(0, 5, 3), rng.normal(0, 0.5, 3)])
    x = rng.normal(0, 3, (25, 3))
    y = apply(from_params(np.r_[rng.normal(0, 2, 3), rng.normal(0, 0.3, 3)]), x) + rng.normal(0, 0.3, x.shape)
    w = rng.uniform(0.1, 2, len(x))
    frame = Lock().bind(T_ref, x.mean(0), 1.0)
    z = constrained_horn(apply(T_ref, x), y, w, frame, np.zeros(6))
    np.testing.assert_allclose(frame.pose(z), weighted_horn(x, y, w), atol=1e-8)


def test_translation_only_horn_is_the_weighted_centroid_difference():
    rng = np.random.default_rng(1)
    y = rng.normal(0, 3, (40, 3))
    q = y @ from_params(np.r_[0, 0, 0, 0.2, -0.1, 0.3])[:3, :3].T + [1.0, -2.0, 0.5]
    w = rng.uniform(0.1, 2, len(y))
    frame = Lock.parse("rotation").bind(np.eye(4), y.mean(0), 2.0)
    z = constrained_horn(y, q, w, frame, np.zeros(3))
    np.testing.assert_allclose(frame.scale * z, w @ (q - y) / w.sum(), atol=1e-12)


def test_constrained_horn_refuses_bad_input():
    frame = Lock.parse("rx").bind(np.eye(4), np.zeros(3), 1.0)
    with pytest.raises(InputError, match="shapes"):
        constrained_horn(np.zeros((4, 3)), np.zeros((5, 3)), np.ones(4), frame, np.zeros(5))
    with pytest.raises(InputError, match="weights"):
        constrained_horn(np.zeros((4, 3)), np.zeros((4, 3)), np.zeros(4), frame, np.zeros(5))


def test_pair_alignment_under_a_turntable_lock_finds_a_large_turn():
    from rangereg.core.transforms import perturb

    rng = np.random.default_rng(5)
    x = rng.normal(0, 50, (6, 3))  # six picked pairs
    point, axis = np.array([10.0, -30.0, 0.0]), np.array([0.0, 0.6, 0.8])
    T = perturb(np.eye(4), np.r_[0, 0, 0, np.radians(150.0) * axis], point)
    y = apply(T, x) + rng.normal(0, 0.5, x.shape)
    frame = Lock.parse("turntable:10,-30,0,0,0.6,0.8").bind(np.eye(4), x.mean(0), 1.0)
    np.testing.assert_allclose(locked_horn(x, y, None, frame), T, atol=0.02)
    # the same turn as a subset lock (tx, ty, tz, rx locked about the centroid) from the projected start
    sub = Lock.parse("tx,ty,tz,rx").bind(np.eye(4), x.mean(0), 1.0)
    T_sub = perturb(np.eye(4), np.r_[0, 0, 0, 0, 1.2, -1.5], x.mean(0))
    np.testing.assert_allclose(locked_horn(x, apply(T_sub, x), None, sub), T_sub, atol=1e-8)
