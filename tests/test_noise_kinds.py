"""The noise floor of a scan with no viewpoint in front of its points (core.noise: local planes)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from rangereg.core.noise import noise_floor
from rangereg.core.scan import ScanKind


def test_a_panorama_has_a_noise_floor_of_the_order_of_its_range_noise():
    from rangereg.core.scenes_sensor import Spinning, lidar_pair

    for noise in (0.01, 0.04):
        _, t = lidar_pair("street", 0, Spinning(rings=16, steps=512, noise=noise))
        floor = noise_floor(t, np.random.default_rng(0))
        assert 0.02 * noise ** 2 < floor < noise ** 2  # capped at 2 x the median: below sigma^2, never 0
    quiet = noise_floor(lidar_pair("street", 0, Spinning(rings=16, steps=512, noise=0.01))[1], np.random.default_rng(0))
    loud = noise_floor(lidar_pair("street", 0, Spinning(rings=16, steps=512, noise=0.04))[1], np.random.default_rng(0))
    assert loud > 4 * quiet


def test_the_local_planes_measure_what_the_triangulation_does_on_a_single_view_scan(scene):
    target, _ = scene("bowl", 2)
    tri = noise_floor(target, np.random.default_rng(0))
    planes = noise_floor(replace(target, kind=ScanKind.UNSTRUCTURED), np.random.default_rng(0))
    assert 0.7 < planes / tri < 1.4
