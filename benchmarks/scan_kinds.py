"""Surfaces and registration per kind of scan on the shared real frames: build times of each kind's surface, and
files-to-pose from the identity (odometry) on the LiDAR pair (against relative.txt) and on the Kinect chain
(no truth: 1->3 against 1->2->3), beside Open3D's point-to-plane ICP on the same pairs.

    python benchmarks/scan_kinds.py [--methods icp,hybrid,global] [--repeats 3] [--kinect-kinds single-view]
    python benchmarks/scan_kinds.py --smallest   # ICP once on every 4th LiDAR point (8 of the 32 rings), no Kinect

The scans are assembled here from Open3D's reader (the LiDAR frames as panoramas at their origin, their
(0, 0, 0) no-returns dropped; the Kinect frames as single-view range grids 640 x 480, or unstructured), so the
figures are the surfaces' and the search's, whatever the file readers decide. Times are medians of
``--repeats`` runs, each reading both files to the pose; quote ``uptime``'s load with them.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.core.config import Config  # noqa: E402
from rangereg.core.register import register  # noqa: E402
from rangereg.core.scan import RangeGrid, Scan, ScanKind  # noqa: E402
from rangereg.core.surface import surface_of  # noqa: E402
from rangereg.core.transforms import invert  # noqa: E402

DATA = next((p / "shared" / "data" for p in ROOT.parents if (p / "shared" / "data").exists()), ROOT / "absent")
LIDAR_TARGET, LIDAR_SOURCE = "251370668.pcd", "251371071.pcd"  # relative.txt is T_target_source of this pair


def lidar(name: str, stride: int = 1) -> Scan:
    import open3d as o3d

    p = np.asarray(o3d.io.read_point_cloud(str(DATA / "lidar" / name)).points, dtype=np.float64)[::stride]
    p = p[np.linalg.norm(p, axis=1) > 0]
    return Scan(points=p, viewpoint=np.zeros(3), name=name, units="m", kind=ScanKind.PANORAMA)


def kinect(k: int, kind: ScanKind) -> Scan:
    import open3d as o3d

    pc = o3d.io.read_point_cloud(str(DATA / "kinect" / f"capture000{k}.pcd"), remove_nan_points=False,
                                 remove_infinite_points=False)
    p = np.asarray(pc.points, dtype=np.float64)
    ok = np.all(np.isfinite(p), axis=1)
    index = np.full(len(p), -1, dtype=np.int64)
    index[ok] = np.arange(ok.sum())
    grid = RangeGrid(index.reshape(480, 640)) if kind is ScanKind.SINGLE_VIEW else None
    return Scan(points=p[ok], viewpoint=np.zeros(3), name=f"capture000{k}", units="m", grid=grid, kind=kind)


def timed(fn, repeats: int):
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return out, float(np.median(times))


def o3d_plane_icp(source: Scan, target: Scan, distances: tuple[float, ...], voxel: float) -> np.ndarray:
    """Open3D's point-to-plane ICP from the identity (clouds at ``voxel``, normals within 3 voxels), coarse to fine."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    a = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source.points)).voxel_down_sample(voxel)
    b = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target.points)).voxel_down_sample(voxel)
    b.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=3 * voxel, max_nn=30))
    T = np.eye(4)
    for d in distances:
        T = reg.registration_icp(a, b, d, T, reg.TransformationEstimationPointToPlane()).transformation
    return T


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--methods", default="icp,hybrid,global")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--kinect-kinds", default="single-view,unstructured")
    ap.add_argument("--smallest", action="store_true", help="a check that it runs (see the module notes)")
    a = ap.parse_args()
    methods = a.methods.split(",")
    print(f"load {os.getloadavg()[0]:.1f}")
    if not (DATA / "lidar" / "relative.txt").exists():
        print(f"the shared frames are absent ({DATA}): nothing to measure")
        return
    if a.smallest:
        T_true = np.loadtxt(DATA / "lidar" / "relative.txt")
        res = register(lidar(LIDAR_SOURCE, 4), lidar(LIDAR_TARGET, 4), np.eye(4), Config(method="icp"))
        deg, move = _error(res.transform, T_true)
        print(f"LiDAR (every 4th point) icp {deg:.3f} deg {100 * move:.1f} cm")
        return
    for what, make in (("LiDAR panorama", lambda: lidar(LIDAR_TARGET)),
                       ("Kinect single view (grid)", lambda: kinect(1, ScanKind.SINGLE_VIEW)),
                       ("Kinect unstructured", lambda: kinect(1, ScanKind.UNSTRUCTURED))):
        scan = make()
        surface, s = timed(lambda scan=scan: surface_of(replace(scan)), a.repeats)  # a new scan: nothing cached
        print(f"surface  {what:28s} {len(scan.points):7d} points  {s:.2f} s  ({surface.n_triangles} triangles)")

    T_true = np.loadtxt(DATA / "lidar" / "relative.txt")
    for m in methods:
        res, s = timed(lambda m=m: register(lidar(LIDAR_SOURCE), lidar(LIDAR_TARGET), np.eye(4), Config(method=m)),
                       a.repeats)
        deg, move = _error(res.transform, T_true)
        print(f"LiDAR    {m:8s} {deg:.3f} deg {100 * move:.1f} cm  {s:.2f} s  {res.stop_reason.value}")
    T, s = timed(lambda: o3d_plane_icp(lidar(LIDAR_SOURCE), lidar(LIDAR_TARGET), (1.0, 0.5, 0.25), 0.25), a.repeats)
    deg, move = _error(T, T_true)
    print(f"LiDAR    open3d point-to-plane (0.25 m voxels, 1 -> 0.25 m) {deg:.3f} deg {100 * move:.1f} cm  {s:.2f} s")

    for kind in (ScanKind(k) for k in a.kinect_kinds.split(",") if k):
        runs = [(m, lambda s, t, m=m: register(s, t, np.eye(4), Config(method=m)).transform) for m in methods]
        runs.append(("open3d", lambda s, t: o3d_plane_icp(s, t, (0.1, 0.05, 0.02), 0.01)))
        for m, fn in runs:
            P, times = {}, []
            for i, j in ((1, 2), (2, 3), (1, 3)):
                P[i, j], s = timed(lambda fn=fn, i=i, j=j, kind=kind: fn(kinect(j, kind), kinect(i, kind)), 1)
                times.append(s)
            deg, move = _error(P[1, 2] @ P[2, 3], P[1, 3])
            print(f"Kinect   {kind.value:12s} {m:8s} chain 1->3 vs 1->2->3: {deg:.3f} deg {100 * move:.2f} cm  "
                  f"median {np.median(times):.2f} s")


def _error(T: np.ndarray, T_ref: np.ndarray) -> tuple[float, float]:
    """Rotation angle (degrees) of T_ref^-1 T and the distance between their translations (units)."""
    from scipy.spatial.transform import Rotation

    d = invert(T_ref) @ T
    return float(np.degrees(Rotation.from_matrix(d[:3, :3]).magnitude())), float(np.linalg.norm(T[:3, 3] - T_ref[:3, 3]))


if __name__ == "__main__":
    main()
