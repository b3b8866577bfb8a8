"""Memory grows linearly with the points (hardening issue: 2M points were killed at 24 GB).

Peak Python-side allocation (tracemalloc: numpy arrays included; qhull's and Open3D's own buffers
are not seen) of each stage on 50k and on 200k points: four times the points may take at most
5.5 times the memory. The scan is a disc seen from above, whose outline (hull) gains corners as it
gains points, as real scans do (a 2M-point scan had 834): the old frustum test, points x corners,
took 6.4 times the memory here.
"""

from __future__ import annotations

import tracemalloc
from dataclasses import replace
from functools import cache

import numpy as np
import pytest
from rangereg.core.io import load_scan
from rangereg.core.ply import write_ply

RATIO = 5.5  # for 4 x the points


@cache
def _disc_file(n: int, folder: str) -> str:
    rng = np.random.default_rng(n)
    r, th = np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
    x, y = 500 * r * np.cos(th), 500 * r * np.sin(th)
    z = 30 * np.sin(x / 60) * np.cos(y / 80) + rng.normal(0, 0.3, n)
    path = f"{folder}/disc{n}.ply"
    write_ply(path, np.c_[x, y, z])
    return path


def _peak(fn, *args) -> int:
    tracemalloc.start()
    try:
        fn(*args)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _scan(tmp_path_factory, n):
    folder = str(tmp_path_factory.getbasetemp())
    return load_scan(_disc_file(n, folder), viewpoint=np.array([0.0, 0.0, 3000.0]))


_FACES: dict = {}


def _faces(s):
    """The scan's triangulation, computed once per size (the surface stage measures it)."""
    from rangereg.core.surface import triangulate

    if len(s.points) not in _FACES:
        _FACES[len(s.points)] = triangulate(s)
    return _FACES[len(s.points)]


def _stages():
    from rangereg.core.frustum import frustum_of, segment_overlap, visible_from
    from rangereg.core.noise import noise_floor
    from rangereg.core.surface import Surface, triangulate
    from rangereg.core.transforms import from_params

    T = from_params(np.r_[40.0, -25.0, 3.0, 0.02, -0.01, 0.05])
    return {
        "read": lambda s: load_scan(s.source, viewpoint=s.viewpoint),
        "frustum": lambda s: frustum_of(s).contains(s.points),
        "overlap": lambda s: segment_overlap(s, s, T),
        "surface": lambda s: _FACES.setdefault(len(s.points), triangulate(s)),
        "visibility": lambda s: visible_from(Surface(s.points, _faces(s)), s.viewpoint, s.points, 1.0),
        "noise floor": lambda s: noise_floor(s, np.random.default_rng(0), 300),
        "spacing": lambda s: replace(s).spacing,  # a fresh copy: loading has cached the scan's own
    }


@pytest.mark.parametrize("stage", list(_stages()))
def test_peak_memory_grows_linearly_with_the_points(tmp_path_factory, stage):
    fn = _stages()[stage]
    peaks = []
    for n in (50_000, 200_000):
        s = _scan(tmp_path_factory, n)
        fn(_scan(tmp_path_factory, 1000))  # warm up imports and caches outside the measure
        peaks.append(_peak(fn, s))
    assert peaks[1] / peaks[0] < RATIO, f"{stage}: {peaks[0] / 1e6:.1f} MB -> {peaks[1] / 1e6:.1f} MB"
