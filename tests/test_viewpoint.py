"""Where the sensor stood (core.viewpoint): estimated on the scanned side from a range grid, a mesh or bare
points, and a given viewpoint refused when it cannot have seen the scan."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.io import load_scan
from rangereg.core.scan import RangeGrid
from rangereg.core.viewpoint import STANDOFF, check_viewpoint, estimate_viewpoint


def cap(n: int = 21, bulge: float = 0.3) -> tuple[np.ndarray, RangeGrid]:
    """A spherical cap over the unit square bulging towards +z, as an (n x n) range grid whose
    cross(d/dcol, d/drow) points to +z (the scanned side: Stanford's convention)."""
    u, v = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n))  # columns run along x, rows along y
    points = np.c_[u.ravel(), v.ravel(), bulge * (1 - (u ** 2 + v ** 2).ravel() / 2)]
    return points, RangeGrid(np.arange(n * n).reshape(n, n))


def test_a_range_grid_puts_the_viewpoint_on_its_scanned_side_at_the_standoff():
    points, grid = cap()
    vp = estimate_viewpoint(points, grid)
    c, size = points.mean(0), np.linalg.norm(np.ptp(points, axis=0))
    assert vp[2] > c[2] and np.linalg.norm(vp - c) == pytest.approx(STANDOFF * size)
    flipped = RangeGrid(grid.index[:, ::-1])  # the other winding: the other side
    assert estimate_viewpoint(points, flipped)[2] < c[2]


def test_mesh_faces_tell_the_side_by_their_winding():
    points, grid = cap()
    i = grid.index
    faces = np.r_[np.c_[i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, :-1].ravel()]]
    assert estimate_viewpoint(points, faces=faces)[2] > points[:, 2].mean()
    assert estimate_viewpoint(points, faces=faces[:, ::-1])[2] < points[:, 2].mean()


def test_bare_points_are_seen_from_where_they_bulge():
    points, _ = cap()
    assert estimate_viewpoint(points)[2] > points[:, 2].mean()
    dish = points * np.array([1, 1, -1])  # the same sheet bulging to -z
    assert estimate_viewpoint(dish)[2] < dish[:, 2].mean()


def test_a_viewpoint_behind_the_surface_or_on_the_points_is_refused():
    points, grid = cap()
    check_viewpoint(points, np.array([0.0, 0.0, 5.0]), grid, None, "s.ply")  # in front: taken
    with pytest.raises(InputError, match="s.ply: the viewpoint .* is on the wrong side of the surface"):
        check_viewpoint(points, np.array([0.0, 0.0, -5.0]), grid, None, "s.ply")
    on_them = np.zeros((10, 3))
    with pytest.raises(InputError, match="sits on the points"):
        check_viewpoint(on_them, np.zeros(3), None, None, "s.ply")
    check_viewpoint(points, np.array([0.0, 0.0, -5.0]), None, None, "s.ply")  # bare points: no side to check


def test_viewpoint_on_the_wrong_side(bunny):
    s = bunny("bun000")
    behind = s.centroid - (s.viewpoint - s.centroid)
    with pytest.raises(InputError, match="wrong side"):
        load_scan(s.source, viewpoint=behind)


def test_a_plane_seen_face_on_grazes_nothing_and_edge_on_everything():
    from rangereg.core.scan import kd_tree
    from rangereg.core.viewpoint import grazing_share

    u, v = np.meshgrid(np.linspace(-1, 1, 60), np.linspace(-1, 1, 60))
    plane = np.c_[u.ravel(), v.ravel(), np.zeros(u.size)]
    tree = kd_tree(plane)
    assert grazing_share(plane, tree, np.array([0.0, 0.0, 5.0])) == 0.0
    assert grazing_share(plane, tree, np.array([50.0, 0.0, 0.0])) == 1.0
