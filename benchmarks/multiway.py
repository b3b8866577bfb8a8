"""The campaigns' peer: Open3D's multiway registration, as its tutorial documents it, on the same poses.

Open3D's "Multiway registration" tutorial: every pair registered by point-to-plane ICP from the poses
the clouds start at (a coarse pass within 15 voxels, then a fine one within 1.5 voxels), its
information matrix from the fine pass; consecutive scans are odometry edges (certain), the other pairs
loop closures (uncertain); Open3D's global optimisation (Levenberg-Marquardt) with edge pruning at
0.25 and node 0 the reference. Scaled by the point spacing: the tutorial's 2 cm voxel is ~1/150 of its
~3 m scenes; here VOXEL_SPACINGS x the scans' median point spacing (1 mm on the bunny, ~1/150 of it).
Fixed before any of our campaign figures were measured.
"""

from __future__ import annotations

import time

import numpy as np

VOXEL_SPACINGS = 2.0
COARSE, FINE = 15.0, 1.5  # the tutorial's correspondence distances, in voxels


def multiway(scans, initial: list[np.ndarray], voxel: float | None = None) -> tuple[list[np.ndarray], float]:
    """Poses T_first_scan (4, 4) per scan from Open3D's multiway registration started at ``initial``
    (T_world_scan per scan), and the seconds it took (downsampling, every pairwise ICP, the graph)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    t0 = time.perf_counter()
    voxel = voxel or VOXEL_SPACINGS * float(np.median([s.spacing for s in scans]))
    clouds = []
    for s, T in zip(scans, initial):
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s.points)).voxel_down_sample(voxel)
        pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
        pcd.orient_normals_towards_camera_location(s.viewpoint)
        clouds.append(pcd.transform(np.asarray(T, dtype=np.float64)))
    graph = reg.PoseGraph()
    odometry = np.eye(4)
    graph.nodes.append(reg.PoseGraphNode(odometry))
    n = len(clouds)
    plane = reg.TransformationEstimationPointToPlane()
    for a in range(n):
        for b in range(a + 1, n):
            coarse = reg.registration_icp(clouds[a], clouds[b], COARSE * voxel, np.eye(4), plane)
            fine = reg.registration_icp(clouds[a], clouds[b], FINE * voxel, coarse.transformation, plane)
            T = fine.transformation
            info = reg.get_information_matrix_from_point_clouds(clouds[a], clouds[b], FINE * voxel, T)
            if b == a + 1:
                odometry = T @ odometry
                graph.nodes.append(reg.PoseGraphNode(np.linalg.inv(odometry)))
                graph.edges.append(reg.PoseGraphEdge(a, b, T, info, uncertain=False))
            else:
                graph.edges.append(reg.PoseGraphEdge(a, b, T, info, uncertain=True))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=FINE * voxel, edge_prune_threshold=0.25,
                                          reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    world = [np.asarray(node.pose) @ np.asarray(T, dtype=np.float64) for node, T in zip(graph.nodes, initial)]
    first = np.linalg.inv(world[0])
    return [first @ W for W in world], time.perf_counter() - t0
