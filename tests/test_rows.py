"""core.rows: the per-row norm and cross product are numpy's own, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.rows import cross, first_in_cells, norms


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


@pytest.mark.parametrize("v", [
    np.array([[3, 4, 12], [2**40, 0, 0]], dtype=np.int64),  # squares that overflow int64
    np.array([[3, 4, 12]], dtype=np.int16),  # numpy's norm is float64, a root of int16 float32
    np.array([[1.0, 2.0, 2.0, 4.0]]),  # rows of four: all four count
    np.array([[True, True, False]]),
    [[1.0, 2.0, 2.0]],  # a list, as numpy takes
])
def test_what_is_not_a_float_3_vector_is_measured_as_numpy_does(v):
    want = np.linalg.norm(v, axis=-1)
    got = norms(v)
    assert got.dtype == want.dtype and np.array_equal(got, want)


def test_cross_products_of_other_rows_as_numpy():
    assert np.array_equal(cross([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), np.cross([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]))
    with pytest.raises(ValueError):  # numpy refuses rows of four; written out, the fourth was dropped
        cross(np.ones((2, 4)), np.ones((2, 4)))


@pytest.mark.parametrize("low, high, n", [(-50, 50, 20_000), (0, 3, 500), (-(2**40), 2**40, 2_000), (7, 8, 10),
                                          (0, 1, 0)])
def test_first_in_cells_is_numpys_unique_rows(low, high, n):
    """The first row of each distinct cell, in lexicographic order, as ``np.unique(axis=0)``: negative cells, a few
    cells held by many rows, a span too wide for one int64 a cell (the 2-D path), one cell, none."""
    cells = np.random.default_rng(n).integers(low, high, (n, 3))
    want = np.unique(cells, axis=0, return_index=True)[1] if n else np.zeros(0, dtype=np.int64)
    assert np.array_equal(first_in_cells(cells), want)
