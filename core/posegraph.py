"""The pose graph of a set of scans: trusted pairwise results -> one pose per scan, keeping only the pairs
that close (merge step 4; the robust idea of Choi, Zhou and Koltun 2015, "Robust reconstruction of indoor
scenes": a pair that breaks the loops it lies on is switched off, not averaged in).

    consensus   seeded RANSAC over spanning trees: each tree gives poses; an edge agrees with a tree when
                its residual against the tree's poses, which is the residual of the cycle it closes with
                the tree, lies within the tolerance; the tree whose poses the most edge weight agrees
                with wins (the max-weight tree is tried first). The other edges are rejected.
    optimise    Open3D's pose-graph optimisation (Levenberg-Marquardt) on the agreeing edges, the winning
                tree's edges certain and the loop closures uncertain (its line process may prune those).
    check       every kept edge's residual against the optimised poses (one that still does not fit is
                rejected and the graph solved again), and every cycle's residual (the cycles closed by
                each kept non-tree edge: a basis of all cycles) reported per edge and per scan.
    placed      the scans joined to the reference scan by kept edges; the others are not placed.

A residual is (rotation in degrees, move of the source scan's centroid in units): the discrepancy
``inv(T_i_j) @ inv(P_i) @ P_j`` of edge (i, j) under poses P (T_reference_scan).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .scan import Scan
from .transforms import apply, invert, rotation_angle

if TYPE_CHECKING:
    from .fuse import FacingNormals

# Open3D's line process prunes a loop closure whose weight falls below this (Open3D's documented default)
EDGE_PRUNE = 0.25
TREE_TRIALS = 200  # spanning trees tried by the consensus: each costs a walk and a residual per edge
# A rival placement (a rejected edge and the edges agreeing with it) that weighs this share of the
# consensus's on the scans it moves makes them ambiguous: two against one decides, one against one not
# (on a scan alone; for a group, see rivals)
RIVAL = 0.75


@dataclass(frozen=True, eq=False)
class Edge:
    """A trusted pair: T_i_j (4, 4) maps scan j into scan i's frame; weight: how much of the pair matched
    (its share in [0, 1]); info: (6, 6) Open3D information matrix (None: identity)."""

    i: int
    j: int
    T_i_j: np.ndarray
    weight: float = 1.0
    info: np.ndarray | None = None


@dataclass(frozen=True)
class Tolerance:
    """An edge closes when its cycle residual is within rotation_deg and translation (units)."""

    rotation_deg: float
    translation: float

    def holds(self, residual: tuple[float, float]) -> bool:
        return residual[0] <= self.rotation_deg and residual[1] <= self.translation


@dataclass(frozen=True, eq=False)
class Graph:
    """poses: (4, 4) T_reference_scan per scan (None where not placed); kept: indices of the edges used;
    rejected: {edge index: why}; cycle: {edge index: (deg, units)} the residual of the cycle each kept
    non-tree edge closes with the tree and of each rejected edge against the final poses; scan_cycle:
    per scan, the largest cycle residual of the kept cycles through it (None: on no cycle); tree: indices
    of the spanning tree's edges."""

    poses: list
    kept: list
    rejected: dict
    cycle: dict
    scan_cycle: list
    tree: list = field(default_factory=list)

    @property
    def placed(self) -> list[bool]:
        return [P is not None for P in self.poses]


def residual(T_i_j: np.ndarray, P_i: np.ndarray, P_j: np.ndarray, center_j: np.ndarray) -> tuple[float, float]:
    """(degrees, units) by which edge T_i_j disagrees with poses P_i, P_j; translation measured at
    ``center_j`` (3,), scan j's centroid in its own frame."""
    D = invert(T_i_j) @ invert(P_i) @ P_j
    move = float(np.linalg.norm(apply(D, center_j[None])[0] - center_j))
    return float(np.degrees(rotation_angle(D[:3, :3]))), move


def spanning_tree(n: int, edges: list[Edge], order: list[int]) -> list[int]:
    """Kruskal: the edges (indices) taken in ``order`` that join new scans (a spanning forest)."""
    parent = list(range(n))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = parent[k]
        return k

    tree = []
    for e in order:
        a, b = root(edges[e].i), root(edges[e].j)
        if a != b:
            parent[a] = b
            tree.append(e)
    return tree


def tree_poses(n: int, edges: list[Edge], tree: list[int], reference: int = 0) -> list[np.ndarray | None]:
    """Poses T_root_scan along ``tree``, per component (its root: ``reference``, else the component's
    lowest scan)."""
    adj: dict[int, list[int]] = {k: [] for k in range(n)}
    for e in tree:
        adj[edges[e].i].append(e)
        adj[edges[e].j].append(e)
    poses: list[np.ndarray | None] = [None] * n
    for root in [reference] + [k for k in range(n) if k != reference]:
        if poses[root] is not None:
            continue
        poses[root] = np.eye(4)
        stack = [root]
        while stack:
            k = stack.pop()
            for e in adj[k]:
                ed = edges[e]
                other = ed.j if ed.i == k else ed.i
                if poses[other] is None:
                    poses[other] = poses[k] @ (ed.T_i_j if ed.i == k else invert(ed.T_i_j))
                    stack.append(other)
    return poses


def components(n: int, pairs: list[tuple[int, int]]) -> list[int]:
    """A component label per scan under the pairs (i, j)."""
    parent = list(range(n))

    def root(k: int) -> int:
        while parent[k] != k:
            k = parent[k]
        return k

    for i, j in pairs:
        parent[root(i)] = root(j)
    return [root(k) for k in range(n)]


def consensus(n: int, edges: list[Edge], centers: list[np.ndarray], tol: Tolerance, rng: np.random.Generator,
              trials: int = TREE_TRIALS, force: int | None = None) -> tuple[list[int], list[int], float]:
    """(agreeing edge indices, tree edge indices, their weight) of the spanning tree whose poses the most
    edge weight agrees with (module notes). Ties go to the earlier tree; the max-weight tree is the
    first. ``force``: an edge every tree must hold (a rival to the best, :func:`rivals`)."""
    if not edges:
        return [], [], 0.0
    w = np.array([e.weight for e in edges], dtype=np.float64)
    label = components(n, [(e.i, e.j) for e in edges])
    best: tuple[float, list[int], list[int]] | None = None
    seen: set[tuple[int, ...]] = set()
    for t in range(trials):
        # the first tree takes the heaviest edges; the others a random order leaning to heavy ones
        key = -w if t == 0 else -w * rng.uniform(0.0, 1.0, len(w)) ** 0.5
        order = [int(e) for e in np.argsort(key, kind="stable")]
        if force is not None:
            order = [force] + [e for e in order if e != force]
        tree = spanning_tree(n, edges, order)
        if tuple(sorted(tree)) in seen:
            continue
        seen.add(tuple(sorted(tree)))
        poses = tree_poses(n, edges, tree)
        agree = [k for k, e in enumerate(edges)
                 if label[e.i] == label[e.j] and tol.holds(residual(e.T_i_j, poses[e.i], poses[e.j], centers[e.j]))]
        score = float(w[agree].sum())
        if best is None or score > best[0] + 1e-12:
            best = (score, agree, tree)
    return best[1], best[2], best[0]


def rivals(n: int, edges: list[Edge], centers: list[np.ndarray], tol: Tolerance, rng: np.random.Generator,
           agree: list[int], tree: list[int], reference: int = 0) -> dict[int, str]:
    """Scans the graph cannot place for sure: {scan: why}. For each edge the consensus rejected, the best
    tree that holds it is a rival; where the rival puts scans elsewhere (beyond the tolerance), and the
    edges at those scans that agree with it weigh at least RIVAL x those that agree with the consensus,
    the scans it moves are ambiguous (notes below)."""
    best = tree_poses(n, edges, tree, reference)
    label = components(n, [(edges[e].i, edges[e].j) for e in tree])
    w = [e.weight for e in edges]
    out: dict[int, str] = {}
    for k in range(len(edges)):
        if k in agree:
            continue
        r_agree, r_tree, _ = consensus(n, edges, centers, tol, rng, force=k)
        other = tree_poses(n, edges, r_tree, reference)
        moved = {s for s in range(n) if not tol.holds(_pose_gap(best[s], other[s], centers[s]))}
        if not moved:
            continue
        # the two placements differ by a motion of one group against the rest of its component: the
        # smaller side is the one in doubt (measured from the reference, a wrong edge at the reference
        # "moves" every other scan and the group's inner edges outweigh any boundary: a 24-scan ring of
        # 96 edges, 25 of them wrong, placed 1 scan; with the smaller side 17, none wrong)
        # (When that side holds the reference, the reference may end up unplaced: a caller then solves
        # again from its largest group, as core.merge does.)
        rest = {s for s in range(n) if label[s] == label[next(iter(moved))]} - moved
        if len(rest) < len(moved):
            moved = rest
        # every edge at the moved scans counts, those that agree with both placements on both sides: a
        # group attached by little against the weight inside it is left unplaced whenever a trusted pair
        # says it lies elsewhere. Counting only the edges that differ places more and places wrong: on
        # crops of the simulated turntable (where the pair threshold trusts many wrong poses) 14 right,
        # 4 wrong, 6 not placed of 24, against 5 right, 0 wrong here (the same pair results, replayed)
        here = sum(w[m] for m in agree if {edges[m].i, edges[m].j} & moved)
        there = sum(w[m] for m in r_agree if {edges[m].i, edges[m].j} & moved)
        if there >= RIVAL * here:
            for s in moved:
                out.setdefault(s, f"its pairs disagree ({edges[k].i}-{edges[k].j} against the others) and no "
                                  "cycle decides which is right")
    return out


def _spread(edges: list[Edge], kept: list[int], poses: list, centers: list[np.ndarray], tol: Tolerance) -> float:
    """Sum over the kept edges of their residuals in tolerances (rotation + translation)."""
    total = 0.0
    for k in kept:
        e = edges[k]
        r = residual(e.T_i_j, poses[e.i], poses[e.j], centers[e.j])
        total += r[0] / tol.rotation_deg + r[1] / tol.translation
    return total


def _pose_gap(P: np.ndarray, Q: np.ndarray, center: np.ndarray) -> tuple[float, float]:
    D = invert(P) @ Q
    return float(np.degrees(rotation_angle(D[:3, :3]))), float(np.linalg.norm(apply(D, center[None])[0] - center))


def optimise(n: int, edges: list[Edge], kept: list[int], tree: list[int], poses: list[np.ndarray],
             max_distance: float, reference: int = 0) -> tuple[list[np.ndarray], set[int]]:
    """Open3D's global optimisation of ``poses`` (the reference's the identity) over the kept edges of
    the reference's component (tree edges certain, the others loop closures its line process may
    prune). Returns the poses (the other components' as given) and the pruned edge indices."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    label = components(n, [(edges[k].i, edges[k].j) for k in tree])
    order = [k for k in kept if label[edges[k].i] == label[reference]]
    if all(k in tree for k in order):  # a tree alone: nothing to reconcile
        return poses, set()
    # the reference's component only: Open3D optimises nothing, and says only "Invalid PoseGraph - graph is not
    # connected" as a warning, when the graph holds a node no edge reaches (a scan not placed). With every scan a
    # node, a campaign that left any scan out kept its spanning tree's poses, its loops never reconciled
    # (measured, the 24-stop turntable's crops: each of them)
    nodes = [k for k in range(n) if label[k] == label[reference]]
    at = {k: a for a, k in enumerate(nodes)}
    graph = reg.PoseGraph()
    for k in nodes:
        graph.nodes.append(reg.PoseGraphNode(poses[k]))
    for k in order:
        e = edges[k]
        info = np.eye(6) if e.info is None else e.info
        # Open3D's edge convention: the transformation maps source (j) into target (i)
        graph.edges.append(reg.PoseGraphEdge(at[e.j], at[e.i], e.T_i_j, info, uncertain=k not in tree))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=max_distance, edge_prune_threshold=EDGE_PRUNE,
                                          reference_node=at[reference])
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    left = {(nodes[e.target_node_id], nodes[e.source_node_id]) for e in graph.edges}
    pruned = {k for k in order if (edges[k].i, edges[k].j) not in left}
    P0 = invert(np.asarray(graph.nodes[at[reference]].pose))
    out = list(poses)
    for k in nodes:
        out[k] = P0 @ np.asarray(graph.nodes[at[k]].pose)
    return out, pruned


def solve(n: int, edges: list[Edge], centers: list[np.ndarray], tol: Tolerance, max_distance: float,
          seed: int = 0, reference: int = 0) -> Graph:
    """The pose graph of ``n`` scans from trusted ``edges`` (module notes). ``centers``: (3,) centroid of
    each scan in its own frame; ``max_distance``: Open3D's correspondence distance (units)."""
    rng = np.random.default_rng(seed)
    rejected: dict[int, str] = {}
    live = list(range(len(edges)))
    for _ in range(len(edges) + 1):  # each pass rejects at least one edge or ends
        sub = [edges[k] for k in live]
        agree, tree, _ = consensus(n, sub, centers, tol, rng)
        unsure = rivals(n, sub, centers, tol, rng, agree, tree, reference)
        agree, tree = [live[k] for k in agree], [live[k] for k in tree]
        start = tree_poses(n, edges, tree, reference)
        for k in live:
            e = edges[k]
            if e.i in unsure or e.j in unsure:
                rejected[k] = unsure.get(e.i) or unsure[e.j]
            elif k not in agree:
                r = residual(e.T_i_j, start[e.i], start[e.j], centers[e.j])
                rejected[k] = (f"does not close: its cycle's residual is {r[0]:.3g} deg / {r[1]:.3g} (tolerance "
                               f"{tol.rotation_deg:g} deg / {tol.translation:.3g})")
        if unsure:  # the tree without the ambiguous scans' edges
            live = [k for k in live if k not in rejected]
            continue
        poses, pruned = optimise(n, edges, agree, tree, start, max_distance, reference)
        if _spread(edges, agree, poses, centers, tol) > _spread(edges, agree, start, centers, tol):
            poses, pruned = start, set()  # the optimiser made it worse (e.g. poor information): the tree's poses
        for k in pruned:
            rejected[k] = "pruned by the pose graph's line process (it disagrees with the others once reconciled)"
        kept = [k for k in agree if k not in pruned]
        late = [k for k in kept if not tol.holds(residual(edges[k].T_i_j, poses[edges[k].i], poses[edges[k].j],
                                                          centers[edges[k].j]))]
        for k in late:
            r = residual(edges[k].T_i_j, poses[edges[k].i], poses[edges[k].j], centers[edges[k].j])
            rejected[k] = f"does not fit the optimised poses: {r[0]:.3g} deg / {r[1]:.3g} off"
        if not late and not pruned:
            break
        live = [k for k in live if k not in rejected]
    label = components(n, [(edges[k].i, edges[k].j) for k in kept])
    placed = [label[k] == label[reference] for k in range(n)]
    poses = [P if ok else None for P, ok in zip(poses, placed)]
    cycle, scan_cycle = cycles(n, edges, kept, tree, centers, reference)
    for k in rejected:
        e = edges[k]
        if poses[e.i] is not None and poses[e.j] is not None:
            cycle[k] = residual(e.T_i_j, poses[e.i], poses[e.j], centers[e.j])
    return Graph(poses, sorted(kept), rejected, cycle, scan_cycle, sorted(tree))


def cycles(n: int, edges: list[Edge], kept: list[int], tree: list[int], centers: list[np.ndarray],
           reference: int = 0) -> tuple[dict, list]:
    """The residual of the cycle each kept non-tree edge closes with the tree ({edge: (deg, units)}; tree
    edges lie on cycles only through those), and per scan the largest over the cycles through it."""
    poses = tree_poses(n, edges, tree, reference)
    parent: dict[int, tuple[int, int]] = {}  # scan -> (parent scan, depth) on the tree, by a walk from the roots
    adj: dict[int, list[int]] = {k: [] for k in range(n)}
    for e in tree:
        adj[edges[e].i].append(edges[e].j)
        adj[edges[e].j].append(edges[e].i)
    for root in [reference] + list(range(n)):
        if root in parent:
            continue
        parent[root] = (-1, 0)
        stack = [root]
        while stack:
            k = stack.pop()
            for m in adj[k]:
                if m not in parent:
                    parent[m] = (k, parent[k][1] + 1)
                    stack.append(m)

    def path(a: int, b: int) -> set[int]:
        on = {a, b}
        while a != b:
            if parent[a][1] >= parent[b][1]:
                a = parent[a][0]
            else:
                b = parent[b][0]
            on.add(a)
            on.add(b)
        return on

    cycle: dict[int, tuple[float, float]] = {}
    worst: list[tuple[float, float] | None] = [None] * n
    for k in kept:
        if k in tree:
            continue
        e = edges[k]
        r = residual(e.T_i_j, poses[e.i], poses[e.j], centers[e.j])
        cycle[k] = r
        for s in path(e.i, e.j):
            if worst[s] is None or r[0] > worst[s][0] or (r[0] == worst[s][0] and r[1] > worst[s][1]):
                worst[s] = r
    return cycle, worst


def information_matrix(source_points: np.ndarray, target: Scan, max_distance: float, T_target_source: np.ndarray) -> np.ndarray:
    """(6, 6) information matrix of a pair, as Open3D's ``get_information_matrix_from_point_clouds``
    computes it (:func:`information` of the target points matched within ``max_distance``), here with a
    fixed summation order: Open3D's parallel sums differ in the last bits from run to run, and the pose
    graph then gives poses that differ by ~1e-13 between two identical runs."""
    d, idx = target.tree.query(apply(T_target_source, source_points), distance_upper_bound=max_distance)
    return information(target.points[idx[np.isfinite(d)]])


def information(points: np.ndarray) -> np.ndarray:
    """(6, 6) sum of G^T G over matched points (K, 3) of the target (its frame), G = [-[t]x | I]: how
    firmly they pin a pose (rotation first, then translation, Open3D's order)."""
    x, y, z = points[:, 0], points[:, 1], points[:, 2]
    zero, one = np.zeros(len(points)), np.ones(len(points))
    G = np.stack([np.stack([zero, z, -y, one, zero, zero], 1), np.stack([-z, zero, x, zero, one, zero], 1),
                  np.stack([y, -x, zero, zero, zero, one], 1)], 1)  # (K, 3, 6)
    return np.einsum("kri,krj->ij", G, G)


def plane_information(source_points: np.ndarray, target: Scan, normals: np.ndarray | FacingNormals, max_distance: float,
                      T_target_source: np.ndarray) -> np.ndarray:
    """(6, 6) point-to-plane information of a pair (rotation first, then translation, in the target's frame,
    as :func:`information`): the sum of g g^T / s^2 over the source points (K, 3) matched within
    ``max_distance`` to the target's points, g = [q x n, n] at the matched target point q with its normal n
    (``normals``, (Nt, 3), or the target's FacingNormals), s^2 the mean squared point-to-plane residual there.
    Unlike point-to-point, it sees a pair pinned only across its surfaces: a crop of a smooth region is loose along
    its slide, and its inverse (the covariance) says how loose. Fewer than 6 matches: zeros (the pair pins nothing)."""
    moved = apply(T_target_source, source_points)
    d, idx = target.tree.query(moved, distance_upper_bound=max_distance)
    ok = np.isfinite(d)
    if ok.sum() < 6:
        return np.zeros((6, 6))
    q, n = target.points[idx[ok]], normals[idx[ok]]
    r = np.einsum("ij,ij->i", n, moved[ok] - q)
    s2 = max(float(np.mean(r ** 2)), (1e-6 * max_distance) ** 2)
    G = np.concatenate([np.cross(q, n), n], axis=1)
    return np.einsum("ki,kj->ij", G, G) / s2


def _adjoint(T: np.ndarray) -> np.ndarray:
    """(6, 6) the adjoint of T (4, 4) on twists (rotation, translation): a small motion exp(xi) in T's source
    frame is exp(Ad_T xi) in its target frame."""
    R, t = T[:3, :3], T[:3, 3]
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = R
    A[3:, :3] = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ R
    return A


def covariances(n: int, edges: list[Edge], infos: list[np.ndarray], poses: list, reference: int = 0) -> list:
    """The uncertainty the pose graph propagates to each placed scan: (6, 6) covariance of its pose relative
    to the reference's (a small motion exp(xi) P of its pose P, xi = (rotation, translation) in the
    reference's frame at its origin), or None (not placed, or the reference). ``edges``: the kept edges;
    ``infos``: each one's information (:func:`plane_information`); ``poses``: T_reference_scan (None: not
    placed). The graph's information, linearised at the poses, is the sum over the edges of A^T L A with
    A = Ad(inv(P_i)) [-I, I] (the edge's motion in scan i's frame); its inverse, the reference held, is
    the joint covariance: a scan reached by a long open chain has the chain's uncertainties added up, a
    loop that closes takes them down. A direction nothing pins (a pair's information singular there) comes
    out as a huge variance, not an error."""
    free = [k for k in range(n) if poses[k] is not None and k != reference]
    at = {k: a for a, k in enumerate(free)}
    M = np.zeros((6 * len(free), 6 * len(free)))
    for e, L in zip(edges, infos):
        if poses[e.i] is None or poses[e.j] is None:
            continue
        A = _adjoint(invert(poses[e.i]))
        blocks = [(at[k], s * A) for k, s in ((e.i, -1.0), (e.j, 1.0)) if k in at]
        for a, Ba in blocks:
            for b, Bb in blocks:
                M[6 * a:6 * a + 6, 6 * b:6 * b + 6] += Ba.T @ L @ Bb
    out: list = [None] * n
    if not free:
        return out
    # a ridge far below any pinned direction keeps the solve finite where a direction is pinned by nothing
    ridge = 1e-12 * max(float(np.abs(np.diag(M)).max()), 1e-300)
    S = np.linalg.inv(M + ridge * np.eye(len(M)))
    for k, a in at.items():
        out[k] = S[6 * a:6 * a + 6, 6 * a:6 * a + 6]
    return out


def disagreement(edges: list[Edge], infos: list[np.ndarray], poses: list) -> list[float]:
    """Per edge, how far it misses the poses in its own standard deviations: chi^2 / 6 of the motion
    ``log(inv(P_i) P_j inv(T_i_j))`` (in scan i's frame, the frame of its information ``infos``) under
    ``poses``; 0 for an edge with a scan not placed. About 1 where the pairs err as their information
    says; an edge on no loop (a bridge) is met exactly (0): only loops can show a pair's error."""
    from scipy.spatial.transform import Rotation

    out = []
    for e, L in zip(edges, infos):
        if poses[e.i] is None or poses[e.j] is None:
            out.append(0.0)
            continue
        D = invert(poses[e.i]) @ poses[e.j] @ invert(e.T_i_j)
        eta = np.r_[Rotation.from_matrix(D[:3, :3]).as_rotvec(), D[:3, 3]]
        out.append(float(eta @ L @ eta) / 6.0)
    return out


def spread(cov: np.ndarray, point: np.ndarray) -> tuple[float, float]:
    """(degrees, units): the largest standard deviation of a pose's rotation, and of where it puts
    ``point`` (3,) (the reference's frame), under the covariance ``cov`` (6, 6) of :func:`covariances`."""
    x, y, z = point
    J = np.array([[0, z, -y, 1, 0, 0], [-z, 0, x, 0, 1, 0], [y, -x, 0, 0, 0, 1]], dtype=np.float64)
    rot = float(np.linalg.eigvalsh(cov[:3, :3]).max())
    move = float(np.linalg.eigvalsh(J @ cov @ J.T).max())
    return float(np.degrees(np.sqrt(max(rot, 0.0)))), float(np.sqrt(max(move, 0.0)))
