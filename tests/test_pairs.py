"""Point-pair alignment without a browser: the ray pick and the pairs' pose."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.app.tab.pairs import PointPairs, nearest_to_ray
from rangereg.core.errors import InputError
from rangereg.core.transforms import apply, from_params


def test_a_ray_picks_the_visible_point_not_the_one_behind_it():
    pts = np.array([[0.0, 0.0, 5.0], [0.0, 0.0, 2.0], [3.0, 0.0, 2.0]])
    assert nearest_to_ray(pts, (0, 0, 0), (0, 0, 1), reach=0.1, band=0.05) == 1
    assert nearest_to_ray(pts, (0, 0, 0), (0, 1, 0), reach=0.1, band=0.05) is None  # a miss
    assert nearest_to_ray(pts, (0, 0, 10), (0, 0, 1), reach=0.1, band=0.05) is None  # all behind the camera


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
