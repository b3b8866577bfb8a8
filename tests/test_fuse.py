"""Fusing registered scans into one mesh (core.fuse): the same scans and poses give the same mesh every run
(the no-double-layer property is in tests/test_merge.py, beside the merge that uses it)."""

from __future__ import annotations

import numpy as np
from rangereg.core.fuse import fuse
from rangereg.core.simulate import true_transform


def test_the_same_scans_fuse_to_the_same_mesh_every_run(scene):
    target, source = scene("bowl")
    poses = [np.eye(4), true_transform(source, target)]
    first = fuse([target, source], poses)
    for _ in range(2):
        again = fuse([target, source], poses)
        assert np.array_equal(again.vertices, first.vertices) and np.array_equal(again.faces, first.faces)
