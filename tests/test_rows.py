"""core.rows: the per-row norm and cross product are numpy's own, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from rangereg.core.rows import cross, norms


@pytest.mark.parametrize("shape", [(300_000, 3), (32, 200, 3), (1, 3), (0, 3)])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_same_bits_as_numpy(shape, dtype):
    rng = np.random.default_rng(7)
    a = (rng.normal(size=shape) * 10.0 ** rng.uniform(-3, 3, size=shape[:-1] + (1,))).astype(dtype)
    b = rng.normal(size=shape).astype(dtype)
    assert np.array_equal(norms(a), np.linalg.norm(a, axis=-1))
    assert np.array_equal(cross(a, b), np.cross(a, b))
    assert norms(a).dtype == np.linalg.norm(a, axis=-1).dtype


def test_broadcasting_and_non_finite_rows_as_numpy():
    a = np.array([[0.0, 0.0, 1.0], [np.nan, 1.0, 2.0], [np.inf, 0.0, 0.0]])
    axis = np.array([1.0, 0.0, 0.0])
    with np.errstate(invalid="ignore"):  # inf x 0, in both
        assert np.array_equal(cross(a, axis), np.cross(a, axis), equal_nan=True)
        assert np.array_equal(cross(axis, a), np.cross(axis, a), equal_nan=True)
    assert np.array_equal(norms(a), np.linalg.norm(a, axis=1), equal_nan=True)


def test_the_inputs_come_back_unmodified():
    rng = np.random.default_rng(1)
    a, b = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    a0, b0 = a.copy(), b.copy()
    norms(a), cross(a, b)
    assert np.array_equal(a, a0) and np.array_equal(b, b0)
