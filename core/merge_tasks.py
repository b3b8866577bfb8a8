"""The tasks of a merge (core.merge): plain numpy in, plain numpy out, so they run anywhere (this process
or a Dask worker; Open3D geometry does not pickle). What every task needs is one :class:`Shared` (the
scans as arrays and the config), sent once per worker; each process builds a scan's geometry once.

    overlap_task   the overlap of a pair under poses (frustum and visibility: core.problem)
    feature_task   a scan's FPFH features (the cue for which scans are neighbours when nothing is known)
    pair_task      one pair registered by the ``global`` pipeline (core.register) in a stated region, then
                   polished (point-to-plane) when trusted
"""

from __future__ import annotations

import hashlib
import threading
import time
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import InputError
from .frustum import frustum_of, visible_from
from .fuse import FacingNormals, sample_quality
from .guess import Guess
from .merge_result import Start
from .quiet import quiet_open3d
from .register import Config, register
from .result import Stop
from .scan import Scan
from .surface import Surface
from .threshold import Constraint
from .transforms import apply, from_params, invert, pose_error

FEATURE_VOXEL = 5.0  # FPFH voxel in point spacings: Open3D's recipe scale (~1/60 of a bunny scan)
OVERLAP_SAMPLE = 2000  # points of each scan an overlap is measured on (a share: +-1 % at 2000)
# The polish stops at a step this small (radians; units in point spacings). Measured, the 10-stop turntable of
# 40k-point scans (its 13 trusted pairs, 10k source points): the pose after 5 steps lies within 0.0007 deg of the
# 30th, after 8 within 0.00005; a step then jitters about 1e-6 rad as the correspondences shift, so a bound of
# 1e-7 rad ran all 30 steps (0.41 s a pair). 1e-5 rad is 0.0006 deg, a hundredth of the polish's own effect
POLISH_SETTLED_RAD = 1e-5
POLISH_SETTLED_SPACINGS = 1e-3
# A polish that moves the pose less than this (degrees; units in point spacings at the source's centroid) is taken
# as it is; a larger one only where the share of the pair matching (share_at) rises by more than POLISH_MORE_MATCHING
# after it (core.merge_tasks.polished). The small step alone was the rule until 2026-12-06: on the RGB-D drives
# (benchmarks/sequences.py, 16 depth frames at 0.4 m, seed 1) it refused the three largest polishes: 2-3 from 1.49
# deg / 3.0 cm off to 0.02 deg / 0.4 mm (share 0.501 -> 0.644), 2-4 from 0.56 deg / 3.9 cm to 0.04 deg / 0.3 mm
# (0.358 -> 0.435) and 1-3 from 1.02 to 0.04 deg (0.276 -> 0.285), and the graph used 2-3 and 1-3 as they were. Of
# 425 polishes recorded (RGB-D drives 0.1-0.4 m, four LiDAR street and room drives, the simulated turntable's three
# families and its crops from rough poses, the bunny campaigns) one other moved that far: a crop pair trusted 150 deg
# off, polished 9.3 deg further while less of it matched (0.502 -> 0.481; the graph did not use the pair). The 421
# small polishes changed the share by 0.015 at most (RGB-D; LiDAR rooms 0.009, the turntable, its crops and the bunny
# 0.006), whether the pose improved or not: a rise that small says nothing, so 1-3's (0.009) is refused too
# (benchmarks/polish_evidence.py).
POLISH_STEP_DEG = 1.0
POLISH_STEP_SPACINGS = 2.0
POLISH_MORE_MATCHING = 0.02


@dataclass(frozen=True, eq=False)
class Shared:
    """What every task needs, shipped once per worker: the scans as plain arrays, the registration
    config and the merge's polish knobs (steps, gate in point spacings, source points at most); ``stated``:
    the uncertainty stated for each scan's initial pose (core.guess; its pose unused)."""

    token: str  # identifies the scan set, for the per-process cache
    scans: tuple  # dicts from scan_arrays
    config: Config
    polish_steps: int = 30
    polish_gate: float = 1.5
    polish_points: int = 10000
    stated: Guess = field(default_factory=Guess.identity)


@dataclass(frozen=True, eq=False)
class PairTask:
    """Register scan j onto scan i from T0 (T_i_j guess) in the stated region (rotation_deg about the
    guess; translation in units, None: unstated); ``attempt`` numbers the registrations of this pair."""


    i: int
    j: int
    T0: np.ndarray
    rotation_deg: float
    translation: float | None
    attempt: int = 0
    start: Start = Start.ROUGH_POSES  # what the guess is, for the report
    fallback_steps: int | None = None  # the hybrid's steps when no candidate is trusted (None: the config's)
    end_on_weak: bool = False  # the search ends at a weakly pinned pose (core.candidates.CandidateConfig.end_on_weak)


@dataclass(frozen=True, eq=False)
class PairOutcome:
    """T: (4, 4) T_i_j found (polished when trusted); error: the registration's robust E (squared units), at
    its pose before the polish, which moves it by hundredths of a degree; trusted: the pair threshold's verdict;
    misfit: its measure (None: too little overlap to judge); within_region: inside the stated region;
    share: the smaller share of either scan lying within the polish gate of the other at T; stop: why
    the search stopped (the core's Stop; None: the registration refused the pair, ``failure`` says
    why); seconds: the task's wall time."""

    T: np.ndarray
    error: float
    trusted: bool
    misfit: float | None
    within_region: bool | None
    share: float
    stop: Stop | None
    seconds: float
    failure: str = ""
    free: Constraint | None = None  # not trusted and its overlap leaves a motion free at T: what it pins (core.threshold)
    found_by: str = ""  # the search's stage whose pose T is (core.result.GlobalDetails.found_by; "" when refused)
    twin: bool = False  # T puts points where the other's sensor looked through (core.result.Verdict.looked_through)


def verdict(res) -> tuple[bool, float | None, bool | None]:
    """(trusted, misfit, within_region) of a core Result: the one place a merge reads them."""
    v = res.verdict
    return bool(res.below_threshold), None if v is None else v.misfit, res.within_region


def scan_arrays(scan: Scan) -> dict:
    """A scan as plain numpy arrays and strings (picklable, cheap to ship)."""
    return scan.to_arrays()


def token(scans: list[Scan], config: Config) -> str:
    h = hashlib.sha1(repr(config).encode())
    for s in scans:
        h.update(s.name.encode())
        h.update(np.ascontiguousarray(s.points).tobytes())
    return h.hexdigest()


# per process: token -> {scan index: (Scan, Surface)}, {("normals", k): FacingNormals}, ..., the last used last
_BUILT: dict[str, dict] = {}
# Scan sets kept at once: a new merge frees the geometry of the least recently used beyond this. Two, so that two
# merges under way in one process (two of the workbench's tabs) do not free each other's scans at every task.
SCAN_SETS = 2
# one lock per value being made, so that two threads (a task, the qualities made ahead for the model) make it once
_MAKING: dict[tuple, threading.Lock] = {}
_MAKING_LOCK = threading.Lock()


def _once(shared: Shared, key, make):
    """The value at ``key`` of this scan set's cache, made by ``make()`` by the first thread to ask for it."""
    with _MAKING_LOCK:
        cache = _BUILT.pop(shared.token, None)
        if cache is None:
            cache = {}
            while len(_BUILT) >= SCAN_SETS:
                gone = next(iter(_BUILT))
                del _BUILT[gone]
                for k in [k for k in _MAKING if k[0] == gone]:
                    del _MAKING[k]
        _BUILT[shared.token] = cache  # the last used last
        if key in cache:
            return cache[key]
        lock = _MAKING.setdefault((shared.token, key), threading.Lock())
    with lock:
        if key not in cache:
            cache[key] = make()
    return cache[key]


def clear_geometry_cache() -> None:
    """Forget the scans built in this process (a benchmark's runs each start from none, as workers do)."""
    with _MAKING_LOCK:
        _BUILT.clear()
        _MAKING.clear()


def built(shared: Shared, k: int) -> tuple[Scan, Surface]:
    """Scan k rebuilt from its arrays, with its surface: built once per process, then reused. Every task
    starts here, so a worker's Open3D is quieted here too (core.quiet)."""
    quiet_open3d()

    def make() -> tuple[Scan, Surface]:
        scan = Scan.from_arrays(shared.scans[k])
        return scan, Surface.from_scan(scan)

    return _once(shared, k, make)


def quality(shared: Shared, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Scan k's normals (N, 3) facing its sensor and sample quality (N,) (core.fuse.sample_quality), once per
    process, for the model (~0.3 s a 40k-point scan, 1.3 s a Kinect frame); the rest ask :func:`facing_normals`."""
    return _once(shared, ("quality", k), lambda: sample_quality(built(shared, k)[0]))


def facing_normals(shared: Shared, k: int) -> FacingNormals:
    """Scan k's normals facing its sensor, each worked out once per process when first asked for (the polish, an
    overlap facing a sensor and a pair's information ask a few thousand of them; core.fuse.FacingNormals)."""
    return _once(shared, ("normals", k), lambda: FacingNormals(built(shared, k)[0]))


def pair_seed(seed: int, i: int, j: int, attempt: int = 0) -> int:
    """The seed of pair (i, j)'s registration number ``attempt``: independent of where and in which
    order the pairs run. Below 2**21: the global pipeline seeds Open3D's RANSAC with seed x 1000 + k,
    which Open3D takes as a 32-bit int."""
    key = [seed, i, j] if attempt == 0 else [seed, i, j, attempt]
    return int(np.random.SeedSequence(key).generate_state(1)[0] % 2**21)


def overlap_task(shared: Shared, item: tuple) -> float:
    """item (i, j, T_i_j[, facing]) -> the smaller of the two overlap shares under T_i_j: of a fixed sample
    of each scan's points (OVERLAP_SAMPLE), those inside the other's frustum and not hidden behind its
    surface by more than the stated uncertainty allows (core.cut's test on a sample: a ray per point
    over a whole 40k-point scan costs ~1 s a pair). ``facing``: instead of the rays, those whose normal
    (turned by T) faces the other's sensor: for poses known only roughly (a rotation within tens of
    degrees, the position not at all), where a surface the other sensor saw from behind must not count."""
    i, j, T_i_j, *rest = item
    facing = bool(rest and rest[0])
    pc = shared.config.problem
    fracs = []
    for a, b, T in ((j, i, T_i_j), (i, j, invert(T_i_j))):
        src, (tgt, surf) = built(shared, a)[0], built(shared, b)
        step = max(1, len(src.points) // OVERLAP_SAMPLE)
        pts = src.points[::step]
        moved = apply(T, pts)
        inside = frustum_of(tgt, pc.frustum).contains(moved)
        if facing:
            normals = facing_normals(shared, a)[::step] @ T[:3, :3].T
            inside &= np.einsum("ij,ij->i", normals, tgt.viewpoint - moved) > 0
        elif pc.visibility and inside.any():
            radius = float(np.linalg.norm(pts - pts.mean(0), axis=1).max())
            rotation, translation = shared.stated.uncertainty(tgt.size)
            margin = translation + rotation * radius
            inside[np.flatnonzero(inside)] = visible_from(surf, tgt.viewpoint, moved[inside], margin)
        fracs.append(float(inside.mean()))
    return min(fracs)


def feature_task(shared: Shared, k: int) -> np.ndarray:
    """(M, 33) float32 FPFH features of scan k on a voxel grid of FEATURE_VOXEL point spacings (Open3D's
    recipe: normals within 2 voxels, features within 5)."""
    import open3d as o3d

    scan = built(shared, k)[0]
    voxel = FEATURE_VOXEL * scan.spacing
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points)).voxel_down_sample(voxel)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    pcd.orient_normals_towards_camera_location(scan.viewpoint)
    reg = o3d.pipelines.registration
    f = reg.compute_fpfh_feature(pcd, o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100))
    return np.asarray(f.data, dtype=np.float32).T.copy()


def share_at(shared: Shared, i: int, j: int, T_i_j: np.ndarray, sample: int = 2000) -> float:
    """The smaller share of either scan's points (a fixed sample) within the polish gate of the other's
    points under T_i_j: how much of the pair matches (the pose graph's edge weight)."""
    (si, _), (sj, _) = built(shared, i), built(shared, j)
    gate = shared.polish_gate * max(si.spacing, sj.spacing)
    out = []
    for a, b, T in ((sj, si, T_i_j), (si, sj, invert(T_i_j))):
        step = max(1, len(a.points) // sample)
        d, _ = b.tree.query(apply(T, a.points[::step]), distance_upper_bound=gate)
        out.append(float(np.isfinite(d).mean()))
    return min(out)


def share_task(shared: Shared, item: tuple) -> float:
    """item (i, j, T_i_j) -> :func:`share_at`."""
    return share_at(shared, *item)


def pair_task(shared: Shared, task: PairTask) -> PairOutcome:
    """Scan j registered onto scan i by the global pipeline in the task's region; polished when trusted."""
    t0 = time.perf_counter()
    target, surface = built(shared, task.i)
    source = built(shared, task.j)[0]
    seed = pair_seed(shared.config.seed, task.i, task.j, task.attempt)
    guess = Guess(task.T0, task.rotation_deg, task.translation)
    config = replace(shared.config, method="global", seed=seed)
    if task.fallback_steps is not None:
        config = replace(config, candidates=replace(config.candidates, fallback_steps=task.fallback_steps))
    if task.end_on_weak:
        config = replace(config, candidates=replace(config.candidates, end_on_weak=True))
    try:
        res = register(source, target, guess, config, surface=surface)  # the target's, built once per process
    except InputError as exc:  # e.g. no overlap at the guess or at a candidate: a pair that did not register
        return PairOutcome(task.T0, float("inf"), False, None, None, 0.0, None, time.perf_counter() - t0,
                           failure=str(exc))
    trusted, misfit, within = verdict(res)
    T = polished(shared, task, res.transform) if trusted else res.transform
    v = res.verdict
    # free along a motion: weakly pinned, or slid along it through the other's seen space (Verdict.slid_through)
    free = (v.constraint if v is not None and not trusted and (not v.pinned or v.slid_through) and v.constraint.matched
            else None)
    return PairOutcome(T, float(res.error), trusted, misfit, within, share_at(shared, task.i, task.j, T),
                       res.stop, time.perf_counter() - t0, free=free, found_by=res.found_by,
                       twin=v is not None and v.looked_through)


def polished(shared: Shared, task: PairTask, T: np.ndarray) -> np.ndarray:
    """The trusted pose T (T_i_j) after :func:`polish`, when the polish only polishes: a small step, or a larger one
    after which clearly more of the pair matches (:func:`share_at`, by ``POLISH_MORE_MATCHING``); else T itself."""
    target, surface = built(shared, task.i)
    source = built(shared, task.j)[0]
    spacing = max(source.spacing, target.spacing)
    points = source.points[::max(1, len(source.points) // shared.polish_points)]
    P = polish(points, target, surface, facing_normals(shared, task.i), T, spacing, shared.polish_steps,
               shared.polish_gate)
    rot, move = pose_error(P, T, source.centroid)
    if rot < POLISH_STEP_DEG and move < POLISH_STEP_SPACINGS * spacing:
        return P
    return P if share_at(shared, task.i, task.j, P) > share_at(shared, task.i, task.j, T) + POLISH_MORE_MATCHING else T


def polish(points: np.ndarray, target: Scan, surface: Surface, normals: np.ndarray | FacingNormals, T: np.ndarray,
           spacing: float, steps: int = 30, gate: float = 1.5) -> np.ndarray:
    """Point-to-plane Gauss-Newton from T (T_target_source): points (N, 3) source frame, normals (Nt, 3)
    at the target's points (or its FacingNormals, asked for the matched ones only); ``steps`` at most,
    correspondences within ``gate`` point spacings. Returns the polished T; T itself if too few correspondences."""
    gate2 = (gate * spacing) ** 2
    for _ in range(steps):
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
        if np.linalg.norm(x[:3]) < POLISH_SETTLED_RAD and np.linalg.norm(x[3:]) < POLISH_SETTLED_SPACINGS * spacing:
            break
    return T
