"""A sequence of frames merges as odometry plus loop closure (core.merge_sequence)."""

from pathlib import Path

import numpy as np
import pytest
from rangereg.core.io import load_scans
from rangereg.core.merge import merge
from rangereg.core.merge_result import Start
from rangereg.core.scenes_sensor import Spinning, pose_at, spin_scan, street_mesh
from rangereg.core.transforms import invert, rotation_angle

KINECT = Path(__file__).resolve().parents[2] / "shared" / "data" / "kinect"


def test_simulated_street_sequence_places_every_frame_and_reports_its_loops():
    rng = np.random.default_rng(0)
    mesh = street_mesh()
    poses = [pose_at(-10 + 0.5 * k + rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1), 1.8, rng.uniform(-3, 3))
             for k in range(6)]
    scans = [spin_scan(mesh, T, Spinning(), rng, name=f"f{k}") for k, T in enumerate(poses)]
    res = merge(scans, pairs="sequence", build_model=False)
    for k, P in enumerate(res.poses):
        assert P is not None
        D = invert(invert(poses[0]) @ poses[k]) @ P
        assert np.degrees(rotation_angle(D[:3, :3])) < 1.0 and np.linalg.norm(D[:3, 3]) < 0.05
    odometry = [p for p in res.pairs if p.j == p.i + 1 and p.start is Start.IDENTITY]
    assert odometry
    assert res.rings and all(r.closing[1] - r.closing[0] > 1 or len(r.order) > 2 for r in res.rings)
    assert all(r.after[0] < 1.0 and r.after[1] < 0.05 for r in res.rings)


@pytest.mark.skipif(not KINECT.is_dir(), reason="../shared/data/kinect absent")
def test_kinect_sequence_places_all_five():
    scans = load_scans(sorted(str(p) for p in KINECT.glob("*.pcd")))
    res = merge(scans, pairs="sequence", build_model=False)
    assert all(res.placed)
    assert res.rings
