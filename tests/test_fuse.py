"""Fusing registered scans into one mesh (core.fuse): the same scans and poses give the same mesh every run
(the no-double-layer property is in tests/test_merge.py, beside the merge that uses it)."""

from __future__ import annotations

import numpy as np
from rangereg.core.fuse import FacingNormals, fuse, sample_quality
from rangereg.core.simulate import true_transform


def test_the_same_scans_fuse_to_the_same_mesh_every_run(scene):
    target, source = scene("bowl")
    poses = [np.eye(4), true_transform(source, target)]
    first = fuse([target, source], poses)
    for _ in range(2):
        again = fuse([target, source], poses)
        assert np.array_equal(again.vertices, first.vertices) and np.array_equal(again.faces, first.faces)


def _kept_by_brute_force(scans, poses, quality, surfaces, tol):
    """Which samples fuse keeps, every point asked against every other scan's whole surface (no shortcut)."""
    out = []
    for i, (s, T) in enumerate(zip(scans, poses)):
        pts = s.points @ T[:3, :3].T + T[:3, 3]
        keep = np.zeros(len(pts), bool)
        keep[surfaces[i].faces.ravel()] = True
        for j, (surf, Tj) in enumerate(zip(surfaces, poses)):
            if j == i:
                continue
            Ti = np.linalg.inv(Tj)
            c, d2 = surf.closest(pts @ Ti[:3, :3].T + Ti[:3, 3])
            covered = d2 < tol * tol
            qj = quality[j][scans[j].tree.query(c[covered])[1]]
            qi = quality[i][covered]
            lose = (qj > qi) | ((qj == qi) & (j < i))
            keep[np.flatnonzero(covered)[lose]] = False
        out.append(keep)
    return out


def test_the_samples_kept_are_those_every_point_asked_against_every_scan_keeps():
    from rangereg.core.fuse import sample_quality
    from rangereg.core.surface import Surface
    from rangereg.core.turntable import TurntableConfig, make_campaign

    camp = make_campaign(0, TurntableConfig(scans=8))  # four stops 45 degrees apart: each overlaps some, not all
    scans = camp.scans[:4]
    poses = [np.linalg.inv(scans[0].pose) @ s.pose for s in scans]
    surfaces = [Surface.from_scan(s) for s in scans]
    quality = [sample_quality(s)[1] for s in scans]
    tol = 3.0 * float(np.median([s.spacing for s in scans]))
    model = fuse(scans, poses, surfaces)
    expected = _kept_by_brute_force(scans, poses, quality, surfaces, tol)
    for got, want in zip(model.kept, expected):
        assert np.array_equal(got, want)
    assert 0 < sum(k.sum() for k in model.kept) < sum(len(s.points) for s in scans)  # some overlap was decided
    given = fuse(scans, poses, surfaces, qualities=[sample_quality(s) for s in scans])  # made already: the same
    assert np.array_equal(given.vertices, model.vertices) and np.array_equal(given.faces, model.faces)


def test_normals_worked_out_where_asked_are_those_of_the_whole_scan_bit_for_bit(scene):
    """A campaign asks a scan's normals a few thousand at a time (the polish, a pair's information): each row as
    sample_quality gives it for the whole scan, however asked (indices with repeats, any shape, slices)."""
    scan = scene("corner")[0]
    whole = sample_quality(scan)[0]
    lazy = FacingNormals(scan)
    rows = np.random.default_rng(0).integers(0, len(scan.points), (40, 25))
    assert np.array_equal(lazy[rows], whole[rows])
    assert np.array_equal(lazy[::7], whole[::7])
    assert np.array_equal(lazy[np.arange(len(scan.points))], whole)
