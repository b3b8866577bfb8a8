"""Per-row arithmetic on (..., 3) vectors, bit for bit numpy's and several times faster.

numpy's general routines pay for their generality on the engine's arrays of 3-vectors (hundreds of
thousands of rays, edges, normals a registration): ``np.linalg.norm(v, axis=-1)`` squares the whole
array into a temporary and reduces along a 3-long axis, ``np.cross`` moves axes and copies. Written
out component by component the same operations, in the same order, give the same bits (checked on
300k random vectors spanning six decades, tests/test_rows.py) in a quarter of the time for the norm
(2.0 ms against 8.0 ms for 300k rows) and 0.6 x for the cross product (6.4 ms against 10.3 ms).
"""

from __future__ import annotations

import numpy as np


def norms(v: np.ndarray) -> np.ndarray:
    """(...,) Euclidean lengths of (..., 3) vectors ``v``: ``np.linalg.norm(v, axis=-1)``."""
    v = np.asarray(v)
    if not _written_out(v):
        return np.linalg.norm(v, axis=-1)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.sqrt(x * x + y * y + z * z)


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(..., 3) cross products of (..., 3) vectors ``a`` and ``b`` (broadcast): ``np.cross(a, b)``."""
    a, b = np.asarray(a), np.asarray(b)
    if not (_written_out(a) and _written_out(b)):
        return np.cross(a, b)
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(b)), dtype=np.result_type(a, b))
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


def first_in_cells(cells: np.ndarray) -> np.ndarray:
    """(K,) the index of the first row of each distinct row of (N, 3) integer grid ``cells``, in their lexicographic
    order: ``np.unique(cells, axis=0, return_index=True)[1]``. Each cell is one int64 (its offset from the lowest
    corner in mixed radix, which keeps the order) where the grid's span allows: the 2-D unique sorts rows as
    structured records, ~20 x slower (0.1 s on a 300k-point fragment)."""
    c = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
    if not len(c):
        return np.zeros(0, dtype=np.int64)
    c = c - c.min(0)
    dims = c.max(0) + 1
    if float(np.prod(dims.astype(np.float64))) >= 2.0**62:
        return np.unique(c, axis=0, return_index=True)[1]
    return np.unique((c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2], return_index=True)[1]


def _written_out(v: np.ndarray) -> bool:
    """Whether ``v`` is float32 or float64 (..., 3), where the written-out arithmetic is numpy's bit for bit.
    numpy's own routines take the rest: integers squared in their own type overflow (and a small one's root
    is a float32), and a row that is not a 3-vector would be cut to its first three components."""
    return v.ndim >= 1 and v.shape[-1] == 3 and v.dtype in (np.float32, np.float64)
