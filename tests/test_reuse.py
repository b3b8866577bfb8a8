"""Work a registration keeps and reuses gives the answers of the same work done afresh, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.noise import NORMAL_NEIGHBOURS
from rangereg.core.problem import _normals_at, prepare
from rangereg.core.scan import Scan, ScanKind, kd_tree
from rangereg.core.surface import pca_normals
from rangereg.core.unstructured import cloud_view
from scipy.spatial import cKDTree


def _cloud(n=6000, seed=0) -> Scan:
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, (n, 2))
    pts = np.c_[xy, 0.2 * np.sin(3 * xy[:, 0]) * np.cos(2 * xy[:, 1])] + rng.normal(0, 0.002, (n, 3))
    return Scan(points=pts, viewpoint=np.zeros(3), name="cloud", units="m", kind=ScanKind.UNSTRUCTURED)


def test_a_scans_normals_are_the_same_whichever_draw_fits_them_first():
    scan = _cloud()
    rng = np.random.default_rng(3)
    draws = [rng.choice(len(scan.points), 2500, replace=False) for _ in range(4)]
    fresh = [pca_normals(scan.points, scan.tree.query(scan.points[d], NORMAL_NEIGHBOURS)[1]) for d in draws]
    kept = [_normals_at(scan, d) for d in draws]  # later draws reuse the earlier draws' fits
    for f, k in zip(fresh, kept):
        assert np.array_equal(f, k)
    assert np.array_equal(_normals_at(scan, draws[0][::-1]), fresh[0][::-1])


def test_a_clouds_cut_under_a_guess_asks_only_about_points_not_already_on_it():
    source, target = _cloud(seed=1), _cloud(seed=2)
    view = cloud_view(target)
    rng = np.random.default_rng(5)
    moved = source.points + rng.normal(0, 0.05, source.points.shape)
    inside = view.contains(moved)
    assert 0 < inside.sum() < len(moved)
    for margin in (0.0, 0.01, 0.1, 5.0, -0.5 * view.near, float("nan")):
        assert np.array_equal(view.guessed(None, moved, inside, margin), view._within(moved, view.near + margin))


def test_the_k_d_tree_picks_scipys_default_neighbours_among_equal_distances():
    # a quantized scan (a depth camera's millimetres): many neighbours tie, and which of them a tree returns
    # depends on how it splits; normals, noise floors and misfits were measured on the default tree's picks
    rng = np.random.default_rng(4)
    xy = np.stack(np.meshgrid(np.arange(60), np.arange(60)), -1).reshape(-1, 2) * 0.01
    pts = np.c_[xy, np.round(0.05 * np.sin(7 * xy[:, 0]) + rng.normal(0, 0.002, len(xy)), 3)]
    want, got = cKDTree(pts).query(pts, NORMAL_NEIGHBOURS), kd_tree(pts).query(pts, NORMAL_NEIGHBOURS)
    assert np.array_equal(want[0], got[0]) and np.array_equal(want[1], got[1])


def test_a_source_no_view_can_be_made_of_is_refused_at_the_cut_not_when_drawn():
    # the source's view is made with the cut although only drawing reads it: made later, this pair registered
    wall = _cloud(seed=6).points + [0.0, 0.0, 3.0]
    behind = np.vstack([wall, [[0.0, 0.0, -1.0], [0.1, 0.0, -1.0], [0.0, 0.1, -1.0]]])
    source = Scan(points=behind, viewpoint=np.zeros(3), name="source", units="m", kind=ScanKind.SINGLE_VIEW)
    target = Scan(points=wall, viewpoint=np.zeros(3), name="target", units="m", kind=ScanKind.SINGLE_VIEW)
    with pytest.raises(InputError, match="source: some points lie beside or behind the viewpoint"):
        prepare(source, target)
