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
