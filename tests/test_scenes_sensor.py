"""The simulated sensor scenes: fragments fused as a reconstruction system fuses them lie on the scene."""

from __future__ import annotations

import numpy as np
from rangereg.core import scenes_sensor as ss
from rangereg.core.scan import ScanKind
from rangereg.core.transforms import apply


def _off_the_room(scan, mesh) -> np.ndarray:
    """(N,) each point's distance (m) from the room's surface, the point placed by the scan's true pose."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh[0].astype(np.float32)), o3d.core.Tensor(mesh[1].astype(np.uint32)))
    world = apply(scan.pose, scan.points).astype(np.float32)
    return scene.compute_distance(o3d.core.Tensor(world)).numpy()


def test_a_tsdf_fragment_lies_on_the_room_and_its_drift_bends_it():
    rng = np.random.default_rng(3)
    mesh = ss.room_mesh(seed=12)
    first, _ = ss._arc_walk(rng, 6, 2)
    cam, bounds = ss.DepthCamera(cols=80, rows=60), ((-0.05, -0.05, -0.05), (7.05, 5.05, 2.85))
    still = ss.tsdf_fragment(mesh, first, cam, np.random.default_rng(1), bounds, voxel=0.04, drift_deg=0, drift_m=0)
    assert still.kind is ScanKind.UNSTRUCTURED and len(still.points) > 5000
    assert np.median(_off_the_room(still, mesh)) < 0.01  # the surface's points, within a quarter of a voxel
    drifted = ss.tsdf_fragment(mesh, first, cam, np.random.default_rng(1), bounds, voxel=0.04, drift_deg=1.0,
                               drift_m=0.02)
    assert np.percentile(_off_the_room(drifted, mesh), 90) > 2 * np.percentile(_off_the_room(still, mesh), 90)
