"""A whole set of scans -> globally consistent poses -> one model.

1. Initial poses (``T_world_scan``): given (a Stanford .conf), the scans' stored rough poses, or a
   chain in the given order (each scan registered onto the previous one from the identity).
2. Candidate pairs (``pairs``): ``init``: the pairs that overlap under the initial poses, each scan
   keeping its best few partners; ``overlap``: every pair that overlaps; ``chain``: consecutive scans
   (and the last with the first when they overlap: a turntable's loop).
3. Every candidate pair is registered with the hybrid optimiser, then polished (point-to-plane).
   Pairs are independent tasks: ``map_tasks`` runs them (serially by default; ``app.distributed``
   runs them on Dask). Each task gets a seed of its own, ``SeedSequence([seed, i, j])``, so the
   result does not depend on where or in which order the tasks run.
4. Open3D's pose-graph optimisation makes the pairwise results globally consistent; loop-closure
   edges it finds inconsistent are pruned and reported.
5. :func:`core.fuse.fuse` builds one surface model. Poses are returned in the first scan's frame.
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from .errors import InputError
from .fuse import FusedModel, fuse, sample_quality
from .posegraph import solve_pose_graph
from .problem import ProblemConfig, prepare
from .register import Config, register
from .scan import RangeGrid, Scan
from .surface import Surface
from .transforms import apply, from_params, invert

MIN_OVERLAP = 0.25  # visible overlap, both ways, under the initial poses, for a pair to be registered
MIN_OVERLAP_ANY = 0.05  # below this a scan's best partner is no partner: the scan overlaps nothing
# pairs="init" keeps, per scan, its best partners by overlap: on a 24-stop turntable every scan overlaps
# 10-11 others by >= 0.25 (measured, seed 1), and the far ones add work and wrong minima, not accuracy.
MAX_PARTNERS = 4
OUTLIER_PAIR = 20.0  # a pair whose E exceeds this many times the median pair's is dropped
# Polish: point-to-plane Gauss-Newton steps after the hybrid. Beyond the paper: its ICP (point to
# closest point) slides slowly along smooth surfaces and stops up to a degree or more off on the simulated
# turntable; point-to-plane converges in a few steps. Measured, 24 stops, seed 1, 15 pairs 15-30 deg apart,
# mean (max) rotation error: no polish 0.36 (1.27) deg; gate 3 / 1.5 / 1 spacings: 0.15 / 0.055 / 0.059 deg
# (a wide gate lets in points beyond the target's edge, whose closest points sit on the edge). On a smoother
# object (fewer, wider lumps): 1.92 (6.6) deg without, 0.16 / 0.11 / 0.11 deg with.
POLISH_STEPS = 30
POLISH_GATE = 1.5  # correspondences farther than this many point spacings are left out of the polish
PAIR_MODES = ("init", "chain", "overlap")

TaskMap = Callable[[Callable[[Any, Any], Any], Sequence[Any], Any], list]
"""``map_tasks(fn, items, shared) -> [fn(shared, item) for item in items]``, in order, run anywhere."""


def serial_map(fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any) -> list:
    """The default :data:`TaskMap`: a plain loop in this process."""
    return [fn(shared, item) for item in items]


@dataclass(frozen=True, eq=False)
class PairResult:
    """One registered pair. ``status``: "used" (an edge of the pose graph), "dropped" (E far above the
    other pairs': it did not find its partner surface) or "rejected" (pruned by the pose graph as
    inconsistent with the others)."""

    i: int
    j: int
    T_i_j: np.ndarray  # maps scan j into scan i's frame
    error: float
    overlap: float
    seconds: float = 0.0
    status: str = "used"

    def __repr__(self) -> str:
        return f"PairResult({self.j}->{self.i}, E={self.error:.4g}, overlap {self.overlap:.0%}, {self.status})"


@dataclass(frozen=True, eq=False)
class MergeResult:
    poses: list  # (4, 4) T_first_scan per scan
    pairs: list  # every registered PairResult, with its status
    model: FusedModel | None
    seconds: float
    pair_seconds: float = 0.0  # wall time of the pairwise stage (candidates + registrations)
    overlap_seconds: float = 0.0  # of which measuring the candidates' overlap
    mode: str = "init"

    @property
    def used(self) -> list:
        return [p for p in self.pairs if p.status == "used"]

    def __repr__(self) -> str:
        return (f"MergeResult({len(self.poses)} scans, {len(self.used)} of {len(self.pairs)} pairs used, "
                f"{self.seconds:.1f} s, {self.model!r})")


# ---- tasks: plain numpy in, plain numpy out (Open3D geometry does not pickle) ----

@dataclass(frozen=True, eq=False)
class Shared:
    """What every task needs, shipped once per worker: the scans as plain arrays and the config."""

    token: str  # identifies the scan set, for the per-process cache
    scans: tuple  # dicts from scan_arrays
    config: Config


def scan_arrays(scan: Scan) -> dict:
    """A scan as plain numpy arrays and strings (picklable, cheap to ship)."""
    return {"points": scan.points, "viewpoint": scan.viewpoint, "name": scan.name, "units": scan.units,
            "grid": None if scan.grid is None else scan.grid.index, "faces": scan.faces}


def _token(scans: list[Scan], config: Config) -> str:
    h = hashlib.sha1(repr(config).encode())
    for s in scans:
        h.update(s.name.encode())
        h.update(np.ascontiguousarray(s.points).tobytes())
    return h.hexdigest()


_BUILT: dict[str, dict] = {}  # per process: token -> {scan index: (Scan, Surface)} and {("normals", k): (N, 3)}


def clear_geometry_cache() -> None:
    """Forget the scans built in this process (a benchmark's runs each start from none, as workers do)."""
    _BUILT.clear()


def _built(shared: Shared, k: int) -> tuple[Scan, Surface]:
    """Scan k rebuilt from its arrays, with its surface: built once per process, then reused."""
    if shared.token not in _BUILT:
        _BUILT.clear()  # one scan set at a time: a new merge frees the last one's geometry
        _BUILT[shared.token] = {}
    cache = _BUILT[shared.token]
    if k not in cache:
        d = shared.scans[k]
        scan = Scan(points=d["points"], viewpoint=d["viewpoint"], name=d["name"], units=d["units"],
                    grid=None if d["grid"] is None else RangeGrid(d["grid"]), faces=d["faces"])
        cache[k] = (scan, Surface.from_scan(scan))
    return cache[k]


def _normals(shared: Shared, k: int) -> np.ndarray:
    """(N, 3) normals of scan k (facing its sensor), once per process: only targets of a pair need them."""
    cache = _BUILT[shared.token]
    if ("normals", k) not in cache:
        cache[("normals", k)] = sample_quality(_built(shared, k)[0])[0]
    return cache[("normals", k)]


def pair_seed(seed: int, i: int, j: int) -> int:
    """The seed of pair (i, j): independent of where and in which order the pairs run."""
    return int(np.random.SeedSequence([seed, i, j]).generate_state(1)[0])


def overlap_task(shared: Shared, item: tuple) -> float:
    """item (i, j, T_i_j) -> the smaller of the two overlap fractions (frustum and visibility)."""
    i, j, T_i_j = item
    (si, fi), (sj, fj) = _built(shared, i), _built(shared, j)
    fracs = []
    for src, tgt, surf, T in ((sj, si, fi, T_i_j), (si, sj, fj, invert(T_i_j))):
        try:
            fracs.append(prepare(src, tgt, T, shared.config.problem, surface=surf, seed=shared.config.seed).used.mean())
        except InputError:
            return 0.0
    return float(min(fracs))


def pair_task(shared: Shared, item: tuple) -> tuple[np.ndarray, float, float]:
    """item (i, j, T0_i_j) -> (T_i_j, E, seconds): scan j registered onto scan i from T0, then polished."""
    i, j, T0 = item
    t0 = time.perf_counter()
    target, surface = _built(shared, i)
    normals = _normals(shared, i)
    source = _built(shared, j)[0]
    seed = pair_seed(shared.config.seed, i, j)
    config = replace(shared.config, seed=seed)
    problem = prepare(source, target, T0, config.problem, surface=surface, seed=seed)
    res = register(source, target, T0, config, problem=problem)
    T = polish(source.points, target, surface, normals, res.transform, max(source.spacing, target.spacing))
    return T, float(res.error), time.perf_counter() - t0


def polish(points: np.ndarray, target: Scan, surface: Surface, normals: np.ndarray, T: np.ndarray,
           spacing: float) -> np.ndarray:
    """Point-to-plane Gauss-Newton from T (T_target_source): points (N, 3) source frame, normals
    (Nt, 3) at the target's points. Returns the polished T; T itself if too few correspondences."""
    gate2 = (POLISH_GATE * spacing) ** 2
    for _ in range(POLISH_STEPS):
        p = apply(T, points)
        c, d2 = surface.closest(p)
        ok = d2 < gate2
        if ok.sum() < 12:
            break
        p, c = p[ok], c[ok]
        n = normals[target.tree.query(c)[1]]
        centre = p.mean(0)
        J = np.concatenate([np.cross(p - centre, n), n], axis=1)
        r = np.einsum("ij,ij->i", n, p - c)
        # einsum, not BLAS: the same sums in the same order whatever the thread count (bitwise-equal results)
        A = np.einsum("ni,nj->ij", J, J)
        b = -np.einsum("ni,n->i", J, r)
        try:
            x = np.linalg.solve(A, b)
        except np.linalg.LinAlgError:
            break
        D = from_params(np.r_[0.0, 0.0, 0.0, x[:3]])
        D[:3, 3] = centre - D[:3, :3] @ centre + x[3:]
        T = D @ T
        if np.linalg.norm(x[:3]) < 1e-7 and np.linalg.norm(x[3:]) < 1e-5 * spacing:
            break
    return T


# ---- the merge ----

def merge(scans: list[Scan], initial: list[np.ndarray] | None = None, config: Config | None = None,
          progress: Callable[[str], None] | None = None, build_model: bool = True, pairs: str | None = None,
          map_tasks: TaskMap | None = None) -> MergeResult:
    """Register and fuse ``scans``; ``initial``: T_world_scan per scan (None: stored guesses or a chain).

    ``pairs``: "init", "overlap" or "chain" (None: "init" when there are initial poses, else "chain").
    ``map_tasks``: runs the pairwise tasks (default :func:`serial_map`).
    """
    if len(scans) < 2:
        raise InputError("merge needs at least two scans")
    if pairs is not None and pairs not in PAIR_MODES:
        raise InputError(f"pairs must be one of {', '.join(PAIR_MODES)}, got {pairs!r}")
    t0 = time.perf_counter()
    say = progress or (lambda _msg: None)
    run = map_tasks or serial_map
    config = config or Config(method="hybrid", problem=ProblemConfig(rotation_uncertainty_deg=25.0))
    config.validate()
    have_init = initial is not None or all(s.guess is not None for s in scans)
    if initial is None:
        initial = [s.guess for s in scans] if have_init else [np.eye(4) for _ in scans]
    if len(initial) != len(scans):
        raise InputError(f"{len(initial)} initial poses for {len(scans)} scans")
    mode = pairs or ("init" if have_init else "chain")
    chain = not have_init  # no initial poses: chain from the identity, no loop closure to test
    shared = Shared(_token(scans, config), tuple(scan_arrays(s) for s in scans), config)
    rel = lambda i, j: invert(initial[i]) @ initial[j]  # noqa: E731
    n = len(scans)
    if chain:
        if mode != "chain":
            raise InputError(f"pairs={mode!r} needs initial poses (--init, or stored guesses)")
        # consecutive scans from the identity; checked up front, so that a scan that overlaps its
        # neighbour nowhere is refused before any registration runs
        say(f"measuring the overlap of {n - 1} consecutive pairs")
        fracs = run(overlap_task, [(i, i + 1, np.eye(4)) for i in range(n - 1)], shared)
        gaps = [f"{scans[i].name} and {scans[i + 1].name}" for i, f in zip(range(n - 1), fracs) if f <= 0]
        if gaps:
            raise InputError(f"{'; '.join(gaps)} do not overlap from the identity; give initial poses (--init)")
        candidates = [(i, i + 1, f) for i, f in zip(range(n - 1), fracs)]
    else:
        if mode == "chain":
            items = [(i, i + 1) for i in range(n - 1)] + ([(0, n - 1)] if n > 2 else [])
        else:
            items = [(i, j) for i in range(n) for j in range(i + 1, n)]
        say(f"measuring the overlap of {len(items)} pairs under the initial poses")
        fracs = run(overlap_task, [(i, j, rel(i, j)) for i, j in items], shared)
        overlaps = [(i, j, f) for (i, j), f in zip(items, fracs)]
        candidates = _choose(overlaps, n, mode)
    linked = {k for i, j, _ in candidates for k in (i, j)}
    alone = [scans[k].name for k in range(n) if k not in linked]
    if alone:
        raise InputError(f"{', '.join(alone)} overlap(s) no other scan under the initial poses; "
                         "give better initial poses (--init) or leave it out")
    overlap_seconds = time.perf_counter() - t0
    groups = _components(n, candidates)
    if len(groups) > 1:
        listed = "; ".join(", ".join(scans[k].name for k in g) for g in groups)
        raise InputError(f"the overlapping pairs form {len(groups)} separate groups ({listed}); "
                         "give better initial poses (--init)")
    say(f"registering {len(candidates)} pairs")
    out = run(pair_task, [(i, j, rel(i, j)) for i, j, _ in candidates], shared)
    results = [PairResult(i, j, T, err, frac, sec) for (i, j, frac), (T, err, sec) in zip(candidates, out)]
    pair_seconds = time.perf_counter() - t0
    if not chain:  # a chain from the identity has no pair to spare
        results = _drop_outliers(results, n)
    poses, rejected = solve_pose_graph(n, [p for p in results if p.status == "used"], initial, chain, scans)
    results = [replace(p, status="rejected") if (p.i, p.j) in rejected else p for p in results]
    model = None
    if build_model:
        say("fusing the registered scans into one model")
        model = fuse(scans, poses)
    return MergeResult(poses, results, model, time.perf_counter() - t0, pair_seconds, overlap_seconds, mode)


def _choose(overlaps: list, n: int, mode: str) -> list:
    """Candidate pairs (i, j, overlap) from the measured overlaps."""
    floor = MIN_OVERLAP_ANY if mode == "chain" else MIN_OVERLAP
    candidates = [c for c in overlaps if c[2] >= floor]
    if mode == "init":
        # a pair both of whose scans count the other among their best partners (the union where that
        # leaves separate groups): a scan seen from behind can look overlapping near its silhouette
        # (12-stop turntable: 48 % "overlap" at 180 degrees, ranked 4th by the far scan alone)
        best = {k: {c[:2] for c in sorted((c for c in candidates if k in c[:2]), key=lambda c: -c[2])[:MAX_PARTNERS]}
                for k in range(n)}
        mutual = [c for c in candidates if c[:2] in best[c[0]] and c[:2] in best[c[1]]]
        either = [c for c in candidates if c[:2] in best[c[0]] or c[:2] in best[c[1]]]
        candidates = mutual if len(_components(n, mutual)) == 1 else either
    # A scan whose every overlap looks small under rough poses still gets its best partner.
    for k in range(n):
        if not any(k in c[:2] for c in candidates):
            mine = [c for c in overlaps if k in c[:2]]
            best = max(mine, key=lambda c: c[2]) if mine else None
            if best is not None and best[2] >= MIN_OVERLAP_ANY:
                candidates.append(best)
    return sorted(candidates, key=lambda c: c[:2])


def _components(n: int, pairs: list) -> list[list[int]]:
    """Connected groups of scan indices under the pairs (i, j, ...)."""
    parent = list(range(n))

    def root(k):
        while parent[k] != k:
            k = parent[k]
        return k

    for i, j, *_ in pairs:
        parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for k in range(n):
        groups.setdefault(root(k), []).append(k)
    return list(groups.values())


def _drop_outliers(pairs: list, n: int) -> list:
    """A pair whose final E is far above the others' did not find its partner surface: leave it out,
    unless that splits the scans into separate groups."""
    if len(pairs) < 3:
        return pairs
    median = float(np.median([p.error for p in pairs]))
    good = [(p.i, p.j) for p in pairs if p.error <= OUTLIER_PAIR * median]
    if len(_components(n, good)) > 1:
        return pairs
    return [p if p.error <= OUTLIER_PAIR * median else replace(p, status="dropped") for p in pairs]
