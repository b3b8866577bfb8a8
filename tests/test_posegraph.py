"""The pose graph (core.posegraph): known-answer graphs with corrupted edges, cycles, placement."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.posegraph import (
    Edge,
    Tolerance,
    consensus,
    covariances,
    cycles,
    disagreement,
    information,
    information_matrix,
    plane_information,
    residual,
    solve,
    spanning_tree,
    spread,
)
from rangereg.core.scan import Scan
from rangereg.core.transforms import apply, from_params, invert, pose_error

TOL = Tolerance(2.0, 2.0)  # degrees, units (the scans below are ~100 units across, 1000 units away)


def _truth(n: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """n sensor poses T_world_scan round a turntable 1000 units from its axis, each looking at the object
    at the origin (its z axis), and each scan's centroid in its own frame (the object, 1000 units ahead)."""
    rng = np.random.default_rng(seed)
    poses, centers = [], []
    for k in range(n):
        a = 2 * np.pi * k / n + rng.normal(0, 0.05)
        z = -np.array([np.cos(a), np.sin(a), 0.0])
        x = np.array([-np.sin(a), np.cos(a), 0.0])
        T = np.eye(4)
        T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        T[:3, 3] = -1000 * z + [0, 0, rng.normal(0, 20)]
        poses.append(T)
        centers.append(np.array([0.0, 0.0, 1000.0]) + rng.normal(0, 1, 3))
    return poses, centers


def _edge(P: list[np.ndarray], i: int, j: int, rng: np.random.Generator, weight: float = 0.5) -> Edge:
    """The true T_i_j of poses P, off by a small seeded motion about scan j's centroid (a pairwise
    registration's error: 0.05 deg and 0.1 units per axis, sd)."""
    c = np.array([0.0, 0.0, 1000.0])
    D = from_params(np.r_[rng.normal(0, 0.1, 3), np.radians(rng.normal(0, 0.05, 3))])
    about = from_params(np.r_[c, 0, 0, 0]) @ D @ from_params(np.r_[-c, 0, 0, 0])
    T = invert(P[i]) @ P[j] @ about
    # matched points: 200 of scan j's surface round its centroid, as scan i sees them
    pts = apply(T, c + np.random.default_rng([i, j]).normal(0, 40, (200, 3)))
    return Edge(i, j, T, weight, information(pts))


def _worst(poses, truth) -> float:
    ref = invert(truth[0])
    return max(pose_error(P, ref @ T)[0] for P, T in zip(poses, truth) if P is not None)


def _corrupt(e: Edge, deg: float = 40.0, weight: float | None = None) -> Edge:
    """The edge turned by ``deg`` about its source's frame: a wrong minimum (a twin) that was trusted."""
    T = e.T_i_j @ from_params(np.r_[30.0, 0, 0, np.radians(deg), 0, 0])
    return Edge(e.i, e.j, T, e.weight if weight is None else weight, e.info)


def test_a_corrupted_edge_is_rejected_and_every_scan_lands():
    truth, centers = _truth(6)
    rng = np.random.default_rng(1)
    pairs = [(i, (i + d) % 6) for i in range(6) for d in (1, 2)]
    edges = [_edge(truth, i, j, rng) for i, j in pairs]
    bad = 3
    # the heaviest edge, so that the max-weight tree takes it: only the other trees can show it is wrong
    edges[bad] = _corrupt(edges[bad], weight=1.0)
    g = solve(6, edges, centers, TOL, max_distance=30.0)
    assert set(g.rejected) == {bad} and "does not close" in g.rejected[bad]
    assert all(g.placed)
    assert _worst(g.poses, truth) < 0.5
    # its residual is measured against the final poses: about the corruption
    assert 35 < g.cycle[bad][0] < 45
    # every scan lies on a cycle of kept edges, each closing within the tolerance
    assert all(c is not None and TOL.holds(c) for c in g.scan_cycle)


def test_two_corrupted_edges_of_a_four_scan_campaign_are_both_rejected():
    truth, centers = _truth(4, seed=2)
    rng = np.random.default_rng(2)
    edges = [_edge(truth, i, j, rng) for i in range(4) for j in range(i + 1, 4)]  # all 6 pairs
    edges[0] = _corrupt(edges[0], 30.0)
    edges[5] = _corrupt(edges[5], -50.0)
    g = solve(4, edges, centers, TOL, max_distance=30.0)
    assert set(g.rejected) == {0, 5}
    assert all(g.placed) and _worst(g.poses, truth) < 0.5


def test_a_scan_no_edge_reaches_is_not_placed_and_a_bridge_lies_on_no_cycle():
    truth, centers = _truth(5, seed=3)
    rng = np.random.default_rng(3)
    # 0-1-2 a triangle; 3 hangs on 2 by one edge (no cycle checks it); 4 has no edge at all
    edges = [_edge(truth, 0, 1, rng), _edge(truth, 1, 2, rng), _edge(truth, 0, 2, rng), _edge(truth, 2, 3, rng)]
    g = solve(5, edges, centers, TOL, max_distance=30.0)
    assert g.placed == [True, True, True, True, False] and g.poses[4] is None
    assert not g.rejected
    assert g.scan_cycle[3] is None and g.scan_cycle[4] is None
    assert all(g.scan_cycle[k] is not None for k in (0, 1, 2))
    assert _worst(g.poses, truth) < 0.5


def test_a_scan_whose_two_edges_disagree_is_not_placed_wrong():
    truth, centers = _truth(4, seed=4)
    rng = np.random.default_rng(4)
    edges = [_edge(truth, 0, 1, rng), _edge(truth, 1, 2, rng), _edge(truth, 0, 2, rng)]
    # scan 3: one right edge, one 90 degrees off, of the same weight; every cycle through scan 3 holds
    # both, so no cycle says which is right: one against one does not place it
    edges += [_edge(truth, 2, 3, rng), _corrupt(_edge(truth, 0, 3, rng), 90.0)]
    g = solve(4, edges, centers, TOL, max_distance=30.0)
    assert g.placed == [True, True, True, False]
    assert set(g.rejected) == {3, 4} and all("disagree" in why for why in g.rejected.values())
    assert _worst(g.poses, truth) < 0.5
    # two against one decides: a second right edge to scan 3
    g = solve(4, edges + [_edge(truth, 1, 3, rng)], centers, TOL, max_distance=30.0)
    assert all(g.placed) and set(g.rejected) == {4} and _worst(g.poses, truth) < 0.5


def test_the_consensus_tree_is_seeded_and_the_cycle_residuals_are_exact():
    truth, centers = _truth(5, seed=5)
    edges = [Edge(i, j, invert(truth[i]) @ truth[j]) for i in range(5) for j in range(i + 1, 5)]
    a = consensus(5, edges, centers, TOL, np.random.default_rng(7))
    b = consensus(5, edges, centers, TOL, np.random.default_rng(7))
    assert a == b and len(a[0]) == len(edges) and len(a[1]) == 4 and a[2] == len(edges)
    tree = spanning_tree(5, edges, list(range(len(edges))))
    cyc, per_scan = cycles(5, edges, list(range(len(edges))), tree, centers)
    assert set(cyc) == set(range(len(edges))) - set(tree)  # one cycle per non-tree edge: a basis
    assert max(r for c in cyc.values() for r in c) < 1e-9
    # a known offset on one loop closure shows as that cycle's residual, in degrees and units
    k = next(iter(cyc))
    turned = Edge(edges[k].i, edges[k].j, edges[k].T_i_j @ from_params(np.r_[0, 0, 0, np.radians(3.0), 0, 0]))
    cyc2, per_scan2 = cycles(5, [turned if m == k else e for m, e in enumerate(edges)], list(range(len(edges))), tree,
                             centers)
    assert cyc2[k][0] == pytest.approx(3.0, abs=1e-6)
    c = centers[edges[k].j]
    assert cyc2[k][1] == pytest.approx(2 * np.sin(np.radians(1.5)) * np.hypot(c[1], c[2]), rel=1e-6)
    assert max(s[0] for s in per_scan2 if s is not None) == pytest.approx(3.0, abs=1e-6)


def test_residual_is_zero_for_consistent_poses_and_symmetric_in_its_terms():
    truth, centers = _truth(3, seed=6)
    T = invert(truth[0]) @ truth[1]
    assert residual(T, truth[0], truth[1], centers[1]) == pytest.approx((0.0, 0.0), abs=1e-9)
    M = from_params(np.r_[5.0, -3.0, 2.0, 0.1, -0.2, 0.3])
    # the residual does not depend on the frame the poses are written in
    assert residual(T, M @ truth[0], M @ truth[1], centers[1]) == pytest.approx((0.0, 0.0), abs=1e-7)


def test_information_matrix_is_the_same_bits_every_run(scene):
    from rangereg.core.simulate import true_transform

    target, source = scene("corner")
    T = true_transform(source, target)
    a = information_matrix(source.points, target, 3 * target.spacing, T)
    b = information_matrix(source.points, target, 3 * target.spacing, T)
    assert np.array_equal(a, b) and np.allclose(a, a.T)
    assert a[3, 3] > 100  # the matched points count on the translation diagonal


def test_wrong_edges_at_the_reference_leave_the_rest_placed_and_none_wrong():
    # a 12-scan ring, each scan tied to its 3 neighbours each way, 8 of its 36 edges wrong: a rival that
    # takes a wrong edge at the reference "moves" every other scan, and weighed by all their edges it made
    # all of them ambiguous (1 of 12 placed); the smaller side of the move is the one in doubt
    n, seed = 12, 1
    truth, centers = _truth(n, seed=seed)
    rng = np.random.default_rng(seed)
    edges = [_edge(truth, i, (i + d) % n, rng) for i in range(n) for d in (1, 2, 3)]
    bad = sorted(np.random.default_rng(seed + 10).choice(len(edges), 8, replace=False).tolist())
    for k in bad:
        edges[k] = _corrupt(edges[k], float(np.random.default_rng(k).uniform(20, 170)) * (1 if k % 2 else -1))
    assert any(0 in (edges[k].i, edges[k].j) for k in bad)
    g = solve(n, edges, centers, TOL, max_distance=30.0)
    assert set(bad) <= set(g.rejected)
    assert all(g.placed) and _worst(g.poses, truth) < 0.5


def test_the_uncertainty_adds_up_along_an_open_chain_and_a_closing_pair_takes_it_down():
    # 8 scans at the identity, each pair pinning every direction alike (information I): along the open chain
    # 0-1-...-7 scan k is k pairs' uncertainty from the reference (covariance k I); closed into a ring by 7-0,
    # the two ways round it are two measurements in parallel: k (8 - k) / 8 I (a random walk pinned at both ends)
    n = 8
    poses = [np.eye(4)] * n
    chain = [Edge(k, k + 1, np.eye(4)) for k in range(n - 1)]
    open_cov = covariances(n, chain, [np.eye(6)] * len(chain), poses)
    ring = chain + [Edge(n - 1, 0, np.eye(4))]
    ring_cov = covariances(n, ring, [np.eye(6)] * len(ring), poses)
    assert open_cov[0] is None and ring_cov[0] is None  # the reference
    for k in range(1, n):
        assert np.allclose(open_cov[k], k * np.eye(6), rtol=1e-9)
        assert np.allclose(ring_cov[k], k * (n - k) / n * np.eye(6), rtol=1e-9)
    # a scan not placed has none; the largest standard deviations in degrees and at a point
    poses_apart = poses[:4] + [None] * 4
    assert covariances(n, chain, [np.eye(6)] * len(chain), poses_apart)[5] is None
    rot, move = spread(np.diag([1e-4, 4e-4, 1e-4, 1.0, 1.0, 1.0]), np.zeros(3))
    assert rot == pytest.approx(np.degrees(0.02)) and move == pytest.approx(1.0)
    # away from the origin the rotation's uncertainty moves the point too: 0.02 rad about z at 100 units along x
    assert spread(np.diag([0, 0, 4e-4, 0, 0, 0]), np.array([100.0, 0, 0]))[1] == pytest.approx(2.0)


def test_an_edge_posed_elsewhere_carries_its_uncertainty_in_its_own_frame():
    # one edge from the reference to scan 1 placed 90 deg about z and 100 units along x: the edge's
    # information is in scan 0's frame (its target), so scan 1's covariance is that information's inverse
    P1 = from_params(np.r_[100.0, 0, 0, 0, 0, np.pi / 2])
    L = np.diag([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    (_, cov) = covariances(2, [Edge(0, 1, P1)], [L], [np.eye(4), P1])
    assert np.allclose(cov, np.linalg.inv(L))
    # the same edge written the other way round (1 -> 0, its information in scan 1's frame) agrees once turned
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = P1[:3, :3]
    A[3:, :3] = np.array([[0, 0, 0], [0, 0, -100.0], [0, 100.0, 0]]) @ P1[:3, :3]
    L1 = A.T @ L @ A  # the information of the motion seen from scan 1
    (_, back) = covariances(2, [Edge(1, 0, invert(P1))], [L1], [np.eye(4), P1])
    assert np.allclose(back, np.linalg.inv(L), rtol=1e-6, atol=1e-9)


def test_point_to_plane_information_sees_that_a_flat_patch_slides():
    # a flat patch matched onto itself pins the motion across it (z, and tilts about x and y), and nothing
    # along it: point-to-point information pins all three translations alike and cannot tell
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-50, 50, (400, 2)), rng.normal(0, 0.1, 400)]
    target = Scan(pts, np.array([0.0, 0.0, 500.0]))
    normals = np.tile([0.0, 0.0, 1.0], (400, 1))
    L = plane_information(pts, target, normals, 2.0, np.eye(4))
    assert np.allclose(L, L.T)
    eig = np.linalg.eigvalsh(L)
    assert eig[:3].max() < 1e-9 * eig.max()  # x, y and the turn about z: free
    assert L[5, 5] > 1e3 and L[3, 3] < 1e-9 * L[5, 5] and L[4, 4] < 1e-9 * L[5, 5]
    P = information(pts)
    assert P[3, 3] == P[4, 4] == P[5, 5] == len(pts)
    # nothing matched within the distance: no information
    assert not plane_information(pts + [0, 0, 10.0], target, normals, 2.0, np.eye(4)).any()


def test_an_edge_that_misses_the_poses_shows_it_in_its_own_standard_deviations():
    # poses at the truth; edge 0-1 off by 0.01 rad about z and 0.5 units along x (in scan 0's frame), edge
    # 1-2 exact: chi^2 / 6 is the miss weighed by the edge's information, 0 for the exact one
    P = [from_params(np.r_[100.0 * k, 0, 0, 0, 0, 0.3 * k]) for k in range(3)]
    off = from_params(np.r_[0.5, 0, 0, 0, 0, 0.01])
    L = np.diag([1e4, 1e4, 1e4, 4.0, 4.0, 4.0])
    edges = [Edge(0, 1, invert(off) @ invert(P[0]) @ P[1]), Edge(1, 2, invert(P[1]) @ P[2])]
    chi = disagreement(edges, [L, L], P)
    assert chi[0] == pytest.approx((1e4 * 0.01 ** 2 + 4.0 * 0.5 ** 2) / 6, rel=1e-3) and chi[1] < 1e-12
    assert disagreement(edges, [L, L], [P[0], P[1], None])[1] == 0.0  # a scan not placed: nothing to miss


def test_a_scan_not_placed_does_not_stop_the_others_loops_from_being_optimised():
    # a ring of 8 scans with noisy edges, optimised alone and beside a ninth scan that no edge reaches: Open3D
    # optimises nothing in a graph that is not connected (it only warns), so the ring kept its spanning tree's
    # poses whenever a campaign left a scan out; now the ring's poses are the same either way
    n = 8
    truth, centers = _truth(n, seed=2)
    rng = np.random.default_rng(2)
    edges = [_edge(truth, i, (i + d) % n, rng) for i in range(n) for d in (1, 2)]
    alone = solve(n, edges, centers, TOL, max_distance=30.0)
    beside = solve(n + 1, edges, centers + [centers[0]], TOL, max_distance=30.0)
    assert all(alone.placed) and beside.placed == [True] * n + [False]
    tree = spanning_tree(n, edges, list(range(len(edges))))
    assert not alone.tree or set(alone.tree) != set(range(len(edges)))  # loops: there is something to reconcile
    for P, Q in zip(alone.poses, beside.poses):
        assert np.allclose(P, Q, atol=1e-9)
    assert len(tree) == n - 1 and _worst(beside.poses[:n], truth) < 0.5
