"""Point-pair alignment without a browser: the ray pick and the pairs' pose."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.app.tab.pairs import PointPairs, nearest_to_ray
from rangereg.core.errors import InputError
from rangereg.core.transforms import apply, from_params


def test_a_ray_picks_the_visible_point_not_the_one_behind_it():
    pts = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 2.0], [3.0, 0.0, 2.0]])
    assert nearest_to_ray(pts, (0, 0, 0), (0, 0, 1), reach=0.1, depth=0.05) == 1
    assert nearest_to_ray(pts, (0, 0, 0), (0, 1, 0), reach=0.1, depth=0.05) is None  # a miss
    assert nearest_to_ray(pts, (0, 0, 10), (0, 0, 1), reach=0.1, depth=0.05) is None  # all behind the camera


def test_of_the_visible_surface_the_point_under_the_click_is_picked():
    # a surface at z = 2 sampled every 0.1, one point behind it: the click between samples takes the nearest sample
    grid = np.array([[x, y, 2.0 + 0.01 * x] for x in np.arange(-0.5, 0.51, 0.1) for y in np.arange(-0.5, 0.51, 0.1)])
    pts = np.r_[grid, [[0.03, 0.0, 4.0]]]
    ray = np.array([0.032, 0.011, 1.0])
    k = nearest_to_ray(pts, (0, 0, 0), ray, reach=0.3, depth=0.3)
    hit = ray / ray[2] * pts[k, 2]
    assert np.linalg.norm(pts[k, :2] - hit[:2]) < 0.05 and k < len(grid)


def test_far_away_the_reach_is_a_few_pixels_not_the_spacing():
    pts = np.array([[0.0, 0.0, 100.0]])
    off = np.array([0.05, 0.0, 1.0])  # 0.05 rad off the ray: 5 m at 100 m, far beyond a 0.1 reach
    assert nearest_to_ray(pts, (0, 0, 0), off, reach=0.1, depth=0.1) is None
    assert nearest_to_ray(pts, (0, 0, 0), off, reach=0.1, depth=0.1, per_distance=0.06) == 0


def test_three_pairs_give_the_pose_and_zero_residuals():
    rng = np.random.default_rng(0)
    source = rng.uniform(-1, 1, (50, 3))
    T = from_params(np.array([0.3, -0.2, 0.1, 0.4, -0.3, 0.2]))
    target = apply(T, source)
    pairs = PointPairs()
    with pytest.raises(InputError, match="source .* first"):
        pairs.add("target", 0)
    for i in (3, 17, 41):
        pairs.add("source", i)
        pairs.add("target", i)
    assert np.allclose(pairs.align(source, target), T)
    assert np.allclose(pairs.residuals(source, target, T), 0.0)
    pairs.remove(0)
    with pytest.raises(InputError, match="at least 3"):
        pairs.align(source, target)
    with pytest.raises(InputError, match="no pair 5"):
        pairs.remove(4)
