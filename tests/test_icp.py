"""ICP on the robust error (core.icp): convergence, the bounded walk, its config."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core import prepare
from rangereg.core.errors import InputError
from rangereg.core.icp import IcpConfig, icp
from rangereg.core.transforms import apply, invert, pose_error


def test_icp_converges_from_a_small_offset(scene_start):
    a, b, Tt, T0 = scene_start("corner", 0.5, 5.0)
    p = prepare(b, a, T0)
    res = icp(p.error, T0)
    rot, tr = pose_error(res.T, Tt, b.points.mean(0))
    assert rot < 0.2 and tr < 2.0
    assert res.error < p.error(T0)


@pytest.mark.parametrize("name", ["corner", "bowl"])
def test_plane_metric_reaches_the_truth_in_fewer_iterations_than_horn(scene_start, name):
    """Measured on four seeds of each scene: Horn's steps creep into the bowl (2-5 deg off after
    5-20 iterations, its E 3-6 x E at the truth), the plane steps reach it (<= 0.5 deg)."""
    a, b, Tt, T0 = scene_start(name, 3.0, 20.0, 2)
    p = prepare(b, a, T0)
    point = icp(p.error, T0, IcpConfig())
    plane = icp(p.error, T0, IcpConfig(metric="plane"))
    rot, tr = pose_error(plane.T, Tt, b.points.mean(0))
    assert rot < 0.5 and tr < 2.0, (plane, rot, tr)
    assert plane.error <= 1.1 * p.error(Tt)
    if name == "corner":
        assert plane.iterations < point.iterations, (plane, point)
    else:
        assert pose_error(point.T, Tt, b.points.mean(0))[0] > 1.0 and plane.error < point.error / 2


def test_plane_steps_never_cycle_between_two_poses(scene_start):
    """Near the minimum a whole Gauss-Newton step can raise E (the weights and closest triangles
    change): a fraction of it, or a Horn step, is taken instead, so ICP stops well before its cap."""
    a, b, Tt, T0 = scene_start("corner", 0.5, 5.0)
    p = prepare(b, a, T0)
    seen = []
    res = icp(p.error, Tt, IcpConfig(metric="plane", tolerance=0.0, max_iterations=100), lambda T, E: seen.append(E))
    assert res.iterations < 100 or len(set(np.round(seen[-6:], 12))) > 2
    assert res.error <= p.error(Tt)


def test_bounded_icp_stays_in_its_region(scene_start):
    a, b, Tt, T0 = scene_start("corner", 10.0, 400.0, 4)
    problem = prepare(b, a, T0)
    center = apply(T0, problem.center[None])[0]

    def inside(T):
        return np.linalg.norm(apply(T, problem.center[None])[0] - center) < 20.0

    res = icp(problem.error, T0, IcpConfig(), inside=inside)
    free = icp(problem.error, T0, IcpConfig())
    assert inside(res.T)
    assert not inside(free.T)  # unbounded, ICP walks farther than the region allows


@pytest.mark.parametrize("bad", [dict(max_iterations=0), dict(tolerance=-1.0), dict(tolerance=float("nan"))])
def test_icp_config_refuses_nonsense(bad):
    with pytest.raises(InputError, match="ICP needs"):
        IcpConfig(**bad).validate()
    IcpConfig().validate()
    with pytest.raises(InputError, match="metric must be one of point, plane"):
        IcpConfig(metric="planes").validate()


@pytest.mark.parametrize("bad", [(0.0, 1.0), (1.0, -1.0), (float("nan"), 1.0), (1.0,), 0.01, "ab", (1.0, 2.0, 3.0)])
def test_icp_config_refuses_a_nonsense_step_tolerance(bad):
    with pytest.raises(InputError, match="step tolerance must be two numbers > 0"):
        IcpConfig(step_tolerance=bad).validate()
    IcpConfig(step_tolerance=(0.01, 0.1)).validate()


@pytest.mark.parametrize("metric", ["point", "plane"])
def test_the_papers_walk_takes_every_step_until_one_is_below_its_tolerance(scene_start, metric):
    """Every step is taken (E may rise on one), the last pose is returned, and the walk ends on the first step
    that turns the pose less than the degrees and moves the sample's centroid less than the units."""
    a, b, Tt, T0 = scene_start("corner", 0.5, 5.0)
    p = prepare(b, a, T0)
    seen = [T0]
    res = icp(p.error, T0, IcpConfig(metric=metric, step_tolerance=(0.01, 0.01), max_iterations=200),
              lambda T, E: seen.append(T))
    assert res.iterations == len(seen) - 1 < 200
    assert res.T is seen[-1] and res.error == pytest.approx(p.error(res.T))
    # each step measured at the sample's centroid where the step starts (source frame)
    moves = [pose_error(T1, T0_, apply(invert(T0_), p.error.terms(T0_).moved.mean(0)[None])[0])
             for T0_, T1 in zip(seen[:-1], seen[1:])]
    assert moves[-1][0] < 0.01 and moves[-1][1] < 0.01
    assert all(r >= 0.01 or t >= 0.01 for r, t in moves[:-1])
    rot, tr = pose_error(res.T, Tt, b.points.mean(0))
    assert rot < 0.3 and tr < 2.0, (rot, tr)


def test_locked_icp_turns_about_the_turntable_axis_only_and_lowers_e(scene):
    from rangereg.core.lock import Lock
    from rangereg.core.simulate import SCENES, true_transform
    from rangereg.core.transforms import invert, perturb

    target, source = scene("bowl", SCENES.index("bowl"))
    Tt = true_transform(source, target)
    point = apply(Tt, source.points.mean(0)[None])[0] + [80.0, -50.0, 0.0]
    T0 = perturb(Tt, np.r_[0, 0, 0, 0, 0, np.radians(4.0)], point)  # the truth turned 4 deg on the table
    problem = prepare(source, target, T0)
    frame = Lock.parse("turntable:" + ",".join(repr(float(v)) for v in (*point, 0, 0, 1))).bind(T0, problem.center, 1.0)
    seen = []
    res = icp(problem.error, T0, IcpConfig(), lambda T, E: seen.append((T, E)), frame=frame)
    rot, tr = pose_error(res.T, Tt, source.points.mean(0))
    assert rot < 0.2 and tr < 1.0, (rot, tr)
    assert seen[0][1] < problem.error(T0) and res.error < problem.error(T0)
    on_axis = point + np.outer([-300.0, 300.0], [0, 0, 1.0])
    for T, _ in seen:
        np.testing.assert_allclose(apply(T @ invert(T0), on_axis), on_axis, atol=1e-9)
    # unlocked ICP from the same start walks in all six parameters (and so leaves the axis)
    free = icp(problem.error, T0, IcpConfig(max_iterations=3))
    assert np.abs(apply(free.T @ invert(T0), on_axis) - on_axis).max() > 1e-6
