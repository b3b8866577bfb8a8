"""ICP on the robust error (core.icp): convergence, the bounded walk, its config."""

from __future__ import annotations

import numpy as np
import pytest

from core import prepare
from core.errors import InputError
from core.icp import IcpConfig, icp
from core.transforms import apply, pose_error


def test_icp_converges_from_a_small_offset(scene_start):
    a, b, Tt, T0 = scene_start("corner", 0.5, 5.0)
    p = prepare(b, a, T0)
    res = icp(p.error, T0)
    rot, tr = pose_error(res.T, Tt, b.points.mean(0))
    assert rot < 0.2 and tr < 2.0
    assert res.error < p.error(T0)


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


def test_locked_icp_turns_about_the_turntable_axis_only_and_lowers_e(scene):
    from core.lock import Lock
    from core.simulate import SCENES, true_transform
    from core.transforms import invert, perturb

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
