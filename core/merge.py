"""A whole set of scans -> globally consistent poses -> one model.

1. Initial poses (``T_world_scan``): given (a Stanford .conf), the scans' stored rough poses, or a
   chain in the given order (each scan registered onto the previous one from the identity).
2. Every pair whose frustums overlap under those poses is registered with the hybrid optimiser.
3. Open3D's pose-graph optimisation makes the pairwise results globally consistent.
4. :func:`core.fuse.fuse` builds one surface model. Poses are returned in the first scan's frame.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .fuse import FusedModel, fuse
from .problem import ProblemConfig, prepare
from .register import Config, register
from .scan import Scan
from .surface import Surface
from .transforms import invert

MIN_OVERLAP = 0.25  # visible overlap, both ways, under the initial poses, for a pair to be registered
MIN_OVERLAP_ANY = 0.05  # below this a scan's best partner is no partner: the scan overlaps nothing
OUTLIER_PAIR = 20.0  # a pair whose E exceeds this many times the median pair's is dropped


@dataclass(frozen=True, eq=False)
class PairResult:
    i: int
    j: int
    T_i_j: np.ndarray  # maps scan j into scan i's frame
    error: float
    overlap: float


@dataclass(frozen=True, eq=False)
class MergeResult:
    poses: list  # (4, 4) T_first_scan per scan
    pairs: list
    model: FusedModel | None
    seconds: float

    def __repr__(self) -> str:
        return f"MergeResult({len(self.poses)} scans, {len(self.pairs)} pairs, {self.seconds:.1f} s, {self.model!r})"


def merge(scans: list[Scan], initial: list[np.ndarray] | None = None, config: Config | None = None,
          progress: Callable[[str], None] | None = None, build_model: bool = True) -> MergeResult:
    """Register and fuse ``scans``; ``initial``: T_world_scan per scan (None: stored guesses or a chain)."""
    if len(scans) < 2:
        raise InputError("merge needs at least two scans")
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    config = config or Config(problem=ProblemConfig(rotation_uncertainty_deg=25.0))
    surfaces = [Surface.from_scan(s) for s in scans]
    chain = initial is None and not all(s.guess is not None for s in scans)
    if initial is None:
        initial = [s.guess for s in scans] if not chain else [np.eye(4) for _ in scans]
    pairs: list[PairResult] = []
    if chain:
        candidates = [(i, i + 1, 1.0) for i in range(len(scans) - 1)]
    else:
        overlaps = [(i, j, _visible_overlap(scans, surfaces, i, j, invert(initial[i]) @ initial[j], config))
                    for i in range(len(scans)) for j in range(i + 1, len(scans))]
        candidates = [c for c in overlaps if c[2] >= MIN_OVERLAP]
        # A scan whose every overlap looks small under rough poses still gets its best partner.
        for k in range(len(scans)):
            if not any(k in c[:2] for c in candidates):
                best = max((c for c in overlaps if k in c[:2]), key=lambda c: c[2])
                if best[2] >= MIN_OVERLAP_ANY:
                    candidates.append(best)
    linked = {k for i, j, _ in candidates for k in (i, j)}
    alone = [scans[k].name for k in range(len(scans)) if k not in linked]
    if alone:
        raise InputError(f"{', '.join(alone)} overlap(s) no other scan under the initial poses; "
                         "give better initial poses (--init) or leave it out")
    for i, j, frac in candidates:
        say(f"registering {scans[j].name} onto {scans[i].name}")
        T0 = invert(initial[i]) @ initial[j]
        problem = prepare(scans[j], scans[i], T0, config.problem, surface=surfaces[i], seed=config.seed)
        res = register(scans[j], scans[i], T0, config, problem=problem)
        pairs.append(PairResult(i, j, res.transform, res.error, frac))
    if len(pairs) >= 3:
        # A pair whose final E is far above the others' did not find its partner surface: leave it out.
        median = float(np.median([p.error for p in pairs]))
        good = [p for p in pairs if p.error <= OUTLIER_PAIR * median]
        if {k for p in good for k in (p.i, p.j)} == set(range(len(scans))):
            pairs = good
    poses = _pose_graph(len(scans), pairs, initial, chain, scans)
    model = None
    if build_model:
        say("fusing the registered scans into one model")
        model = fuse(scans, poses, surfaces)
    return MergeResult(poses, pairs, model, time.perf_counter() - t0)


def _visible_overlap(scans, surfaces, i, j, T_i_j, config) -> float:
    """The smaller of the two overlap fractions (frustum and visibility, as registration uses)."""
    fracs = []
    for a, b, T in ((j, i, T_i_j), (i, j, invert(T_i_j))):
        try:
            fracs.append(prepare(scans[a], scans[b], T, config.problem, surface=surfaces[b]).used.mean())
        except InputError:
            return 0.0
    return float(min(fracs))


def _pose_graph(n, pairs, initial, chain, scans):
    """Globally consistent T_first_scan from pairwise results (Open3D pose-graph optimisation)."""
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
        return world
    graph = reg.PoseGraph()
    for T in world:
        graph.nodes.append(reg.PoseGraphNode(T))
    scale = float(np.median([s.spacing for s in scans]))
    clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(s.points)) for s in scans]
    for p in pairs:
        # Open3D's edge convention: the transformation maps source (j) into target (i).
        info = reg.get_information_matrix_from_point_clouds(clouds[p.j], clouds[p.i], 3.0 * scale, p.T_i_j)
        # Spanning-tree edges are trusted; the others are loop closures the optimiser may prune.
        graph.edges.append(reg.PoseGraphEdge(p.j, p.i, p.T_i_j, info, uncertain=(p.i, p.j) not in tree))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=3.0 * scale, edge_prune_threshold=0.25,
                                          reference_node=0)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                                reg.GlobalOptimizationConvergenceCriteria(), option)
    T0 = np.asarray(graph.nodes[0].pose)
    return [invert(T0) @ np.asarray(node.pose) for node in graph.nodes]
