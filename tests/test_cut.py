"""The overlap cut (core.cut): the paper's frustum cut under the guess (section 2.1), widened step by step
when it holds too few points, and None when the guess's uncertainty allows no overlap."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.cut import CUTS, MIN_SHARE, overlap_cut
from rangereg.core.frustum import frustum_of
from rangereg.core.simulate import true_transform
from rangereg.core.surface import Surface


@pytest.fixture
def corner(scene):
    """(target, source, its surface, T_true) of the simulated corner."""
    target, source = scene("corner")
    return target, source, Surface.from_scan(target), true_transform(source, target)


def sideways(T: np.ndarray, target, distance: float) -> np.ndarray:
    """T moved ``distance`` along the target's view's first image axis (out of its view, for a large one)."""
    out = T.copy()
    out[:3, 3] += distance * frustum_of(target).basis[0]
    return out


def test_at_the_truth_the_cut_is_the_frustum_cut_itself(corner):
    target, source, surface, T = corner
    cut = overlap_cut(source, target, surface, T, "convex", False, np.radians(15), 100.0)
    assert cut.name == CUTS[0] and np.array_equal(cut.used, cut.source_mask)
    assert cut.used.sum() >= MIN_SHARE * len(source.points)
    assert cut.target_mask.any()  # the paper's overlap both ways, for drawing


def test_a_widening_holds_every_point_the_narrower_one_holds(corner):
    target, source, _, T = corner
    f = frustum_of(target)
    from rangereg.core.transforms import apply

    moved = apply(sideways(T, target, 2000.0), source.points)
    assert np.array_equal(f.widened(moved, 0.0), f.contains(moved))
    masks = [f.widened(moved, np.radians(a)) for a in (0, 5, 20, 60)]
    assert all(np.all(wide[narrow]) for narrow, wide in zip(masks, masks[1:]))
    assert masks[-1].sum() > masks[0].sum()
    assert f.widened(moved, np.pi / 2).all()


def test_the_frustum_opens_by_the_angle_on_every_side(corner):
    target = corner[0]
    f = frustum_of(target)
    for i in range(len(f.outline)):  # a ray through the middle of each outline edge, turned out by 10 deg
        m = (f.outline[i] + f.outline[(i + 1) % len(f.outline)]) / 2
        side = f.equations[np.argmin(np.abs(f.equations[:, :2] @ m + f.equations[:, 2]))]
        n = side / np.linalg.norm(side)  # the side plane's outward unit normal, in the frustum's frame
        r0 = np.r_[m, 1.0] / np.linalg.norm(np.r_[m, 1.0])
        ray = np.cos(np.radians(10)) * r0 + np.sin(np.radians(10)) * n
        point = f.apex + 1000.0 * ray @ f.basis
        assert not f.contains(point[None])[0]
        assert f.widened(point[None], np.radians(12))[0] and not f.widened(point[None], np.radians(8))[0]


def test_a_guess_beside_the_view_widens_the_cut_to_what_its_uncertainty_allows(corner):
    target, source, surface, T = corner
    T0 = sideways(T, target, 2000.0)  # the frustum cut is empty
    narrow = overlap_cut(source, target, surface, T0, "convex", False, np.radians(30), 2400.0)
    assert narrow.source_mask.sum() == 0 and narrow.name in CUTS[1:]
    assert narrow.used.sum() >= MIN_SHARE * len(source.points)
    wide = overlap_cut(source, target, surface, T0, "convex", False, np.radians(80), 2400.0)
    assert CUTS.index(wide.name) <= CUTS.index(narrow.name)  # more uncertainty: the cut needs no wider step


def test_a_guess_whose_uncertainty_allows_no_overlap_has_no_cut(corner):
    target, source, surface, T = corner
    for distance in (1e4, 1e6):  # far beside the view: ~90 deg off its axis, far more than 1 deg beyond its side
        far = sideways(T, target, distance)
        assert overlap_cut(source, target, surface, far, "convex", False, np.radians(1), 10.0) is None


def test_a_resample_keeps_the_cut_and_draws_another_sample_of_it(corner):
    from rangereg.core.problem import ProblemConfig, prepare, resample

    target, source, surface, T = corner
    p = prepare(source, target, T, ProblemConfig(max_points=200), surface=surface, seed=0)
    before = p.points.copy()
    q = resample(p, 200, [0, 1])
    assert np.array_equal(p.points, before)  # the input unchanged
    assert q.used is p.used and q.guess is p.guess and q.cut == p.cut and q.overlap is p.overlap
    assert (q.rotation_uncertainty, q.translation_uncertainty) == (p.rotation_uncertainty, p.translation_uncertainty)
    inside = source.points[p.used]
    assert len(q.points) == 200 and not np.array_equal(q.points, p.points)
    assert np.all(np.isin(q.points.view([("", q.points.dtype)] * 3), inside.view([("", inside.dtype)] * 3)))
    assert np.array_equal(resample(p, 200, [0, 1]).points, q.points)  # seeded
    assert np.isclose(q.error(T), p.error(T), rtol=0.5)  # the same surface and overlap, another sample
