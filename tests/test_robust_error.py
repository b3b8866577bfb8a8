"""The robust error (core.robust_error, paper eq. 1-2), read-only so that one prepared problem is shared."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.robust_error import RobustError, robust_weights
from rangereg.core.surface import Surface


def _plane_and_points():
    # One triangle in z = 0; points at heights 1, 1, 2, 10 -> d2 = 1, 1, 4, 100.
    surf = Surface(np.array([[-50.0, -50, 0], [50, -50, 0], [0, 50, 0]]), np.array([[0, 1, 2]]))
    pts = np.array([[0, 0, 1.0], [1, 0, 1], [0, 1, 2], [1, 1, 10]])
    return surf, pts


def test_robust_error_by_hand():
    surf, pts = _plane_and_points()
    e = RobustError(pts, surf)
    t = 2 * np.median([1, 1, 4, 100])  # = 5
    expect = (1 + 1 + 4 + t) / 4  # the outlier adds t, not 100 and not 0
    assert e(np.eye(4)) == pytest.approx(expect)
    w, tt = robust_weights(np.array([1.0, 1, 4, 100]))
    assert tt == 5 and w.tolist() == [1, 1, 1, 0.05]


def test_widening_gives_a_new_error_and_leaves_the_old_one_as_it_was():
    surf, pts = _plane_and_points()
    e = RobustError(pts, surf)
    wide = e.widened(10.0)
    assert wide is not e and e.widen == 1.0 and wide.widen == 10.0
    assert e(np.eye(4)) == pytest.approx((1 + 1 + 4 + 5) / 4)
    assert wide(np.eye(4)) == pytest.approx((1 + 1 + 4 + 50) / 4)  # t = 50: the outlier now adds 50
    assert e.widened(1.0) is e


def test_the_error_cannot_be_changed_from_outside():
    surf, pts = _plane_and_points()
    e = RobustError(pts, surf)
    pts[3, 2] = 0.0  # the caller's array is not the error's
    assert e(np.eye(4)) == pytest.approx((1 + 1 + 4 + 5) / 4)
    with pytest.raises(ValueError):
        e.points[0, 0] = 1.0
    with pytest.raises(AttributeError):
        e.widen = 2.0
    assert not hasattr(e, "evaluations")  # a run counts its own (core.search.state)
