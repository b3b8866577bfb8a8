"""The noise floor (core.noise, the paper's section 2.3 "lowest expected error"): the two scans'
floors measured side by side give the bits they give one after the other, and the floor follows
the scanner's noise."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from rangereg.core.noise import noise_floor, noise_floors
from rangereg.core.simulate import Scanner

from tests.conftest import BUNNY, _bunny


def test_floors_side_by_side_are_the_floors_one_after_the_other(scene):
    pairs = [scene("corner"), scene("bowl")]
    if BUNNY.is_dir():  # windowed: each half holds > 5,000 points (without the shared scans, the scenes alone)
        pairs.append((_bunny("bun045"), _bunny("bun000")))
    for a, b in pairs:
        for seed in (0, 3):
            rng = np.random.default_rng(seed)
            one_by_one = [noise_floor(s, rng, 300) for s in (a, b)]
            assert noise_floors([a, b], np.random.default_rng(seed), 300) == one_by_one
            assert all(f > 0 for f in one_by_one)


def test_floors_measured_ahead_are_the_floors_and_leave_the_generator_as_they_do(scene):
    from rangereg.core.noise import noise_floors_ahead

    a, b = scene("bowl")
    for threads in (1, 2):
        rng, ahead_rng = np.random.default_rng(7), np.random.default_rng(7)
        ahead = noise_floors_ahead([a, b], ahead_rng, 300, threads)
        assert ahead_rng.random() == (noise_floors([a, b], rng, 300), rng.random())[1]  # the draws made at once
        assert ahead() == noise_floors([a, b], np.random.default_rng(7), 300)


def _corner_scans(noises: tuple[float, ...]) -> list:
    """One view of the corner per range noise (mm), the same rays and seed."""
    from rangereg.core.simulate import corner_mesh, look_at, scan_mesh

    vertices, faces = corner_mesh()
    eye = vertices.mean(0) + np.array([900.0, 700.0, 600.0])
    return [scan_mesh(vertices, faces, look_at(eye, vertices.mean(0)),
                      replace(Scanner(rows=80, cols=80, fov_deg=(40.0, 40.0), outliers=0.0), noise=noise),
                      np.random.default_rng(1)) for noise in noises]


def test_the_floor_grows_with_the_scanners_noise():
    floors = [np.median([noise_floor(scan, np.random.default_rng(k), 300) for k in range(5)])
              for scan in _corner_scans((0.2, 0.8, 3.2))]
    assert floors[0] < floors[1] < floors[2]
    # E is a mean squared distance: 4 x the noise gives ~16 x the floor (spacing adds a part that does not grow)
    assert floors[2] / floors[1] > 4


def test_a_stream_held_to_one_thread_measures_the_floors_one_after_the_other(scene, monkeypatch):
    import open3d as o3d
    import rangereg.core.noise

    a, b = scene("corner")
    expect = noise_floors([a, b], np.random.default_rng(2), 300)

    def no_threads(*args, **kwargs):
        raise AssertionError("a thread pool in a stream held to one thread")

    before = o3d.utility.get_max_threads()
    monkeypatch.setattr(rangereg.core.noise, "ThreadPoolExecutor", no_threads)
    o3d.utility.set_max_threads(1)  # what app.distributed sets for --threads 1
    try:
        assert noise_floors([a, b], np.random.default_rng(2), 300) == expect
    finally:
        o3d.utility.set_max_threads(before)


def test_the_normals_floor_is_zero_on_a_clean_plane_and_follows_the_scanners_noise():
    from rangereg.core.noise import normal_floor
    from rangereg.core.scan import Scan

    g = np.stack(np.meshgrid(np.arange(40.0), np.arange(40.0)), -1).reshape(-1, 2)
    tilt = np.c_[g, 0.3 * g[:, 0] - 0.2 * g[:, 1]]  # a tilted plane, 1 unit apart
    plane = Scan(tilt, np.array([20.0, 20.0, 100.0]), name="plane")
    assert normal_floor(plane, tilt[::37]) < 1e-6
    noisy = Scan(tilt + np.random.default_rng(0).normal(0.0, 0.05, tilt.shape), plane.viewpoint, name="noisy")
    assert normal_floor(noisy, tilt[::37]) > 0.5  # degrees: a 5 % jitter of the spacing tilts the fits
    assert normal_floor(Scan(tilt[:23], plane.viewpoint), tilt[:3]) == 0.0  # fewer than 2 x 12 points: not measured

    floors = [normal_floor(scan, scan.points[::40]) for scan in _corner_scans((0.2, 0.8, 3.2))]
    assert 0 < floors[0] < floors[1] < floors[2] < 90
