"""The slice as a 3-D height field: its surface, and a path that lies on it."""

from __future__ import annotations

import numpy as np

from app.tab.terrain import HEIGHT, LIFT, TERRAIN_SIZE, heights, on_surface, surface
from core.landscape import Slice


def bowl(steps: int = 9) -> Slice:
    a = np.linspace(-2.0, 2.0, steps)
    b = np.linspace(-30.0, 30.0, steps)
    A, B = np.meshgrid(a, b, indexing="ij")
    return Slice(("tx", "ry"), a, b, 1e-3 + A**2 + (B / 15.0) ** 2, np.eye(4))


def test_the_height_field_spans_the_box_lowest_at_the_minimum():
    sl = bowl()
    v, f, rgba = surface(sl)
    assert v.shape == (81, 3) and f.shape == (2 * 64, 3) and rgba.shape == (81, 4)
    assert np.allclose([v[:, 0].min(), v[:, 0].max()], [-TERRAIN_SIZE / 2, TERRAIN_SIZE / 2])
    h = heights(sl)
    assert np.isclose(h.min(), 0.0) and np.isclose(h.max(), HEIGHT) and np.argmin(h) == 40  # the centre


def test_a_path_lies_on_the_surface_and_is_clipped_to_its_box():
    sl = bowl()
    p = on_surface(sl, np.array([[0.0, 0.0], [2.0, 30.0], [50.0, 0.0]]))
    h = heights(sl)
    assert np.isclose(p[0, 1], h[4, 4] + LIFT) and np.isclose(p[1, 1], h[-1, -1] + LIFT)
    assert np.isclose(p[2, 0], TERRAIN_SIZE / 2)  # beyond the slice: on its edge
