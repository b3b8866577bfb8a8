"""The stop threshold (core.threshold): the paper's noise-based estimate and the pair threshold that says
"trust" for the global pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core import prepare
from rangereg.core.candidates import make_basis
from rangereg.core.config import Config, ThresholdConfig
from rangereg.core.surface import Surface
from rangereg.core.threshold import estimate_threshold, threshold_for
from rangereg.core.transforms import apply, invert, perturb, pose_error


def test_the_threshold_factor_scales_the_estimate(scene):
    a, b = scene("corner")
    p = prepare(b, a)
    six = estimate_threshold(p, 3)
    assert estimate_threshold(p, 3, ThresholdConfig(factor=3.0)) == pytest.approx(six / 2)
    assert threshold_for(p, Config(seed=3)) == six
    assert threshold_for(p, Config(seed=3, threshold=1.5)) == 1.5


def test_the_pair_threshold_trusts_the_truth_and_not_a_pose_beside_it_on_every_shared_pair(bunny):
    from rangereg.app.sweep import shared_pairs
    from rangereg.core.noise import noise_floor
    from rangereg.core.threshold import pair_threshold

    from tests.conftest import BUNNY

    pairs = shared_pairs(BUNNY)
    assert len(pairs) >= 5 and ("bun090", "bun000") in {(s.stem, t.stem) for s, t, _ in pairs}
    for s, t, _ in pairs:
        source, target = bunny(s.stem), bunny(t.stem)
        T_true = invert(target.pose) @ source.pose
        rng = np.random.default_rng(0)
        floor = float(np.mean([noise_floor(x, rng, 300) for x in (source, target)]))
        basis = make_basis(source, target, Surface.from_scan(target), floor, rng)
        thr = pair_threshold(floor, basis.angle_floor, basis.min_overlap)
        assert thr.holds(basis, T_true)
        off = perturb(T_true, np.r_[0.004, 0, 0, 0, np.radians(5), 0], apply(T_true, source.centroid[None])[0])
        assert not thr.holds(basis, off)


def test_the_pair_threshold_trusts_no_twin_of_the_bowl_and_trusts_the_truth(scene):
    """The bowl turned 20-90 deg about each principal axis and refined ends at the truth or in a twin valley
    (8-90 deg off). No twin is trusted: the misfit (distance and normals) is above the factor at each.
    Which turn finds which valley moves with the float32 closest points between processors: on one, the
    35 deg turn about the third axis ended 3.8 deg and 19 mm off where 71 % of the sample matched at 6.4 x
    the floor in d^2 (distance alone at 7 x would trust it); on another every twin sat at 8-16 x. Both
    are claims of this test, whichever the processor gives."""
    from rangereg.core.candidates import CandidateConfig
    from rangereg.core.global_search import refine
    from rangereg.core.guess import Guess
    from rangereg.core.noise import noise_floor
    from rangereg.core.simulate import true_transform
    from rangereg.core.threshold import pair_threshold

    target, source = scene("bowl", 2)
    T_true = true_transform(source, target)
    rng = np.random.default_rng(0)
    floor = float(np.mean([noise_floor(x, rng, 300) for x in (source, target)]))
    surface = Surface.from_scan(target)
    basis = make_basis(source, target, surface, floor, rng)
    thr = pair_threshold(floor, basis.angle_floor, basis.min_overlap)
    assert thr.holds(basis, T_true)
    _, axes = np.linalg.eigh(np.cov((source.points - source.centroid).T))
    stated = Guess.identity(90.0, 0.3 * target.size)
    config = Config(candidates=CandidateConfig(refine_metric="plane"))
    centre = apply(T_true, source.centroid[None])[0]
    twins = right = 0
    for axis in (2, 1, 0):
        for deg in (35, -50, 70, 90):
            turned = perturb(T_true, np.r_[0, 0, 0, np.radians(deg) * (T_true[:3, :3] @ axes[:, axis])], centre)
            T, _ = refine(source, target, surface, stated.at(turned), config)
            rot, trans = pose_error(T, T_true, source.centroid)
            if rot > 2.0:  # a wrong minimum (the scenes' success bound: 1 deg, 1 % of the size)
                twins += 1
                assert thr.factor < thr.misfit(basis, T) and not thr.holds(basis, T), (axis, deg, rot, trans)
                s = basis.evaluate(T[None])
                if s.inliers[0] > 0.6 and s.inlier_median[0] < 7 * floor:  # distance alone would trust it:
                    assert basis.normal_angle(T) > 2 * basis.angle_floor  # the normals tell
            elif rot < 1.0:
                right += 1
                assert thr.holds(basis, T)
    assert twins >= 3 and right >= 1  # both kinds of valley were met


def test_a_weakly_pinned_pose_is_held_to_the_known_sensors_free_space_bound(monkeypatch):
    # where the rise decides (a pose pinned weakly), a share of points where the other looked through that a fused
    # cloud's hull would allow (below MAX_INTRUSION) still refuses it above MAX_LOOKED_THROUGH; a pose pinned well keeps
    # the fused bound (walk30's truths read up to 0.047 at ratios 0.10-0.14)
    from types import SimpleNamespace

    from rangereg.core import threshold as th
    from rangereg.core.intrusion import MAX_INTRUSION, MAX_LOOKED_THROUGH

    share = 0.5 * (MAX_LOOKED_THROUGH + MAX_INTRUSION)
    monkeypatch.setattr(th, "clear", lambda basis, T, bound: share < bound)
    basis = SimpleNamespace(valid=lambda s: np.array([True]))
    scores = SimpleNamespace(inliers=np.array([1.0]))
    thr = th.pair_threshold(1.0, 2.0, 0.1)
    for rise, trusted in ((None, True), (1.3, False)):
        c = SimpleNamespace(rise=rise, pins=lambda bound: True, matched=900, ratio=0.1 if rise is None else 0.01,
                            stably_pinned=False)
        monkeypatch.setattr(th, "constraint", lambda basis, T, free=None, c=c: c)
        assert thr.holds(basis, np.eye(4), scores, misfit=1.0) is trusted
    weak = SimpleNamespace(rise=1.1, pins=lambda bound: False, matched=900, ratio=0.01, stably_pinned=False)
    monkeypatch.setattr(th, "constraint", lambda basis, T, free=None: weak)
    monkeypatch.setattr(th.PairThreshold, "misfit", lambda self, basis, T, s=None: 1.0)
    monkeypatch.setattr(basis, "evaluate", lambda Ts: scores, raising=False)
    assert thr.weakly_pinned(basis, np.eye(4))  # a rise that falls short stays weakly pinned, for a campaign's loops
    from dataclasses import replace

    lifted = replace(thr, slide_intrusion=np.inf)  # an evidence script's "before the test": the fused bound alone
    monkeypatch.setattr(th, "constraint", lambda basis, T, free=None: SimpleNamespace(rise=1.3, pins=lambda bound: True))
    assert lifted.holds(basis, np.eye(4), scores, misfit=1.0) and lifted.slide_bound == MAX_INTRUSION
