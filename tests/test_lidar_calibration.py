"""The simulated spinning LiDAR's per-laser calibration residuals (core.scenes_sensor.Spinning: a range offset and
an elevation error per laser, the points written along the nominal elevations; benchmarks/lidar_floor.py)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from rangereg.core.scenes_sensor import Spinning, lidar_pair, pose_at, quad, spin_scan

HEIGHT = 1.8  # m, the sensor above the ground plane


def _ground_scan(lidar: Spinning):
    """One turn of ``lidar`` (every beam pointing down) over a flat ground plane, the same draws whatever its
    calibration: (the scan's points (rings * steps, 3), their nominal elevations (rings * steps,) radians)."""
    mesh = quad((-500, -500, 0), (500, -500, 0), (500, 500, 0), (-500, 500, 0))
    scan = spin_scan(mesh, pose_at(0.0, 0.0, HEIGHT), lidar, np.random.default_rng(3))
    assert len(scan.points) == lidar.rings * lidar.steps  # every beam hits: the grids line up point for point
    return scan.points, np.repeat(np.radians(np.linspace(*lidar.elevation_deg, lidar.rings)), lidar.steps)


def test_without_per_laser_errors_the_calibration_seed_changes_nothing():
    small = Spinning(rings=16, steps=512)
    for scene in ("street", "room"):
        a = lidar_pair(scene, 1, small)
        b = lidar_pair(scene, 1, replace(small, calibration_seed=7))
        assert all(np.array_equal(x.points, y.points) for x, y in zip(a, b))


def _with_and_without(**errors):
    """A small scanner over flat ground without and with per-laser ``errors``: (the unit with them, points without,
    points with, their ranges without and with, the nominal elevations)."""
    lidar = Spinning(rings=8, steps=256, elevation_deg=(-25.0, -5.0), noise=0.01)
    unit = replace(lidar, **errors)
    p0, el = _ground_scan(lidar)
    p1, _ = _ground_scan(unit)
    return unit, p0, p1, np.linalg.norm(p0, axis=1), np.linalg.norm(p1, axis=1), el


def test_a_range_offset_moves_each_lasers_points_along_their_rays_by_that_lasers_offset():
    biased, p0, p1, r0, r1, _ = _with_and_without(laser_range_bias=0.02, calibration_seed=4)
    np.testing.assert_allclose(p1 / r1[:, None], p0 / r0[:, None], atol=1e-12)  # the same rays
    offsets = biased.calibration()[0]
    np.testing.assert_allclose(r1 - r0, np.repeat(offsets, biased.steps), atol=1e-9)
    assert 0.005 < np.std(offsets) < 0.05  # drawn at the stated sigma, not zero
    # one unit: both scans of a pair carry the same offsets; another seed, another unit
    assert np.array_equal(offsets, replace(biased, calibration_seed=4).calibration()[0])
    assert not np.allclose(offsets, replace(biased, calibration_seed=5).calibration()[0])


def test_an_elevation_error_fires_the_beam_elsewhere_but_writes_the_point_at_the_nominal_elevation():
    tilted, p0, p1, r0, r1, el = _with_and_without(laser_elevation_deg=0.05, calibration_seed=2)
    np.testing.assert_allclose(np.arcsin(p1[:, 2] / r1), el, atol=1e-9)  # written at the nominal elevation
    err = np.repeat(tilted.calibration()[1], tilted.steps)
    # on flat ground the range is the height over the sine of the true depression; the noise draw is shared
    expected = HEIGHT / np.sin(-(el + err)) - HEIGHT / np.sin(-el)
    np.testing.assert_allclose(r1 - r0, expected, atol=2e-4)  # Open3D casts in float32
    assert np.max(np.abs(expected)) > 0.01  # the error is visible: a point off the ground by centimetres
