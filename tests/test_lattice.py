"""A depth camera's range grid is recovered from its frame written as bare points, and from nothing else."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.io import load_scan
from rangereg.core.lattice import pixel_grid
from rangereg.core.ply import write_ply
from rangereg.core.scan import ScanKind
from rangereg.core.surface import triangulate

from tests.conftest import DATA


def _depth_frame(rng, rows=60, cols=80, holes=0.2):
    """A pinhole camera's frame of a wavy wall (z forward): (N, 3) float32-rounded points of its valid pixels in
    row-major order, and the (rows, cols) grid of their indices (-1: no depth)."""
    fx, fy = rng.uniform(300, 600, 2)
    cx, cy = cols / 2 + rng.uniform(-3, 3), rows / 2 + rng.uniform(-3, 3)
    r, c = np.mgrid[0:rows, 0:cols]
    z = 2.0 + 0.3 * np.sin(c / 9.0) * np.cos(r / 7.0) + rng.normal(0, 0.002, (rows, cols))
    valid = rng.random((rows, cols)) > holes
    valid[:, 0] = valid[0, :] = valid[:, -1] = valid[-1, :] = True  # the grid spans the whole image
    pts = np.stack([(c - cx) * z / fx, (r - cy) * z / fy, z], -1)[valid].astype(np.float32).astype(np.float64)
    grid = np.full((rows, cols), -1, dtype=np.int64)
    grid[valid] = np.arange(valid.sum())
    return pts, grid


@pytest.mark.parametrize("seed", range(5))
def test_a_depth_frames_grid_comes_back_from_its_bare_points_in_every_camera_convention(seed):
    rng = np.random.default_rng(seed)
    pts, grid = _depth_frame(rng)
    assert np.array_equal(pixel_grid(pts, np.zeros(3)), grid)
    # Open3D's tutorial turns the frame upside down (y and z negated): x / z changes sign, y / z does not
    flipped = pixel_grid(pts * [1, -1, -1], np.zeros(3))
    assert np.array_equal(flipped, grid[:, ::-1])
    # a robot's body frame (x forward, y left, z up): the image coordinates are y / x and z / x
    body = pixel_grid(np.c_[pts[:, 2], -pts[:, 0], -pts[:, 1]], np.zeros(3))
    assert body is not None and np.array_equal(np.sort(body[body >= 0]), np.arange(len(pts)))


def test_points_off_a_lattice_keep_no_grid():
    rng = np.random.default_rng(7)
    pts, _ = _depth_frame(rng)
    assert pixel_grid(pts + rng.normal(0, 0.003, pts.shape), np.zeros(3)) is None  # jittered (thinned, resampled)
    other, _ = _depth_frame(np.random.default_rng(8))
    assert pixel_grid(np.vstack([pts, other]), np.zeros(3)) is None  # two frames fused: two lattices
    assert pixel_grid(np.vstack([pts, pts[:5]]), np.zeros(3)) is None  # two points in one pixel
    assert pixel_grid(pts[:: 37], np.zeros(3)) is None  # too few of the cells filled to be an image
    # thinned on the lattice (Open3D's uniform_down_sample, a random half): still on it, but its cells' neighbours
    # are empty, and a grid's faces would leave the frame without a surface
    assert pixel_grid(pts[::2], np.zeros(3)) is None and pixel_grid(pts[::3], np.zeros(3)) is None
    assert pixel_grid(pts[rng.random(len(pts)) < 0.5], np.zeros(3)) is None
    assert pixel_grid(np.vstack([pts, -pts[:3]]), np.zeros(3)) is None  # not all in front of the camera


def test_a_kinect_frame_written_as_bare_points_reads_as_the_organised_frame(tmp_path):
    folder = DATA / "kinect"
    if not folder.is_dir():
        pytest.skip(f"the shared data {folder} is absent")
    organised = load_scan(folder / "capture0002.pcd")
    write_ply(tmp_path / "bare.ply", organised.points)
    bare = load_scan(tmp_path / "bare.ply")
    index = organised.grid.index
    rows, cols = np.flatnonzero((index >= 0).any(1)), np.flatnonzero((index >= 0).any(0))
    cropped = index[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]  # the image's rim holds no depth
    assert bare.kind is ScanKind.SINGLE_VIEW and np.array_equal(bare.grid.index, cropped)
    assert "pixel lattice" in bare.notes[0]
    assert bare.faces is None and len(triangulate(bare)) == len(triangulate(organised))
    write_ply(tmp_path / "third.ply", organised.points[::3])  # thinned on the lattice: bare points, a surface
    third = load_scan(tmp_path / "third.ply")
    assert third.grid is None and len(triangulate(third)) > len(third.points)
