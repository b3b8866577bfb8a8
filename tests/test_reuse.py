"""Work a registration keeps and reuses gives the answers of the same work done afresh, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.noise import NORMAL_NEIGHBOURS
from rangereg.core.problem import CANDIDATES_PER_POINT, _normals_at, _sample, prepare
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


def _sample_of_the_whole_draw(scan: Scan, idx: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """The normal-space sample as first written: every candidate's normal fitted, then the shares."""
    cand = rng.choice(idx, min(len(idx), CANDIDATES_PER_POINT * n), replace=False)
    axis = np.argmax(np.abs(pca_normals(scan.points, scan.tree.query(scan.points[cand], NORMAL_NEIGHBOURS)[1])), 1)
    groups = [cand[axis == a] for a in range(3)]
    share, left = np.zeros(3, dtype=np.int64), n
    for i, a in enumerate(np.argsort([len(g) for g in groups], kind="stable")):
        share[a] = min(len(groups[a]), left // (3 - i))
        left -= share[a]
    return np.sort(np.concatenate([g[:m] for g, m in zip(groups, share)]))


@pytest.mark.parametrize("seed", range(4))
def test_a_scenes_sample_fitting_normals_in_batches_is_the_whole_draws(seed):
    # a room's corner: the floor holds most points, two walls few (one axis rare enough to need later batches)
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(0, 4, (20000, 2)), rng.normal(0, 0.003, 20000)]
    wall_x = np.c_[rng.normal(0, 0.003, 3000), rng.uniform(0, 4, 3000), rng.uniform(0, 2, 3000)]
    wall_y = np.c_[rng.uniform(0, 4, 600), rng.normal(0, 0.003, 600), rng.uniform(0, 2, 600)]
    scan = Scan(points=np.vstack([floor, wall_x, wall_y]), viewpoint=np.zeros(3), name="corner", units="m",
                kind=ScanKind.UNSTRUCTURED)
    idx = np.sort(rng.choice(len(scan.points), 15000, replace=False))
    for n in (30, 300, 600):  # a third of 600 is more than the rare wall holds among the first batch
        assert np.array_equal(_sample(scan, idx, n, np.random.default_rng(seed)),
                              _sample_of_the_whole_draw(scan, idx, n, np.random.default_rng(seed)))


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
