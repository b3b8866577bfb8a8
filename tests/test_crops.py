"""Seeded crops of a range grid (app.crops): the rule's share, a consistent grid, the same crop every time."""

import numpy as np
import pytest
from rangereg.app.crops import SHARE_HIGH, SHARE_LOW, crop
from rangereg.core.errors import InputError
from rangereg.core.surface import Surface


def test_a_crop_holds_its_share_keeps_its_frame_and_is_the_same_every_time(scene):
    scan, _ = scene("corner")
    for k in range(4):
        c = crop(scan, k)
        share = len(c.points) / len(scan.points)
        assert SHARE_LOW <= share <= SHARE_HIGH + 0.05
        occupied = c.grid.index[c.grid.index >= 0]
        assert sorted(occupied.tolist()) == list(range(len(c.points)))  # every point in one cell
        assert np.array_equal(c.viewpoint, scan.viewpoint) and c.units == scan.units
        assert set(map(tuple, c.points)) <= set(map(tuple, scan.points))
        assert np.array_equal(crop(scan, k).points, c.points)
        assert Surface.from_scan(c).n_triangles > 0
    assert not np.array_equal(crop(scan, 0).points, crop(scan, 1).points)


def test_a_scan_without_a_grid_cannot_be_cropped(scene):
    from dataclasses import replace

    scan, _ = scene("corner")
    with pytest.raises(InputError, match="range grid"):
        crop(replace(scan, grid=None), 0)
