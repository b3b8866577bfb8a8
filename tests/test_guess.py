"""core.guess.Guess: one value for the initial guess (pose + stated uncertainty), and what it gives: the stated
region, the paper's search units, the converged cut, a pair's guess between two rough poses."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.config import SearchConfig
from rangereg.core.errors import InputError
from rangereg.core.guess import DEFAULT_ROTATION_DEG, DEFAULT_TRANSLATION_SHARE, Guess
from rangereg.core.transforms import from_params, invert, pose_error


def _poses(rng: np.random.Generator, n: int, rot_deg: float, trans: float) -> list[np.ndarray]:
    """n rigid poses, rotations up to rot_deg about random axes, translations up to trans."""
    out = []
    for _ in range(n):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        t = rng.normal(size=3)
        t *= rng.uniform(0, trans) / np.linalg.norm(t)
        out.append(from_params(np.r_[t, axis * np.radians(rng.uniform(0, rot_deg))]))
    return out


def test_the_guess_pose_is_copied_checked_and_read_only():
    T = from_params(np.r_[1.0, 2.0, 3.0, 0.1, -0.2, 0.3])
    g = Guess(T, 20.0, 5.0)
    T[0, 3] = 99.0  # the caller's array changes; the guess does not
    assert g.T_target_source[0, 3] == 1.0 and g.T_target_source.dtype == np.float64
    with pytest.raises(ValueError):
        g.T_target_source[0, 0] = 2.0
    assert (g.rotation_deg, g.translation) == (20.0, 5.0)
    assert Guess.of(g) is g and np.array_equal(Guess.of(None).T, np.eye(4))
    assert Guess.of(T).rotation_deg == DEFAULT_ROTATION_DEG and Guess.of(T).translation is None


@pytest.mark.parametrize("make, message", [
    (lambda: Guess(np.eye(3)), r"^the guess's pose must be a 4 x 4 matrix"),
    (lambda: Guess(np.full((4, 4), np.nan)), r"^the guess's pose contains NaN"),
    (lambda: Guess(np.diag([1.0, 1.0, -1.0, 1.0])), r"^the guess's pose is not rigid"),
    (lambda: Guess(np.diag([2.0, 2.0, 2.0, 1.0])), r"^the guess's pose is not rigid"),
    (lambda: Guess(np.eye(4), 0.0), r"^rotation uncertainty must be in \(0, 180\] degrees, got 0.0$"),
    (lambda: Guess(np.eye(4), 181.0), r"^rotation uncertainty must be in \(0, 180\] degrees, got 181.0$"),
    (lambda: Guess(np.eye(4), float("nan")), r"^rotation uncertainty must be in \(0, 180\] degrees"),
    (lambda: Guess(np.eye(4), "wide"), r"^rotation uncertainty must be a number of degrees"),
    (lambda: Guess(np.eye(4), 15.0, -1.0), r"^translation uncertainty must be positive, got -1.0$"),
    (lambda: Guess(np.eye(4), 15.0, float("inf")), r"^translation uncertainty must be positive, got inf$"),
    (lambda: Guess.identity(15.0, 0.0), r"^translation uncertainty must be positive, got 0.0$"),
])
def test_bad_values_raise_one_input_error_that_says_what_is_wrong(make, message):
    with pytest.raises(InputError, match=message) as info:
        make()
    assert "\n" not in str(info.value)


def test_no_guess_is_any_rotation_and_no_translation_and_the_repr_says_so():
    none = Guess.none()
    assert none.is_none and none.rotation_deg == 180.0 and none.translation is None
    assert not Guess.identity(180.0, 1.0).is_none and not Guess.identity(179.0).is_none
    assert repr(none) == "Guess(identity; no guess (any rotation, any translation))"
    moved = Guess(from_params(np.r_[0.0, 0.0, 2.0, 0.0, 0.0, np.radians(30.0)]), 10.0, 0.5)
    assert repr(moved) == "Guess(rotation 30 deg, translation [0, 0, 2]; 10 deg, translation 0.5 units)"
    assert Guess.none(moved.T).is_none and np.array_equal(Guess.none(moved.T).T, moved.T)


def test_the_region_contains_the_guess_and_nothing_beyond_its_bounds(scene):
    source, target = scene("corner")
    rng = np.random.default_rng(3)
    for T in _poses(rng, 6, 120.0, target.size):
        for deg, trans in ((5.0, None), (30.0, 0.05 * target.size), (120.0, 0.2 * target.size)):
            g = Guess(T, deg, trans)
            region = g.region(source, target)
            assert region.inside(T) and region.rotation == pytest.approx(np.radians(deg))
            # a pose turned well past the rotation bound about the centroid is outside
            c = T[:3, :3] @ source.centroid + T[:3, 3]
            turn = min(deg + 10.0, 179.0)
            beyond = from_params(np.r_[0.0, 0.0, 0.0, np.radians(turn), 0.0, 0.0])
            shifted = np.eye(4)
            shifted[:3, 3] = c
            far = shifted @ beyond @ invert(shifted) @ T
            assert pose_error(far, T, source.centroid)[0] == pytest.approx(turn, abs=1e-6)
            assert not region.inside(far)


def test_no_guess_contains_every_pose(scene):
    source, target = scene("corner")
    region = Guess.none().region(source, target)
    assert region.no_guess and region.translation_free
    for T in _poses(np.random.default_rng(5), 50, 180.0, 100 * target.size):
        assert region.inside(T)


def test_the_search_units_and_the_default_translation_are_the_papers_initial_uncertainty(scene):
    source, target = scene("corner")
    rot, trans = Guess.identity(20.0).uncertainty(target.size)
    assert rot == np.radians(20.0) and trans == DEFAULT_TRANSLATION_SHARE * target.size
    assert Guess.identity(20.0, 3.0).uncertainty(target.size)[1] == 3.0
    from rangereg.core.problem import prepare

    p = prepare(source, target, Guess.identity(20.0, 3.0))
    assert (p.rotation_uncertainty, p.translation_uncertainty) == (np.radians(20.0), 3.0)
    assert np.array_equal(p.steps[3:], np.full(3, np.radians(20.0))) and np.allclose(p.steps[:3], 3.0 / p.scale)


def test_the_converged_cut_is_the_search_configs_small_uncertainty_at_the_pose_found():
    T = from_params(np.r_[1.0, 0.0, 0.0, 0.0, 0.2, 0.0])
    s = SearchConfig()
    g = Guess.converged(T, s, 400.0)
    assert np.array_equal(g.T, T) and g.rotation_deg == s.resegment_rotation_deg
    assert g.translation == s.resegment_translation * 400.0
    assert Guess(np.eye(4), 40.0, 2.0).narrowed(15.0).rotation_deg == 15.0
    assert Guess(np.eye(4), 10.0, 2.0).narrowed(15.0).rotation_deg == 10.0
    assert Guess(np.eye(4), 40.0, 2.0).at(T).translation == 2.0


def test_a_pairs_guess_between_two_rough_poses_is_the_relative_pose_in_the_doubled_region():
    rng = np.random.default_rng(11)
    for T_a, T_b in zip(_poses(rng, 5, 90.0, 10.0), _poses(rng, 5, 90.0, 10.0)):
        a, b = Guess(T_a, 15.0, 0.5), Guess(T_b, 15.0, 0.5)
        pair = Guess.between(a, b)
        assert np.allclose(pair.T, invert(T_a) @ T_b)
        assert (pair.rotation_deg, pair.translation) == (30.0, 1.0)  # twice the per-scan uncertainty
    assert Guess.between(Guess.identity(120.0), Guess.identity(120.0)).rotation_deg == 180.0  # at most any
    unstated = Guess.between(Guess.identity(10.0), Guess.identity(10.0, 2.0))
    assert unstated.translation is None  # unstated stays unstated: the target's default share, not doubled
    assert Guess.between(Guess.none(), Guess.none()).is_none


def test_register_takes_a_guess_and_a_bare_pose_means_the_default_uncertainty(scene):
    from rangereg.core.register import Config, register

    source, target = scene("corner")
    cfg = Config(method="icp", seed=1)
    T0 = np.eye(4)
    by_pose = register(source, target, T0, cfg)
    by_guess = register(source, target, Guess(T0, DEFAULT_ROTATION_DEG), cfg)
    assert np.array_equal(by_pose.transform, by_guess.transform) and by_pose.error == by_guess.error


def test_rangereg_register_takes_a_guess_as_init_the_same_as_the_pose_and_its_uncertainty_apart(scene):
    import rangereg

    source, target = scene("corner")
    T0 = np.eye(4)
    apart = rangereg.register(source, target, T0, rotation_uncertainty=25, method="icp", seed=3)
    one = rangereg.register(source, target, rangereg.Guess(T0, 25), method="icp", seed=3)
    assert np.array_equal(apart.T_target_source, one.T_target_source)
    with pytest.raises(rangereg.InputError, match="^init is a Guess, which states its own uncertainty"):
        rangereg.register(source, target, rangereg.Guess(T0, 25), rotation_uncertainty=25)
