"""Candidate poses beyond the guess, scored on one fixed basis (beyond the paper).

The paper's search starts from the guess and trusts the guess to lie in the true basin (section 2.1).
Before it, we gather poses to try: the guess; hypotheses from global feature matching (Open3D's FPFH
+ RANSAC at two voxel sizes and two seeds, and KISS-Matcher when installed); and a deterministic
sampling of rotations within the guess's stated rotation uncertainty (super-Fibonacci samples of
SO(3), Alexa 2022), each with the translation that best matches the scans' centroids within the
stated translation uncertainty (core.region). Every candidate is scored on one :class:`Basis`.

The basis: one seeded sample of the source's points and one fixed cap. Every candidate pays, per
sample point, its squared distance to the target surface capped at ``cap``; a point outside the
target's frustum pays the cap. So all candidates are scored on the same points with the same
weights (E normalised on each candidate's own overlap cut would favour a small flat patch), and a
candidate must overlap the other scan by at least ``min_overlap`` both ways.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import InputError
from .frustum import Frustum, frustum_of
from .icp import METRICS
from .noise import NORMAL_NEIGHBOURS, normal_floor
from .rows import first_in_cells
from .scan import Scan
from .surface import Surface, normal_angles, pca_normals
from .threads import open3d_one_thread
from .transforms import apply, invert

# The cap is (CAP_SPACINGS x the pair's point spacing)^2 + the pair's noise floor (core.noise). Measured
# (24 ICP minima from starts 20-120 deg off, per case; the score at the truth over the best wrong
# minimum's): caps of 25-100 x the floor (0.5-1 spacing on the bunny pairs and the bowl) rank the truth
# first on all five bunny pairs, the corner and the bowl; 3 spacings (400 x) ranks bowl minima 16-78 deg
# off below the truth (they cover more of the bowl), 9 x the floor leaves the bunny's truth half capped
# (a range bias between views). 0.7 spacing is ~50-65 x the floor on the bunny and the bowl.
CAP_SPACINGS = 0.7
SHIFT_STEPS = 3  # translation-only steps for each rotation sample (Basis.shift_to_fit) ...
SHIFT_POINTS = 48  # ... on this many of the basis's points (a translation is three numbers)
# the point-to-plane system that says whether a pose is pinned is built on this many source points
# (core.threshold.constraint: the basis's 160 leave a road's few poles and kerbs to chance)
CONSTRAINT_SAMPLE = 1500
# ... and its source normals fitted to this many points (as core.threshold.CONSTRAINT_NEIGHBOURS fits the target's)
CONSTRAINT_NORMAL_NEIGHBOURS = 30
RECENT_POSES = 8  # single poses a basis remembers its answers for (Basis.evaluate, normal_angle)
ROTATION_SAMPLES = 720  # super-Fibonacci samples over all of SO(3): neighbours ~15 deg apart
# RANSAC draws at most this many 3-match samples (Open3D's recipe: 100,000); it stops sooner at 0.999
# confidence, after log(0.001) / log(1 - w^3) draws when a share w of the mutual matches is right: 20,000
# serve w >= 0.07. Where nothing matches it never stops early: on the FPFH grid of 2 spacings the bunny's bun000
# against a mirrored bun045 (no rigid pose fits) takes 7.9 s at 20,000 draws and 29 s at 100,000 (2026-12-06).
RANSAC_ITERATIONS = 20_000
# ... but on the coarse grid (FEATURE_SPACINGS, the scene's voxel, as Open3D's recipe and the peers run it) the
# recipe's 100,000: a thin overlap leaves few right matches. Measured there: the TSDF fragments tsdf-13 (PLY, 23 %
# overlap) refine to the truth from the 100,000 draws' hypothesis and to a 99-degree twin from the 20,000's (three runs
# of 20,000 find the truth too); the cost 0.95 -> 1.29 s on that pair, 0.58 -> 1.18 s on a 15-frame walk, 0.24 -> 0.34 s on a
# room against a Kinect frame, 4.25 -> 3.75 s on the bunny against its mirror, 0.23 -> 0.22 s on bun000 -> bun045.
RANSAC_ITERATIONS_COARSE = 100_000
# cells of the coarser FPFH grid below which the finer grid is tried too: 5-spacing cells per scan,
# measured: the bunny scans 4.0-4.6k, their crops (app/crops.py) 1.1-2.3k; the simulated turntables'
# scans 115-277 (8 stops, 0.7-1.0k points) and 246-277 (24 stops, 1.7-1.9k points)
FPFH_FINER_BELOW = 500


@dataclass(frozen=True)
class WholeLegs:
    """The legs of ICP on the whole scans that make a thinned pair's pose (core.global_search: thinned; the legs:
    core.global_search.refinement.converge): each on a fresh ``sample`` of the converged cut (a new cut only where
    the pose left half the old one's assumed uncertainty: a cut of a 250k-point Kinect frame costs 0.3-0.4 s of CPU),
    each walking every step (core.icp: step_tolerance) until a step is under ``step_deg`` and ``step_spacings`` of
    the target's point spacings; the legs go on until one moves the pose less than ``settled_deg`` and
    ``settled_spacings``, ``legs`` at most. Not charged to the search's budget."""

    # Source points of the error on each leg (at least: the problem's own max_points when that is more): there the
    # pose's precision is made, and the minimum of E over 300
    # points of noisy depth is loose. Measured on the shared Kinect chain capture0001 -> 0002 -> 0003 from the legs'
    # poses (5 deg about the sensor, seed 0): legs of 300 points moved each pose a further 0.3-0.8 deg / 1-3 cm, each
    # time elsewhere (the chain 0.67-0.97 deg off); of 3000, a second and third leg moved them < 0.2 deg / 5 mm (the
    # chain 0.34-0.38 deg / 4-6 mm; 1000: 0.40-0.63 deg / 1-3 cm). With the legs walking every step the sample's own
    # noise shows: on the sensor sweep's Kinect family (42 chains: triples 1-2-3, 2-3-4, 3-4-5, every start) 3000
    # points closed 39 (the triple 2-3-4 at 0.66-1.10 deg), 6000 closed 41 (2-3-4 at 0.69-0.84 deg, the one miss a
    # wrong pose said "trust no"); the fragments family the same with 6000 (32 of 42, every miss sim-fragments-0,
    # which no peer gets either). One ICP iteration of 6000 queries costs ~20 ms.
    sample: int = 6000
    # When the legs stop. Measured on the shared Kinect frames from the pose found on the thinned frames, five sample
    # seeds, against where further legs settle (5 legs of 60 iterations): capture0002 -> 0001 from 15 deg: stopping
    # once a leg stays inside half the cut's uncertainty (1 deg, 1 % of the 3.9 m scene) ended a median 0.49 deg /
    # 5.7 cm (max 0.64 deg / 7.2 cm) away; this rule 0.06 deg / 5 mm (max 0.09 deg / 7.7 mm) in 2-6 legs; capture0003
    # -> 0001 and -> 0002 from 5 deg: 0.14 / 0.20 deg before, 0.08 / 0.19 deg (max 0.14 / 0.37) with it. A new cut
    # for every leg was as precise at 1.1-1.6 x the CPU; legs on the same sample stop where the first did (max 0.6
    # deg / 7 cm). (Measured with descent legs, before the walk below.)
    legs: int = 6
    settled_deg: float = 0.1
    settled_spacings: float = 2.0
    # When a leg's walk stops: the descent's steps creep near E's minimum on noisy depth (the notes in core.icp).
    # Measured on the shared Kinect triple capture0002-0003-0004 (each pair's pose from five starts, legs on one cut
    # of 10000 source points): stopped where a step was under 0.002 deg, the walk took 9-44 steps and the five
    # starts' ends lay within 0.08 deg of one another; 0.005 deg and 0.025 spacings (0.1 mm there) ended it in 2-38
    # steps, no farther from it than the sample's own noise (0.1-0.2 deg at 6000 points). The sensor sweep's Kinect
    # family: 41 of 42 chains close (38 with descent legs). Denser spinning LiDARs (64-128 rings, 114-131k points:
    # benchmarks/other_lidars.py) take this path too and land within 0.05 deg / 2 mm.
    # At 0.025 spacings (0.1 mm) a trace of the legs on capture0002 -> 0001 showed each leg's last 8-12 steps moving
    # the pose 0.06-0.16 mm a step all one way (a net 0.8-1.5 mm over a path of 0.9-1.6 mm): a steady creep, not a
    # settling, ended where one step happened to fall under 0.1 mm (18-19 steps a leg), while the next leg's fresh
    # sample moved the pose 0.6-1.0 mm at once. At 0.05 spacings (0.2 mm) the pose moved 1.7 mm and the pair took
    # 1.98 s against 2.42 s (2026-12-07); measured against 0.025 in one run each, the sensor sweep's Kinect family
    # (--runs 3) closed the same 41 of 42 chains (chain errors 0.18-0.86 deg either way, each within 0.17 deg of
    # before, the same 32 trusted, the same miss), its fragments family the same 38 of 42 with the same errors; the
    # denser LiDARs above 48 of 48 right, worst 0.050 deg / 2 mm.
    step_deg: float = 0.005
    step_spacings: float = 0.05

    def validate(self) -> None:
        if not (isinstance(self.sample, int) and self.sample >= 10):
            raise InputError(f"the whole scans' leg needs a whole number of at least 10 points, got {self.sample}")
        if not (isinstance(self.legs, int) and self.legs >= 1):
            raise InputError(f"the whole scans need a whole number of at least 1 leg, got {self.legs}")
        for name in ("settled_deg", "settled_spacings", "step_deg", "step_spacings"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"the whole scans' {name} must be > 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class CandidateConfig:
    """The ``global`` method's knobs (core.global_search): where candidates come from, how many are
    refined and how, and how long the search may go on when nothing is trusted."""

    enabled: bool = True
    sample: int = 160  # source points on the fixed basis (the paper's E: 165-341)
    min_overlap: float = 0.1  # share of each scan's sample that must fall in the other's frustum
    rotation_samples: int = ROTATION_SAMPLES  # over all of SO(3); those within the uncertainty are kept
    # FPFH voxel sizes in point spacings, coarse first; a finer one runs only when the coarser grid
    # leaves a scan fewer than FPFH_FINER_BELOW cells. Open3D's recipe uses 5 cm on scenes ~3 m across
    # (~1/60 of the size); 5 spacings is ~1/60 of a bunny scan. On 224 bunny sweep runs (5 whole and 27
    # crop pairs, four modes, 15 and 90 deg) the trusted poses came from the guess and KISS-Matcher (171),
    # the rotation samples (23), KISS-Matcher after them (23) and FPFH at 5 spacings (3): 2 spacings (~5 x
    # the cost, run in 4) added none. On sparse scans it does: the 8-stop simulated turntable from identity
    # poses (0.7-1.0k points a scan) has neighbour pairs trusted only through it.
    fpfh_voxels: tuple[float, ...] = (2.0, 5.0)
    fpfh_seeds: int = 1  # RANSAC runs per voxel size (one at 2 spacings costs ~ the Open3D peer's)
    kiss_matcher: bool = True  # use KISS-Matcher when it is installed
    # KISS-Matcher's grids (point spacings) tried after its one at the coarse FPFH voxel where either scan is a fused
    # cloud (core.global_search.stages: before FPFH + RANSAC with no guess, before the rotation samples with one).
    # Its hypothesis moves a lot with the grid on a room's fragments: on the 10 TSDF fragment pairs of
    # benchmarks/written_files.py (rooms 11-20, 300k points) the one at 5 spacings lay within 3 deg of the truth on 7;
    # on rooms 13 and 14 it gave none, on 17 it lay 21 deg off, while at 4 spacings 13's lay 5.4 and 17's 0.8 deg off,
    # at 8 14's 1.2 (chosen after looking at room 17). Each costs ~0.1-0.4 s in KISS-Matcher's process, RANSAC 1.2 s.
    # Measured on fused rooms only: other kinds keep their stages.
    kiss_grids: tuple[float, ...] = (4.0, 6.0, 8.0)
    refine: int = 3  # the best few by score, refined by ICP (besides the guess and every feature match)
    # the refinement's ICP step (core.icp METRICS): "plane" converges in several times fewer iterations
    # on the same robust E; "point" is the paper's Horn step
    refine_metric: str = "plane"
    # a refinement leg stops when its best E has not fallen for this many iterations (core.icp's patience).
    # Measured on the bunny sweep's starts (5 pairs, origin mode, 5-180 deg): right refinements reach their
    # best within 2-6 iterations of a leg's start and then at most cycle
    refine_patience: int = 8
    # ... and ends after this many at most: measured on 380 sweep runs (5 whole bunny pairs, 4 modes, 5-180
    # deg), a refinement the pair threshold trusted took 6-39 iterations over both its legs (median 19); one
    # from a wrong candidate crawls on to the cap, each step costly (its points lie off the surface)
    refine_iterations: int = 40
    # A candidate whose first ICP leg (on the cut at the candidate) leaves less than this share of the fixed basis
    # matched has settled nowhere: the legs on the converged cut at its pose (core.global_search.refinement.converge,
    # which assume the pose within 2 deg of where it settles) are not run, and it stays as that leg left it, never
    # trusted (a share at or above what trust asks, 0.3, would give up poses trust could take).
    # Measured (2026-12-07) on every refinement of the bunny sweep (100), its crop families (642), the sensor
    # sweep's LiDAR, Kinect, street, room and fragment families (156), benchmarks/other_lidars.py (112), the TSDF rooms
    # 11-20 from the identity, with no guess and 15 and 60 deg about the sensor (benchmarks/tsdf_modes.py's starts, 40),
    # the turntable's crop campaigns (3177) and the RGB-D drives (886): of the 160 points, the fewest matched after the
    # first leg by a refinement that then ended trusted or weakly pinned were 7 (bunny crops bun000-crop0 ->
    # bun045-crop0, which the legs took to 118), 8 and 14 (more bunny crops), 13 (bun315 -> bun045); 19 on the
    # turntable's crops, 43 on the sensor sweep, 50 on the TSDF rooms, 51 on the RGB-D drives, 95 on the other LiDARs.
    # Wrong candidates on the TSDF rooms leave 0-19 (half 3 or fewer), their legs 0.3-0.8 s each. So below 0.02 (3 of 160 or
    # fewer: next to nothing overlaps), which gives up as many of the TSDF rooms' wrong candidates as 0.03 would (13 of 26)
    # with a wider margin under the objects' crops (3 points against 7; the basis draws them, and a draw of 160 moves
    # a share of 7 by ~2.6). 0: every candidate gets its legs.
    settle_share: float = 0.02
    whole: WholeLegs = field(default_factory=WholeLegs)  # a thinned pair's legs on the whole scans
    normal_neighbours: int = NORMAL_NEIGHBOURS  # points a normal is fitted to (the pair threshold's angle)
    # The guess is refined alone first when its rotation is stated within this; a wider guess is scored
    # with KISS-Matcher's hypothesis first. Measured on the bunny sweep's starts only (the scenes have no
    # KISS-Matcher stage worth timing; it orders stages, success does not depend on it): the guess alone,
    # refined with the point-to-plane steps, is trusted at 5 and 15 deg, but from 30 deg about half of 20
    # starts fell through to the rotation samples: 0.81-4.11 s, median 1.22 (in process, files -> pose,
    # quiet); with KISS-Matcher scored beside the guess 0.93-1.53, median 1.01.
    guess_first_deg: float = 20.0
    refine_rotation_deg: float = 15.0  # a candidate's first overlap cut assumes it is this close (the samples' spacing)
    distinct_rotation_deg: float = 2.0  # candidates closer than this (and distinct_translation) are refined once
    distinct_translation: float = 0.01  # share of the target's size
    local_translation: float = 0.05  # the hybrid's translation uncertainty round the best candidate (share of size)
    # The search's bound on work (core.search.budget), counted from the end of the setup: a run ends the same on
    # every machine, however busy. Steps are ICP iterations and annealing moves over every refinement and the
    # fallback; a refinement takes at most 2 x refine_iterations (80), and the stages refine at most ~8 poses
    # (the guess, KISS-Matcher, 3 rotation samples, FPFH at two grids), so 1000 lets every stage run to its own
    # end and leaves the hybrid its share. A fused cloud's two poses of KISS-Matcher's other grids make that 10
    # with a guess: there the hybrid's share shrinks when every refinement runs to its cap. Candidates: the rotation
    # samples (at most ROTATION_SAMPLES) and the feature matches, so 2000 bounds only a config asking for more samples
    # than that.
    search_steps: int | None = 1000
    max_candidates: int | None = 2000
    # When no candidate is trusted the paper's hybrid searches round the best one, for at most this many of the
    # search's steps (None: until it stops by itself, as --method hybrid, or the search's steps are spent). In
    # the sweep it never turned an untrusted candidate into a trusted pose (0 of the runs that reached it); 300
    # steps cost ~0.3-1 s of CPU on the bunny
    fallback_steps: int | None = 300
    # End the search at the first refined pose inside the region that passes every test of the pair threshold but
    # the score's rise (core.threshold.PairThreshold.weakly_pinned), returning the best refined pose untrusted
    # (StopReason.WEAKLY_PINNED), as a trusted one ends it. Off for a pair alone; a campaign's registrations from a
    # guess (round 1's rough poses, a later round's graph pose) ask for it (core.merge.MergeConfig.guess_ends_on_weak):
    # its loops judge such a pose, which the later stages cannot (the 10-stop turntable of 40k-point scans: 7 of 20
    # pairs weakly pinned, each then spent the whole work bound, 3.4-6.1 s, and 5 of them came back to the first
    # stage's pose)
    end_on_weak: bool = False
    # Seconds of search at most, from the end of the setup (None: no bound on time; the default). A user's explicit
    # choice: a bound on time, not work, so a run that meets it may end otherwise on a slower or busier machine.
    time_limit: float | None = None

    def validate(self) -> None:
        if self.sample < 10:
            raise InputError(f"the candidate sample needs at least 10 points, got {self.sample}")
        if not 0 <= self.min_overlap < 1:
            raise InputError(f"min_overlap must be in [0, 1), got {self.min_overlap}")
        if self.rotation_samples < 0 or self.fpfh_seeds < 0 or self.refine < 1:
            raise InputError("rotation samples and FPFH seeds must be >= 0, refine >= 1")
        if self.refine_metric not in METRICS:
            raise InputError(f"the refinement's ICP metric must be one of {', '.join(METRICS)}, "
                             f"not {self.refine_metric!r}")
        if self.refine_iterations < 1:
            raise InputError(f"the refinement needs at least 1 iteration a leg, got {self.refine_iterations}")
        if not 0 <= self.settle_share < 1:
            raise InputError(f"settle_share must be a share of the basis in [0, 1), got {self.settle_share}")
        if self.refine_patience < 1:
            raise InputError(f"the refinement's patience must be at least 1 iteration, got {self.refine_patience}")
        self.whole.validate()
        if self.normal_neighbours < 3:
            raise InputError(f"a normal needs at least 3 neighbours, got {self.normal_neighbours}")
        if any(not v > 0 for v in self.fpfh_voxels):
            raise InputError(f"FPFH voxel sizes must be positive, got {self.fpfh_voxels}")
        if any(not (np.isfinite(v) and v > 0) for v in self.kiss_grids):
            raise InputError(f"KISS-Matcher's grids must be positive point spacings, got {self.kiss_grids}")
        for name in ("guess_first_deg", "refine_rotation_deg", "distinct_rotation_deg"):
            if not 0 < getattr(self, name) <= 180:
                raise InputError(f"{name} must be in (0, 180] degrees, got {getattr(self, name)}")
        for name in ("distinct_translation", "local_translation"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise InputError(f"{name} must be a share of the target's size > 0, got {getattr(self, name)}")
        for name in ("search_steps", "max_candidates"):
            if getattr(self, name) is not None and getattr(self, name) < 0:
                raise InputError(f"{name} must be >= 0 (or None: unbounded), got {getattr(self, name)}")
        if self.fallback_steps is not None and self.fallback_steps < 0:
            raise InputError(f"the fallback's steps must be >= 0 (or None: unbounded), got {self.fallback_steps}")
        if self.time_limit is not None and not (np.isfinite(self.time_limit) and self.time_limit > 0):
            raise InputError(f"the time limit must be > 0 seconds (or None: unbounded), got {self.time_limit}")



@dataclass(frozen=True, eq=False)
class Scores:
    """Per pose (P,): score (squared units, mean capped d^2 over the fixed sample), inside (share of
    the source sample in the target's frustum), reverse (share of the target sample in the source's),
    inlier_median (median d^2 of the points within the cap; the cap when none), inliers (their share
    of the sample)."""

    score: np.ndarray
    inside: np.ndarray
    reverse: np.ndarray
    inlier_median: np.ndarray
    inliers: np.ndarray


@dataclass(frozen=True, eq=False)
class Basis:
    """The fixed scoring basis of a pair: points (M, 3) source sample (source frame), target_points
    (K, 3) target sample (target frame), cap (squared units), the target surface, both frusta;
    normals (M, 3) the source's at its sample, fitted to ``neighbours`` points; the target scan (for
    its normals at closest points); angle_floor (degrees, core.noise.normal_floor over both samples)."""

    points: np.ndarray
    target_points: np.ndarray
    cap: float
    surface: Surface
    source_frustum: Frustum
    target_frustum: Frustum
    min_overlap: float
    normals: np.ndarray
    neighbours: int
    target: Scan
    angle_floor: float
    constraint_points: np.ndarray | None = None  # (C, 3) a larger seeded source sample (core.threshold.constraint)
    source: Scan | None = None  # the scan ``points`` were drawn from (for :attr:`constraint_normals`)
    # the last few single poses asked about (a pose found is scored, tested for trust and reported: the
    # same answers three times over), by the pose's bytes
    _recent: dict = field(default_factory=dict, init=False, repr=False)
    _lazy: dict = field(default_factory=dict, init=False, repr=False)  # what is made when first asked for

    def _remembered(self, what: str, T: np.ndarray, compute):
        key = (what, T.tobytes())
        if key not in self._recent:
            if len(self._recent) >= RECENT_POSES:
                del self._recent[next(iter(self._recent))]
            self._recent[key] = compute()
        return self._recent[key]

    def once(self, what: str, make: Callable[[], Any]) -> Any:
        """``make()``, made when first asked for ``what`` and kept (what a few poses' tests need: normals, hulls,
        samples)."""
        if what not in self._lazy:
            self._lazy[what] = make()
        return self._lazy[what]

    @property
    def constraint_normals(self) -> np.ndarray | None:
        """(C, 3) the source's unit normals at ``constraint_points``, fitted to CONSTRAINT_NORMAL_NEIGHBOURS points
        when first asked for (core.threshold.stable_rise: few poses need them); None without the source."""
        if self.source is None or self.constraint_points is None:
            return None
        src = self.source
        k = min(CONSTRAINT_NORMAL_NEIGHBOURS, len(src.points))
        return self.once("constraint normals", lambda: pca_normals(
            src.points, src.tree.query(self.constraint_points, k)[1].reshape(-1, k)))

    def evaluate(self, poses: np.ndarray) -> Scores:
        """Score (P, 4, 4) T_target_source poses; all closest points in one query."""
        poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
        if len(poses) == 1:
            return self._remembered("scores", poses, lambda: self._evaluate(poses))
        return self._evaluate(poses)

    def matches(self, poses: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P, M) squared distances of (M, 3) source ``points`` under (P, 4, 4) poses to the target surface (exact
        within the cap, inf beyond: every distance beyond it pays the cap, so only those need the exact query) and
        (P, M) bool: inside the target's frustum."""
        P, M = len(poses), len(points)
        moved = (np.einsum("pij,mj->pmi", poses[:, :3, :3], points) + poses[:, None, :3, 3]).reshape(-1, 3)
        d2 = self.surface.squared_distances_within(moved, float(np.sqrt(self.cap))).reshape(P, M)
        return d2, self.target_frustum.contains(moved).reshape(P, M)

    def _evaluate(self, poses: np.ndarray) -> Scores:
        P, M = len(poses), len(self.points)
        d2, inside = self.matches(poses, self.points)
        inv = np.array([invert(T) for T in poses])
        back = np.einsum("pij,mj->pmi", inv[:, :3, :3], self.target_points) + inv[:, None, :3, 3]
        reverse = self.source_frustum.contains(back.reshape(-1, 3)).reshape(P, -1).mean(1)
        capped = np.where(inside, np.minimum(d2, self.cap), self.cap)
        close = inside & (d2 < self.cap)
        n_close = close.sum(1)
        with np.errstate(all="ignore"):
            med = np.array([np.median(d2[k][close[k]]) if n_close[k] else self.cap for k in range(P)])
        return Scores(capped.mean(1), inside.mean(1), reverse, med, n_close / M)

    def normal_angle(self, T: np.ndarray) -> float:
        """Median angle (degrees) between the source sample's normals under pose T (4, 4) and the
        target's normals at their closest points, over the points that match (inside the target's
        frustum, within the cap); nan when fewer than 3 match. A pose that lays a surface on a
        different one (a twin sliding over itself) tilts them; a range bias between views does not."""
        T = np.asarray(T, dtype=np.float64).reshape(4, 4)
        return self._remembered("normal angle", T, lambda: self._normal_angle(T))

    def _normal_angle(self, T: np.ndarray) -> float:
        moved = self.points @ T[:3, :3].T + T[:3, 3]
        closest, d2 = self.surface.closest(moved)
        close = self.target_frustum.contains(moved) & (d2 < self.cap)
        k = min(self.neighbours, len(self.target.points))
        if close.sum() < 3 or k < 3:
            return float("nan")
        _, idx = self.target.tree.query(closest[close], k)
        return float(np.median(normal_angles(self.normals[close] @ T[:3, :3].T, pca_normals(self.target.points, idx))))

    def shift_to_fit(self, poses: np.ndarray, steps: int = SHIFT_STEPS) -> np.ndarray:
        """(P, 4, 4) poses, each translated so that its sample points meet the target surface: ``steps``
        translation-only ICP steps (the mean offset to the closest points of the better-fitting half),
        all poses in one query per step. A rotation sample placed by centroids alone lies centimetres
        off under partial overlap and pays the cap nearly everywhere; shifted, its score says something."""
        poses = np.array(poses, dtype=np.float64).reshape(-1, 4, 4)
        pts = self.points[:: max(1, len(self.points) // SHIFT_POINTS)]  # spread over the (sorted) sample
        P, M = len(poses), len(pts)
        for _ in range(steps):
            moved = np.einsum("pij,mj->pmi", poses[:, :3, :3], pts) + poses[:, None, :3, 3]
            closest, d2 = self.surface.closest(moved.reshape(-1, 3))
            d2 = d2.reshape(P, M)
            near = d2 <= np.median(d2, axis=1, keepdims=True)
            offset = ((closest.reshape(P, M, 3) - moved) * near[..., None]).sum(1) / near.sum(1)[:, None]
            poses[:, :3, 3] += offset
        return poses

    def valid(self, s: Scores) -> np.ndarray:
        """(P,) bool: at least ``min_overlap`` of the source sample matches the target surface (within
        the cap) and as much of the target sample falls in the source's frustum."""
        return (s.inliers >= self.min_overlap) & (s.reverse >= self.min_overlap)


def pair_spacing(source: Scan, target: Scan) -> float:
    return max(source.spacing, target.spacing)


# ---- the search sized to the scene ---------------------------------------------------------------------
# Feature grids (FPFH, KISS-Matcher) are sized in "feature spacings": the pair's point spacing, or, where the
# scene is far wider than its spacing, SCENE_SPAN_CELLS feature voxels of FEATURE_SPACINGS each across the
# scene's span, whichever is larger. The scene's span is sqrt(size x reach): the bounding box's diagonal times
# twice the median distance of the points from their median (a LiDAR frame's diagonal is set by a few far
# returns, its reach by the road round the sensor). Measured (5 feature spacings = the FPFH voxel):
#   bunny scans and their crops (app.crops): sqrt(size x reach) is 19-64 x 5 spacings: the spacing rules,
#     every voxel as before (the bunny's figures stay bit for bit)
#   the simulated scenes (corner, wing, bowl): 13-32 x: the spacing rules
#   the shared LiDAR street (69k points, spacing 12 mm, 95 m across): 0.29-0.33 m (5 spacings: 6 cm)
#   the shared Kinect frames (250k points, spacing 4 mm): 3.3-3.5 cm (Open3D's recipe for such rooms: 5 cm)
#   simulated streets 0.6 m, rooms 10 cm (LiDAR), RGB-D fragments 5 cm
FEATURE_SPACINGS = 5.0
SCENE_SPAN_CELLS = 80.0
SPAN_POINTS = 20_000  # the reach is a median: measured on an even spread of at most this many points


# A scan of more points than this is searched on a thinned copy (for_search) and the pose found refined on the
# whole scan: the setup's work (the surface, the noise floors, the overlap cut, the feature grids) grows with the
# points, the search's does not (its E uses max_points of them). The bunny's scans (30-40k points), the simulated
# scenes and the LiDAR frames (70k) are searched whole; a 250k-point Kinect frame or a 300k-point fragment thinned.
SEARCH_POINTS = 100_000


def for_search(scan: Scan, limit: int = SEARCH_POINTS) -> Scan:
    """``scan`` itself, or thinned to about ``limit`` points when it has more: a range grid keeps every k-th row
    and column (still a grid), other scans one point (the first, unmoved) per cell of a grid sized so that about
    ``limit`` cells are occupied. Deterministic; kind, viewpoint, pose and units kept."""
    from dataclasses import replace

    from .scan import RangeGrid

    n = len(scan.points)
    if n <= limit:
        return scan
    if scan.grid is not None:
        k = int(np.ceil(np.sqrt(n / limit)))
        index = scan.grid.index[::k, ::k]
        keep = index[index >= 0]
        remap = np.full(n, -1, dtype=np.int64)
        remap[keep] = np.arange(len(keep))
        grid = RangeGrid(np.where(index >= 0, remap[np.maximum(index, 0)], -1))
        return replace(scan, points=scan.points[keep], grid=grid, faces=None)
    cell = scan.spacing * np.sqrt(n / limit)
    for _ in range(6):  # a surface's cells grow as the square of their side: a few steps reach the count
        first = first_in_cells(np.floor((scan.points - scan.points.min(0)) / cell).astype(np.int64))
        if len(first) <= 1.2 * limit:
            break
        cell *= np.sqrt(len(first) / limit)
    return replace(scan, points=scan.points[np.sort(first)], grid=None, faces=None)


def scene_span(scan: Scan) -> float:
    """sqrt(bounding-box diagonal x reach) in units, reach = twice the median distance of the points from their
    median (on at most SPAN_POINTS of them, evenly spread)."""
    pts = scan.points[:: max(1, len(scan.points) // SPAN_POINTS)]
    reach = 2.0 * float(np.median(np.linalg.norm(pts - np.median(pts, axis=0), axis=1)))
    return float(np.sqrt(scan.size * reach))


def feature_spacing(source: Scan, target: Scan) -> float:
    """The unit the feature grids are sized in (units): the pair's point spacing, or 1 / (FEATURE_SPACINGS x
    SCENE_SPAN_CELLS) of the wider scan's span where that is larger (notes above)."""
    span = max(scene_span(source), scene_span(target)) / (FEATURE_SPACINGS * SCENE_SPAN_CELLS)
    spacing = pair_spacing(source, target)
    return spacing if spacing >= span else span


def scene_voxel(source: Scan, target: Scan) -> float:
    """The FPFH voxel of the pair (units): FEATURE_SPACINGS feature spacings (a room ~3-5 cm, a street ~0.3 m)."""
    return FEATURE_SPACINGS * feature_spacing(source, target)


def make_basis(source: Scan, target: Scan, surface: Surface, floor: float, rng: np.random.Generator,
               config: CandidateConfig = CandidateConfig(), frustum: str = "convex") -> Basis:
    """The pair's fixed basis: seeded samples of both scans, cap from spacing and noise floor."""
    src = source.points[np.sort(rng.choice(len(source.points), min(config.sample, len(source.points)), replace=False))]
    tgt = target.points[np.sort(rng.choice(len(target.points), min(config.sample, len(target.points)), replace=False))]
    cap = (CAP_SPACINGS * pair_spacing(source, target)) ** 2 + floor
    k = min(config.normal_neighbours, len(source.points))
    normals = pca_normals(source.points, source.tree.query(src, k)[1].reshape(len(src), k))
    # a scan too small to measure on (fewer than 2 x neighbours points) gives no floor, not a zero one
    floors = [f for f in (normal_floor(source, src, config.normal_neighbours),
                          normal_floor(target, tgt, config.normal_neighbours)) if f > 0]
    angle_floor = float(np.mean(floors)) if floors else 0.0
    # drawn from a generator of its own, so the draws above (and every score) stay as they were
    dense = np.random.default_rng([len(source.points), len(target.points), 6])
    n_dense = min(CONSTRAINT_SAMPLE, len(source.points))
    constraint_points = source.points[np.sort(dense.choice(len(source.points), n_dense, replace=False))]
    return Basis(src, tgt, float(cap), surface, frustum_of(source, frustum), frustum_of(target, frustum),
                 config.min_overlap, normals, config.normal_neighbours, target, angle_floor, constraint_points, source)


# ---- where candidates come from -------------------------------------------------------------------------
def super_fibonacci(n: int) -> np.ndarray:
    """(n, 3, 3) rotations spread evenly over SO(3) (Alexa, CVPR 2022), deterministic."""
    if n == 0:
        return np.zeros((0, 3, 3))
    from scipy.spatial.transform import Rotation

    phi, psi = np.sqrt(2.0), 1.533751168755204288118041
    s = np.arange(n) + 0.5
    r, R = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    a, b = 2 * np.pi * s / phi, 2 * np.pi * s / psi
    q = np.c_[r * np.sin(a), r * np.cos(a), R * np.sin(b), R * np.cos(b)]
    return Rotation.from_quat(q).as_matrix()


def rotation_candidates(source: Scan, target: Scan, T_guess: np.ndarray, rot_unc: float, trans_unc: float,
                        n: int) -> list[np.ndarray]:
    """Rotations from :func:`super_fibonacci` within ``rot_unc`` of the guess's, each about the source's
    centroid, placed so that the centroids match as nearly as the translation uncertainty allows."""
    c_src = source.centroid
    c_guess = apply(T_guess, c_src[None])[0]
    shift = target.centroid - c_guess
    norm = np.linalg.norm(shift)
    if norm > trans_unc:
        shift = shift * trans_unc / norm
    D = super_fibonacci(n)
    D = D[np.arccos(np.clip((np.trace(D, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)) <= rot_unc]
    T = np.zeros((len(D), 4, 4))
    T[:, 3, 3] = 1.0
    T[:, :3, :3] = D @ T_guess[:3, :3]
    T[:, :3, 3] = c_guess + shift - T[:, :3, :3] @ c_src
    return list(T)


def _o3d_cloud(scan: Scan, voxel: float):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points)).voxel_down_sample(voxel)
    # Open3D's global-registration recipe: normals within 2 voxels, FPFH within 5 (max 100 neighbours)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    pcd.orient_normals_towards_camera_location(scan.viewpoint)
    return pcd


def voxel_cells(scan: Scan, size: float) -> int:
    """How many cells of a grid of ``size`` (units) the scan's points occupy."""
    return len(first_in_cells(np.floor(scan.points / size).astype(np.int64)))


def ransac_iterations(voxel_spacings: float) -> int:
    """RANSAC's bound on draws on an FPFH grid of ``voxel_spacings`` feature spacings (notes above)."""
    return RANSAC_ITERATIONS_COARSE if voxel_spacings >= FEATURE_SPACINGS else RANSAC_ITERATIONS


def fpfh_candidates(source: Scan, target: Scan, spacing: float, voxels: tuple[float, ...], seeds: int,
                    seed: int, wanted: Callable[[], bool] = lambda: True) -> list[np.ndarray]:
    """RANSAC hypotheses on FPFH matches (Open3D's documented recipe, voxel sizes in point spacings:
    matches within 1.5 voxels, edge-length check 0.9, at most :func:`ransac_iterations` draws at 0.999 confidence);
    ``wanted()`` is asked before each grid's features and each RANSAC, which are skipped once it says no."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    out = []
    for v in voxels:
        if not wanted():
            break
        voxel = v * spacing
        src, tgt = _o3d_cloud(source, voxel), _o3d_cloud(target, voxel)
        param = o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
        fs, ft = reg.compute_fpfh_feature(src, param), reg.compute_fpfh_feature(tgt, param)
        dist = 1.5 * voxel
        for k in range(seeds):
            if not wanted():
                break
            with open3d_one_thread():  # repeatable only on one thread (core.threads)
                o3d.utility.random.seed(seed * 1000 + k)
                res = reg.registration_ransac_based_on_feature_matching(
                    src, tgt, fs, ft, True, dist, reg.TransformationEstimationPointToPoint(False), 3,
                    [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
                    reg.RANSACConvergenceCriteria(ransac_iterations(v), 0.999))
            out.append(np.asarray(res.transformation).copy())
    return out
