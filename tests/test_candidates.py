"""The global pipeline (issue 13): candidates on one fixed basis, a widened cut, a pair threshold."""

from __future__ import annotations

import numpy as np
import pytest

from core.candidates import CandidateConfig, make_basis, super_fibonacci
from core.problem import ProblemConfig, prepare
from core.register import Config, register
from core.surface import Surface
from core.transforms import apply, invert, perturb, pose_error, rotation_angle


def test_candidate_scores_match_a_per_pose_loop(scene):
    target, source = scene("corner")
    basis = make_basis(source, target, Surface.from_scan(target), 0.4, np.random.default_rng(3),
                       CandidateConfig(sample=50))
    rng = np.random.default_rng(4)
    poses = [perturb(np.eye(4), np.r_[rng.normal(0, 100, 3), rng.normal(0, 0.3, 3)], source.centroid) for _ in range(7)]
    scores = basis.evaluate(np.stack(poses))
    for k, T in enumerate(poses):
        moved = apply(T, basis.points)
        d2 = np.array([basis.surface.closest(p[None])[1][0] for p in moved])
        inside = np.array([basis.target_frustum.contains(p[None])[0] for p in moved])
        expected = np.mean([min(d, basis.cap) if i else basis.cap for d, i in zip(d2, inside)])
        assert scores.score[k] == pytest.approx(expected, rel=1e-6)
        assert scores.inside[k] == pytest.approx(inside.mean())
        assert scores.inliers[k] == pytest.approx(np.mean(inside & (d2 < basis.cap)))


def test_super_fibonacci_rotations_cover_so3_evenly():
    R = super_fibonacci(720)
    assert np.allclose(np.einsum("nij,nkj->nik", R, R), np.eye(3), atol=1e-9)
    rng = np.random.default_rng(0)
    # any rotation lies within 20 degrees of a sample (720 samples: neighbours ~15 deg apart)
    from scipy.spatial.transform import Rotation

    for Q in Rotation.random(50, random_state=rng.integers(1 << 31)).as_matrix():
        assert min(rotation_angle(Q @ S.T) for S in R) < np.radians(20)


def test_an_empty_frustum_cut_widens_and_the_pair_still_registers(scene):
    target, source = scene("corner")
    from core.frustum import frustum_of
    from core.simulate import true_transform

    T_true = true_transform(source, target)
    # the guess moves the source 2 m sideways, out of the target's view: the frustum cut is empty
    T0 = T_true.copy()
    T0[:3, 3] += 2000.0 * frustum_of(target).basis[0]
    pc = ProblemConfig(rotation_uncertainty_deg=30.0, translation_uncertainty=2400.0)
    p = prepare(source, target, T0, pc)
    assert p.overlap.source_mask.sum() == 0 and p.cut != "frustum"
    g = register(source, target, T0, Config(method="global", problem=pc))
    assert g.cut != "frustum"
    assert g.to_json()["cut"] == g.cut
    rot, trans = pose_error(g.transform, T_true, source.centroid)
    assert rot < 1.0 and trans < 0.01 * target.size


def test_a_start_90_degrees_off_registers_with_the_global_pipeline(bunny):
    source, target = bunny("bun045"), bunny("bun000")
    T_true = invert(target.pose) @ source.pose
    T0 = perturb(T_true, np.r_[0.05, 0.0, -0.05, 0.0, 0.0, np.radians(90)], apply(T_true, source.centroid[None])[0])
    pc = ProblemConfig(rotation_uncertainty_deg=180.0, translation_uncertainty=0.075)
    g = register(source, target, T0, Config(method="global", problem=pc))
    rot, trans = pose_error(g.transform, T_true, source.centroid)
    assert rot < 2.0 and trans < 0.002
    assert g.below_threshold
    # the guess, 90 degrees off, is not what was refined into the answer: a stage beyond it was scored
    assert g.iterations.candidates >= 2 and set(g.details.candidate_sources) - {"guess"}
    # the same run again gives the same bits (KISS-Matcher's hypothesis included: core.kiss)
    again = register(source, target, T0, Config(method="global", problem=pc))
    assert np.array_equal(again.transform, g.transform) and again.error == g.error


def test_with_candidates_off_only_the_guess_is_tried(scene):
    from core.simulate import true_transform

    target, source = scene("corner")
    T_true = true_transform(source, target)
    T0 = perturb(T_true, np.r_[50.0, 0, 0, 0, np.radians(3), 0], apply(T_true, source.centroid[None])[0])
    res = register(source, target, T0, Config(method="global", candidates=CandidateConfig(enabled=False)))
    assert res.details.candidates == 1 and res.iterations.candidates == 1
    assert pose_error(res.transform, T_true, source.centroid)[0] < 1.0


def test_the_pair_threshold_trusts_the_truth_and_not_a_pose_beside_it_on_every_shared_pair(bunny):
    from app.sweep import shared_pairs
    from core.noise import noise_floor
    from core.threshold import pair_threshold
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


def test_the_pair_threshold_does_not_trust_a_twin_of_the_bowl_that_fits_in_distance(scene):
    """The bowl turned 35 deg about a principal axis and refined ends in a valley 3.8 deg and 19 mm off,
    where 71 % of the sample matches at 6.4 x the noise floor in d^2: distance alone (the last version's
    test, 7 x) trusted it. The normals there disagree: the misfit rejects it, and trusts the truth."""
    from core.config import Config
    from core.global_search import refine
    from core.noise import noise_floor
    from core.problem import ProblemConfig
    from core.simulate import true_transform
    from core.threshold import pair_threshold

    target, source = scene("bowl", 2)
    T_true = true_transform(source, target)
    rng = np.random.default_rng(0)
    floor = float(np.mean([noise_floor(x, rng, 300) for x in (source, target)]))
    surface = Surface.from_scan(target)
    basis = make_basis(source, target, surface, floor, rng)
    thr = pair_threshold(floor, basis.angle_floor, basis.min_overlap)
    assert thr.holds(basis, T_true)
    _, axes = np.linalg.eigh(np.cov((source.points - source.centroid).T))
    turned = perturb(T_true, np.r_[0, 0, 0, np.radians(35) * (T_true[:3, :3] @ axes[:, 2])],
                     apply(T_true, source.centroid[None])[0])
    pc = ProblemConfig(rotation_uncertainty_deg=90.0, translation_uncertainty=0.3 * target.size)
    T, _ = refine(source, target, surface, turned, pc, Config(candidates=CandidateConfig(refine_metric="plane")))
    rot, trans = pose_error(T, T_true, source.centroid)
    assert rot > 2.0 and trans > 10.0  # a wrong minimum (the scenes' success bound: 1 deg, 1 % of the size)
    s = basis.evaluate(T[None])
    assert s.inliers[0] > 0.6 and s.inlier_median[0] < 7 * floor  # distance alone would trust it
    assert basis.normal_angle(T) > 2 * basis.angle_floor  # the normals tell: the misfit rejects it
    assert thr.factor < thr.misfit(basis, T) < np.inf and not thr.holds(basis, T)


def test_candidates_are_events_of_their_own_phase_in_one_numbered_stream(scene):
    from core.simulate import true_transform

    target, source = scene("corner")
    T_true = true_transform(source, target)
    T0 = perturb(T_true, np.r_[80.0, 0, 0, 0, np.radians(5), 0], apply(T_true, source.centroid[None])[0])
    events = []
    res = register(source, target, T0, Config(method="global"), events.append)
    phases = [e.phase for e in events]
    assert phases[0] == "candidates" and "icp" in phases
    assert phases.count("candidates") == res.iterations.candidates == res.details.candidates
    steps = [e.iteration for e in events if not e.local_minimum]
    assert steps == list(range(1, len(steps) + 1))
    assert all(e.phase_iteration >= 1 and e.leg >= 1 for e in events)


def test_kiss_matcher_started_ahead_gives_the_hypotheses_it_gives_in_line(bunny):
    from core.candidates import pair_spacing
    from core.global_search import kiss_ahead
    from core.kiss import kiss_available, kiss_candidates

    if not kiss_available():
        pytest.skip("kiss-matcher is not installed (an optional extra)")
    source, target = bunny("bun045"), bunny("bun000")
    cc = CandidateConfig()
    assert kiss_ahead(source, target, ProblemConfig(rotation_uncertainty_deg=15.0), cc) is None  # the guess first
    assert kiss_ahead(source, target, ProblemConfig(rotation_uncertainty_deg=90.0), CandidateConfig(enabled=False)) is None
    ahead = kiss_ahead(source, target, ProblemConfig(rotation_uncertainty_deg=90.0), cc)
    inline = kiss_candidates(source, target, pair_spacing(source, target), max(cc.fpfh_voxels))
    got = ahead.result(timeout=60)
    assert len(got) == len(inline) == 1
    assert np.array_equal(got[0], inline[0])
    truth = invert(target.pose) @ source.pose
    rot, trans = pose_error(got[0], truth, source.centroid)
    assert rot < 10 and trans < 0.01  # a hypothesis the refinement can take from there


def test_kiss_matcher_gives_the_same_bits_every_run_in_its_own_process_or_in_this_one(bunny, monkeypatch):
    # In parallel it gave hypotheses up to 0.12 deg apart on this pair (upstream issue 89); serially, the same bits.
    import os
    from pathlib import Path

    from core import kiss
    from core.candidates import pair_spacing

    if not kiss.kiss_available():
        pytest.skip("kiss-matcher is not installed (an optional extra)")
    source, target = bunny("bun045"), bunny("bun000")
    spacing = pair_spacing(source, target)
    first = kiss.kiss_candidates(source, target, spacing, 5.0)
    assert len(first) == 1
    a, b, k = kiss.voxel_clouds(source, target, spacing, 5.0)
    runs = [kiss._CHILD.estimate(a, b) for _ in range(4)]
    assert all(np.array_equal(T, runs[0]) for T in runs)
    assert np.allclose(first[0][:3, 3] * k, runs[0][:3, 3], rtol=1e-12) and np.array_equal(first[0][:3, :3], runs[0][:3, :3])
    # the fallback in this process: the same bits, and the CPU mask it narrows for a moment is as it was
    mask = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
    assert all(np.array_equal(kiss._estimate_here(a, b), runs[0]) for _ in range(3))
    if mask is not None:
        assert os.sched_getaffinity(0) == mask
    # a child that died is started again; one that cannot start leaves the work to this process
    kiss._CHILD._proc.kill()
    kiss._CHILD._proc.wait()
    assert np.array_equal(kiss.kiss_candidates(source, target, spacing, 5.0)[0], first[0])
    kiss._CHILD.close()
    monkeypatch.setattr(kiss, "CHILD", Path(kiss.CHILD.parent / "no_such_child.py"))
    assert np.array_equal(kiss.kiss_candidates(source, target, spacing, 5.0)[0], first[0])
    kiss._CHILD.close()
