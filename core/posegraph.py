"""The pose graph of a set of scans (merge step 4): pairwise results made globally consistent by
Open3D's pose-graph optimisation, solved once on the client; inconsistent loop closures are pruned."""

from __future__ import annotations

import numpy as np

from .scan import Scan
from .transforms import apply, invert


def information_matrix(source_points: np.ndarray, target: Scan, max_distance: float, T_target_source: np.ndarray) -> np.ndarray:
    """(6, 6) information matrix of a pair, as Open3D's ``get_information_matrix_from_point_clouds``
    computes it (sum of G^T G over the target points matched within ``max_distance``, G = [-[t]x | I]),
    here with a fixed summation order: Open3D's parallel sums differ in the last bits from run to run,
    and the pose graph then gives poses that differ by ~1e-13 between two identical runs."""
    d, idx = target.tree.query(apply(T_target_source, source_points), distance_upper_bound=max_distance)
    t = target.points[idx[np.isfinite(d)]]
    x, y, z = t[:, 0], t[:, 1], t[:, 2]
    zero, one = np.zeros(len(t)), np.ones(len(t))
    G = np.stack([np.stack([zero, z, -y, one, zero, zero], 1), np.stack([-z, zero, x, zero, one, zero], 1),
                  np.stack([y, -x, zero, zero, zero, one], 1)], 1)  # (K, 3, 6)
    return np.einsum("kri,krj->ij", G, G)


def solve_pose_graph(n, pairs, initial, chain, scans) -> tuple[list, set]:
    """Globally consistent T_first_scan from pairwise results (Open3D pose-graph optimisation), and the
    pairs (i, j) whose edges the optimisation pruned as inconsistent."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    tree = set()
    if chain:
        world = [np.eye(4)]
        for p in pairs:
            world.append(world[p.i] @ p.T_i_j)
    else:
        world = [invert(initial[0]) @ T for T in initial]
        # start from the pairwise results along a spanning tree, so the optimiser starts near them
        seen = {0}
        for _ in range(n):
            for p in sorted(pairs, key=lambda p: p.error):
                if p.i in seen and p.j not in seen:
                    world[p.j] = world[p.i] @ p.T_i_j
                elif p.j in seen and p.i not in seen:
                    world[p.i] = world[p.j] @ invert(p.T_i_j)
                else:
                    continue
                seen |= {p.i, p.j}
                tree.add((p.i, p.j))
    if chain or len(pairs) < 2:
        return world, set()
    graph = reg.PoseGraph()
    for T in world:
        graph.nodes.append(reg.PoseGraphNode(T))
    scale = float(np.median([s.spacing for s in scans]))
    for p in pairs:
        # Open3D's edge convention: the transformation maps source (j) into target (i).
        info = information_matrix(scans[p.j].points, scans[p.i], 3.0 * scale, p.T_i_j)
        # Spanning-tree edges are trusted; the others are loop closures the optimiser may prune.
        graph.edges.append(reg.PoseGraphEdge(p.j, p.i, p.T_i_j, info, uncertain=(p.i, p.j) not in tree))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=3.0 * scale, edge_prune_threshold=0.25,
                                          reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    kept = {(e.target_node_id, e.source_node_id) for e in graph.edges}
    rejected = {(p.i, p.j) for p in pairs} - kept
    T0 = np.asarray(graph.nodes[0].pose)
    return [invert(T0) @ np.asarray(node.pose) for node in graph.nodes], rejected
