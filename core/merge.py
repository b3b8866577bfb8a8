"""A set of scans -> globally consistent poses -> one model (the paper's Fig. 2, for many views).

1. Poses to start from (``T_world_scan``): given (a Stanford .conf, or the scans' stored rough poses),
   each within the stated uncertainty (``stated``, a core.guess.Guess: rotation about the scan frame's origin,
   and translation); or none: no guess, every pair registered over all rotations and translations.
2. Round 1's pairs (:class:`MergeConfig` ``pairs``; core.merge_pairs): with poses that tell the scans
   apart, those that overlap under them ("init": each scan's best partners; "overlap": every
   overlapping pair; "chain": consecutive scans), measured for each scan's likeliest partners only;
   with none (or poses that do not tell the scans apart, e.g. every one the identity), every pair
   ("all") up to ``all_pairs_up_to`` scans, else each scan's likeliest neighbours by a cheap cue
   ("features": the share of mutually nearest FPFH features, core.merge_cue).
3. Each pair is registered by the ``global`` pipeline (core.register) in the pair's region: a relative
   guess between two poses each within R degrees and T units is within 2R and 2T, so the pair's region
   is twice the stated one (core.guess.Guess.between; no guess: rotation 180, translation unstated). Trusted pairs are polished.
   A pair's first registration stops after the candidates when none is trusted (no hybrid fallback:
   ``first_fallback_steps``), and no pair's search is bounded by time, only by its work
   (``pair_time_limit``): the campaign is the same on a busy machine, later. Pairs are
   independent tasks (core.merge_tasks), run by ``map_tasks`` (serially by default; app.distributed
   runs them on Dask), each with its own seed: the result does not depend on where.
4. The pose graph (core.posegraph, core.merge_graph) of the trusted pairs, less those whose E or
   misfit is far above the campaign's, keeps only pairs that close. A scan the kept pairs do not join
   to the reference is not placed (pose None): never placed wrong silently. (When the first scan's
   group is not the largest, the largest group is placed in its first scan's frame instead, and
   ``MergeResult.reference`` says which.) Nor is a scan joined only so loosely that its pose is in
   doubt: the uncertainty the graph propagates to it from the pairs' point-to-plane information (the
   errors of an open chain add up, a closed loop takes them down) must stay within the tolerance
   (core.merge_graph.drift).
5. Further rounds (core.merge_rounds), while they add pairs: every pair not used that overlaps under
   the poses found is registered again from the graph's pose (once) before it is given up; pairs that
   now overlap under the poses found are registered, those that match too little under them are not;
   groups of scans apart are joined by the pairs likeliest to join them (core.merge_groups: a
   turntable's order, the rough poses, the cue; to the placed scans and to each other), round after
   round until every pair that could join them was tried. Then the graph again.
6. The report (core.merge_report): every pair's status and why, every scan's placement and why not.
   :func:`core.fuse.fuse` builds one surface model from the placed scans. Poses are ``T_reference_scan``.
   Progress goes out as :class:`core.merge_progress.MergeProgress` events.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import Future
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from . import merge_graph, merge_pairs, merge_report, merge_rounds, merge_sequence
from .errors import InputError
from .fuse import FacingNormals, fuse
from .guess import Guess
from .merge_cue import NeighbourCue
from .merge_graph import Screened
from .merge_progress import Counter, MergeProgress, Step
from .merge_result import MergeResult, PairResult, PairStatus, Rejection, ScanReport, ScanStatus, Start
from .merge_tasks import (
    PairOutcome,
    PairTask,
    Shared,
    built,
    clear_geometry_cache,
    facing_normals,
    feature_task,
    pair_task,
    quality,
    scan_arrays,
    token,
)
from .posegraph import Edge, Graph, spanning_tree, tree_poses
from .problem import check_registrable
from .register import Config
from .scan import Scan
from .transforms import check_rigid, invert

__all__ = ["MergeConfig", "MergeProgress", "MergeResult", "PairResult", "PairStatus", "Rejection", "ScanReport",
           "ScanStatus", "Start", "Step", "clear_geometry_cache", "merge", "serial_map"]


@dataclass(frozen=True)
class MergeConfig:
    """The merge's own knobs (the registration's are ``core.register.Config``'s), each with what it was
    measured on."""

    pairs: str | None = None  # round 1's pairs (PAIR_MODES); None: "init" with poses, else "all" / "features"
    # a pair is registered when it overlaps by this share both ways under the initial poses ("init",
    # "overlap"), and found anew when its scans' points match by this share under the poses found; the
    # pair threshold trusts a pose only where >= 30 % of the source's sample matches (core.threshold), so
    # a pair below ~25 % is work for nothing (bunny crops: pairs matching 17-18 % at the truth untrusted)
    min_overlap: float = 0.25
    # below this a scan's best partner is no partner (a scan that overlaps nothing under its rough pose)
    min_overlap_any: float = 0.05
    # a pair whose region lets the source's centroid move by this share of the target's size has its
    # overlap also measured centroid on centroid (bunny, 15 deg about the frame's origin: 0.36; the
    # simulated turntable, whose sensor stands 700 mm from a 382 mm object: 1.5)
    align_from: float = 0.25
    # "init" keeps, per scan, its best partners by overlap: on a 24-stop turntable every scan overlaps
    # 10-11 others by >= 0.25 (measured, seed 1), and the far ones add work and wrong minima, not accuracy
    max_partners: int = 4
    # ... in round 1, half of them the pairs that overlap least while still by this (core.merge_pairs.
    # partners). Measured, the simulated turntable of 40 x 40 scans, frame starts: with the 4 best by
    # overlap (all within 2 stops) 500 stops 478 of 500 right, 22 drifted to 2.0-2.3 mm, and 100 stops
    # worst 0.611 deg / 1.2 mm; with half long links 500 stops 500 of 500 right (worst 0.504 deg /
    # 0.859 mm), 100 stops worst 0.455 deg / 0.463 mm
    long_overlap: float = 0.5
    # Polish: point-to-plane Gauss-Newton steps after a trusted pair. Measured (the hybrid's poses, 24
    # stops, seed 1, 15 pairs 15-30 deg apart), mean (max) rotation error: no polish 0.36 (1.27) deg;
    # gate 3 / 1.5 / 1 spacings: 0.15 / 0.055 / 0.059 deg (a wide gate lets in points beyond the
    # target's edge). On a smoother object: 1.92 (6.6) deg without, 0.16 / 0.11 / 0.11 deg with.
    polish_steps: int = 30
    polish_gate: float = 1.5  # point spacings
    # ... on at most about this many of the source's points (every k-th). Measured on a 10-stop turntable
    # pair of 40k-point scans, from 0.3 deg off: all 40,686 points 0.94 s CPU, 0.0107 deg off after;
    # 10,172 points 0.26 s, 0.0100 deg; 5,086 points 0.17 s, 0.0216 deg
    polish_points: int = 10000
    # a trusted pair whose E exceeds this many times the median of the trusted pairs' is not used.
    # Measured, right pairs: bunny 0.6-1.8e-8 (wrong minima >= 1e-6, untrusted); 10-stop turntable of
    # 40k-point scans 0.015-0.13 (8.6 x its median); 24-stop turntable, every family: none beyond 20 x
    outlier_error: float = 20.0
    # ... or whose misfit (the pair threshold's measure) exceeds this many times the trusted pairs' median:
    # the scans of one campaign share a sensor, so right pairs agree at much the same level. Measured,
    # right pairs over the median: 24-stop turntable (frame, identity) <= 1.44; the four bunny scans
    # (rough seed 0, no poses) <= 2.26; bunny crops <= 1.03. Wrong pairs the pair threshold trusted on
    # crops of the 24-stop turntable (misfit 2.5-3.4, right ones 0.3-0.7): >= 4.9. 3.3: their geometric mean.
    # Its limit: across scenes right pairs span 1.0-3.2 (core.threshold's evidence: bowl to bun315->bun045),
    # so a campaign of mostly clean pairs (median ~1) could lose a right pair with range bias (~3.4)
    outlier_misfit: float = 3.3
    # no guess: every pair is registered up to this many scans (15 pairs); beyond, the cue picks
    all_pairs_up_to: int = 6
    # no guess, more scans: each scan's best partners by the cue (15-stop turntable, seed 0: the best 2
    # by the share of mutually nearest FPFH features are within 2 stops for 28 of 30)
    cue_partners: int = 2
    # a group of scans no trusted pair joins to the first: pairs across to the placed scans, per round
    reach_partners: int = 3
    # ... of which by the cue, per scan of the group, its likeliest placed partners (core.merge_groups):
    # the pairs that could join it (15-stop turntable, seed 0: a scan's best 2 by the cue are within 2
    # stops for 28 of 30; 4 leaves room for a group whose neighbours' views differ from its own)
    join_partners: int = 4
    # rounds beyond max_rounds that only join groups, while pairs that could join them are left
    join_rounds: int = 6
    # overlaps are measured for each scan's likeliest partners only (core.merge_pairs.likeliest): on a
    # 24-stop turntable every scan overlaps 10-11 others by >= 0.25 (measured, seed 1)
    measure_partners: int = 12
    # ... and, in the round that takes the long links after the cue's round (no poses), this many: the graph's
    # poses are close by then, so the 12 likeliest lie within 6 stops of a 500-stop turntable (4.3 degrees) and
    # its long links with them. Measured, 500 stops of 40 x 40 scans from no poses: none (round 2 by the best
    # overlaps) 321 of 500 right, 179 drifted to 2.0-3.1 mm; long links among 12 partners 247 right, among 24
    # 423, among 48 500 of 500 (worst 0.616 deg / 1.56 mm, 93 s against 84 s)
    long_measure_partners: int = 48
    # hybrid steps after the candidates when a pair's first registration trusts none of them (None: the
    # registration config's own, 300 steps or 2.5 s); a campaign registers the pair again from the
    # graph's pose, or other pairs place its scans. Measured, the 24-stop turntable, seed 0, the
    # fallback's full bound: whole scans (frame, identity) 0 of 89 pairs trusted by the fallback; crops 0
    # (frame) 2 of 125, neither used by the graph, while its 56 untrusted pairs spent 91.8 s (1.6 s each,
    # trusted ones 0.40 s median)
    first_fallback_steps: int | None = 0
    # ... and a registration from a guess (not with no guess) ends at the first weakly pinned pose it refines
    # (core.candidates.CandidateConfig.end_on_weak): round 1's from the rough poses, and a later round's from the
    # graph's pose between scans it places (core.merge_rounds: again, fresh). The graph uses such a pose only where a
    # loop corroborates it (core.merge_graph.corroborate), and one not used is registered again, from the graph's pose
    # or as last asked with every stage, once. Measured, the 10-stop turntable of 40k-point scans (frame starts): 7 of
    # 20 pairs weakly pinned, each spending the whole work bound (3.4-6.1 s against 0.3-1.5 s for a trusted pair), 5
    # of the 7 ending at the first stage's pose anyway; its graph-pose retries then spent 1.9-2.4 s each with every
    # stage, and end at 0.54-0.55 s where a weakly pinned pose is refined (2026-12-06: 32.5 and 33.7 -> 30.0 and 31.7 s
    # the whole command, the same poses). The 24-stop turntable's crops 0 (axis starts): of the weakly pinned poses it
    # ended at, 11 of 12 from a guess were right (the 12th 3.3 deg off), 0 of 8 with no guess (80-164 deg off): hence
    # not with no guess. Not a group's join (core.merge_groups): it joins what the graph left apart, and may be a
    # group's one link (those crops, when joins ended there too: 11 placed against 14); nor in the last regular round
    # (max_rounds), after which no round could give it every stage. A sequence's later rounds too (its odometry and
    # loop pairs registered again from the graph's pose): the LiDAR and RGB-D drives of benchmarks/sequences.py as before
    guess_ends_on_weak: bool = True
    # the pairs' time bound (core.candidates.CandidateConfig.time_limit; None: none, the search bounded by
    # its work alone, so a busy machine gives the same campaign later, not another). Measured, the 8-stop
    # turntable of 48 x 48 scans with no poses at load 9.8: with the registration's 2.5 s, neighbour pairs
    # cut short, 6 of 8 scans placed in 61 s; with none, 8 of 8 in 31 s
    pair_time_limit: float | None = None
    # the region about the graph's pose (a pair registered again, or found under the poses found)
    found_rotation_deg: float = 5.0
    # a pair closes when its cycle's residual is within these (rotation; translation in point spacings)
    cycle_rotation_deg: float = 2.0
    cycle_translation: float = 4.0
    # a scan is placed only where drift_sigmas standard deviations of the uncertainty the graph propagates to it
    # (core.merge_graph.drift) lie within drift_rotation_deg and drift_translation x the campaign's size (the
    # reading of the issues' "right" for objects: 2 deg, and 2 mm of the 382 mm turntable object, 0.5 %; of the
    # 0.25 m bunny 0.8 %). Measured, the 24-stop turntable's crops 0 (seed 0, Open3D on one thread), every scan
    # the graph joined, its actual error over its standard deviation (the larger of rotation and translation):
    # no poses 13 scans, all right, at most 2.75; axis starts 17, all right, at most 3.25; frame starts 16, of
    # which 13 right (at most 3.1) and 3 off by 2.0-2.9 mm (2.6-3.1 sd: excluded from 2.35 sd up). Before the
    # graph optimised campaigns with scans left out (core.posegraph.optimise), up to 5.9. 3: the conventional
    # bound, above every wrong one's; it leaves no poses 13 / 0 / 11, axis 14 / 0 / 10, frame 9 / 0 / 15 (2.5
    # would keep 13 / 16 / 13 right, too near the wrong ones' 2.35 to be a rule). The whole scans (frame, axis,
    # no poses) keep 24 / 0 / 0 with a wide margin (3 sd 0.13-0.39 mm against 1.9), though there the error
    # reaches 5.0 sd (0.34 mm at 0.068 sd): the rule bounds what the loops show, not a pair's unseen bias
    drift_sigmas: float = 3.0
    drift_rotation_deg: float = 2.0
    drift_translation: float = 0.005
    max_rounds: int = 4
    # a sequence's loop candidates (core.merge_sequence): each frame's best this many by overlap under the
    # odometry's poses (the 5 shared Kinect frames: every frame overlaps every other; 2 closes a loop through
    # each frame without registering every pair)
    loop_partners: int = 2

    PAIR_MODES: ClassVar[tuple[str, ...]] = ("init", "overlap", "chain", "all", "features", "sequence")

    def validate(self) -> None:
        if self.pairs is not None and self.pairs not in self.PAIR_MODES:
            raise InputError(f"pairs must be one of {', '.join(self.PAIR_MODES)}, got {self.pairs!r}")
        if isinstance(self.long_measure_partners, int) and isinstance(self.measure_partners, int) \
                and self.long_measure_partners < self.measure_partners:
            raise InputError(f"long_measure_partners ({self.long_measure_partners}) must be at least measure_partners "
                             f"({self.measure_partners})")
        if not self.min_overlap <= self.long_overlap < 1:
            raise InputError(f"long_overlap must be in [min_overlap, 1), got {self.long_overlap}")
        if not 0 < self.min_overlap_any <= self.min_overlap < 1:
            raise InputError(f"overlaps must satisfy 0 < min_overlap_any <= min_overlap < 1, got "
                             f"{self.min_overlap_any} and {self.min_overlap}")
        for name in ("max_partners", "polish_steps", "polish_points", "all_pairs_up_to", "cue_partners", "reach_partners",
                     "max_rounds", "loop_partners", "join_partners", "join_rounds", "measure_partners",
                     "long_measure_partners", "first_fallback_steps"):
            v = getattr(self, name)
            low = 0 if name in ("polish_steps", "join_rounds", "first_fallback_steps") else 1
            if name == "first_fallback_steps" and v is None:
                continue
            if not isinstance(v, int) or isinstance(v, bool) or v < low:
                raise InputError(f"{name} must be a whole number >= {low}, got {v!r}")
        for name in ("polish_gate", "outlier_error", "outlier_misfit", "found_rotation_deg", "cycle_rotation_deg",
                     "cycle_translation", "align_from", "drift_sigmas", "drift_rotation_deg", "drift_translation"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a number > 0, got {v!r}")
        if not isinstance(self.guess_ends_on_weak, bool):
            raise InputError(f"guess_ends_on_weak must be True or False, got {self.guess_ends_on_weak!r}")
        if self.pair_time_limit is not None and not (np.isfinite(self.pair_time_limit) and self.pair_time_limit > 0):
            raise InputError(f"pair_time_limit must be > 0 seconds (or None: no bound), got {self.pair_time_limit!r}")
        if self.found_rotation_deg > 180 or self.cycle_rotation_deg > 180:
            raise InputError("rotations must be at most 180 degrees")


TaskMap = Callable[..., list]
"""``map_tasks(fn, items, shared, label=None, done=None) -> [fn(shared, item) for item in items]``, in
order, run anywhere; ``label`` names the work ("pairs, round 2"); ``done(count)``, when given, is called
as tasks finish with the count of this map's tasks finished so far."""


def serial_map(fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any, label: str | None = None,
               done: Callable[[int], None] | None = None) -> list:
    """The default :data:`TaskMap`: a plain loop in this process."""
    out = []
    for item in items:
        out.append(fn(shared, item))
        if done is not None:
            done(len(out))
    return out


def merge(scans: list[Scan], initial: list[np.ndarray] | None = None, config: Config | None = None,
          progress: Callable[[MergeProgress], None] | None = None, build_model: bool = True, pairs: str | None = None,
          map_tasks: TaskMap | None = None, settings: MergeConfig | None = None,
          stated: Guess | None = None) -> MergeResult:
    """Register and fuse ``scans`` (module notes). ``initial``: T_world_scan per scan (None: the scans'
    stored rough poses when all have one, else no guess); ``stated``: how far each initial pose may be off
    (core.guess: its rotation and translation uncertainty; its pose unused; None: the default; a pair's guess
    is :meth:`Guess.between` the two scans'); ``progress``: receives :class:`MergeProgress`
    events; ``pairs``: overrides ``settings.pairs``; ``map_tasks``: runs the tasks (default :func:`serial_map`)."""
    settings = settings or MergeConfig()
    if pairs is not None:
        settings = replace(settings, pairs=pairs)
    settings.validate()
    if len(scans) < 2:
        raise InputError("merge needs at least two scans")
    config = replace(config or Config(), method="global")
    config = replace(config, candidates=replace(config.candidates, time_limit=settings.pair_time_limit))
    config.validate()
    have = initial is not None or all(s.guess is not None for s in scans)
    if initial is None:
        initial = [s.guess for s in scans] if have else [np.eye(4) for _ in scans]
    if len(initial) != len(scans):
        raise InputError(f"{len(initial)} initial poses for {len(scans)} scans")
    check_registrable(*scans)  # up front: a scan no pair can use is bad input, not a scan "not placed"
    try:
        initial = [check_rigid(T, f"the initial pose of {s.name}") for T, s in zip(initial, scans)]
    except ValueError as exc:
        raise InputError(str(exc)) from None
    run = _Campaign(scans, initial, have, config, settings, progress or (lambda _event: None), map_tasks or serial_map,
                    stated or Guess.identity())
    return run.go(build_model)


class _Campaign:
    """One merge's state (the pairs registered so far, what was measured) and its rounds; each step of the
    method is a module of its own: pairs (core.merge_pairs), graph (core.merge_graph), rounds
    (core.merge_rounds), groups (core.merge_groups), report (core.merge_report)."""

    def __init__(self, scans: list[Scan], initial: list[np.ndarray], have: bool, config: Config,
                 settings: MergeConfig, say: Callable[[MergeProgress], None], run: TaskMap,
                 stated: Guess | None = None):
        self.scans, self.initial, self.have, self.config, self.mc, self.say, self.map = (
            scans, initial, have, config, settings, say, run)
        self.n = len(scans)
        stated = stated or Guess.identity()
        self.t0 = time.perf_counter()
        self.shared = Shared(token(scans, config), tuple(scan_arrays(s) for s in scans), config,
                             settings.polish_steps, settings.polish_gate, settings.polish_points, stated)
        self.spacing = float(np.median([s.spacing for s in scans]))
        self.centers = [s.centroid for s in scans]
        self.radius = [float(np.linalg.norm(s.points - s.centroid, axis=1).max()) for s in scans]
        self.pairs: dict[tuple[int, int], PairResult] = {}
        self.tried: dict[tuple[int, int], int] = {}  # registrations per pair
        self.tasks: dict[tuple[int, int], PairTask] = {}  # each pair's last registration, as asked
        self.weak_again: set[tuple[int, int]] = set()  # pairs tried again with every stage after a weakly pinned try
        self.long_links = False  # whether a round after the cue's chose long links (core.merge_rounds)
        self.cue = NeighbourCue(self.n, self._features)
        self.infos: dict[tuple[int, int, int], np.ndarray] = {}
        self.plane_infos: dict[tuple[int, int, int], np.ndarray] = {}  # point-to-plane, for the graph's uncertainty
        self.loose: dict[int, str] = {}  # scans joined but not placed: their pose too uncertain (core.merge_graph.drift)
        self.init_overlap: dict[tuple[int, int], float] = {}
        self.shares: dict[tuple[int, int], float] = {}  # matching share under the poses found (the last measured)
        self.skipped: set[tuple[int, int]] = set()  # pairs not registered: under the poses found they match too little
        self.join_left: dict[tuple, int] = {}  # per group of unplaced scans: the pairs that could join it, untried
        self.last: tuple[Graph, Screened] | None = None
        self.reference = 0  # the scan whose frame the poses are in
        self.t_pairs = self.t_overlap = 0.0
        self.round = 0
        self.registrations = 0
        self.counters = {step: Counter(step, self.say, self.t0) for step in Step}
        # each scan's initial pose: how far off it may be; a sequence's frames with no poses: the identity between
        # consecutive frames, within the stated region
        self.stated = stated if have or settings.pairs == "sequence" else Guess.none()
        self.mode = settings.pairs
        if not have and self.mode in ("init", "overlap"):
            raise InputError(f"pairs={self.mode!r} needs initial poses (--init, or stored rough poses)")
        if self.mode is None:
            # poses that do not tell the scans apart (every one the identity) choose no pairs: the cue does
            told = have and merge_pairs.informative(self, initial)
            self.mode = "init" if told else ("all" if self.n <= settings.all_pairs_up_to else "features")

    # ---- the rounds ----

    def go(self, build_model: bool) -> MergeResult:
        qualities = self._qualities_ahead() if build_model else None
        try:
            return self._go(qualities)
        finally:
            if qualities is not None:
                qualities[1].set()  # (a run that ended early: the scan under way is the last made)

    def _qualities_ahead(self) -> tuple[Future, threading.Event]:
        """Every scan's sample quality for the model (normals and spacings: no pose needed), made on a thread while
        the pairs are registered, which leave a core free for part of the time (the plain loop keeps ~1.3 of 2
        busy; under a cluster this process waits); the model waits for it. Stops after its scan under way once the
        event is set. A scan whose quality cannot be made is left to the model, which asks only for the placed.
        A daemon thread: a merge left running at the process's end (the page runs merges on daemon threads) does
        not hold the exit while its qualities are made."""
        stop, made = threading.Event(), Future()

        def make() -> None:
            try:
                for k in range(self.n):
                    if stop.is_set():
                        break
                    try:
                        self.sample_quality(k)
                    except Exception:  # noqa: BLE001 - made again where the model asks for it, and raised there
                        pass  # (a scan the graph does not place is never asked: its failure is no merge's)
            finally:
                made.set_result(None)  # the model never waits for a thread that has ended

        threading.Thread(target=make, name="qualities", daemon=True).start()
        return made, stop

    def _go(self, qualities: tuple[Future, threading.Event] | None) -> MergeResult:
        if self.mode == "sequence":
            tasks = merge_sequence.odometry_tasks(self)
        else:  # round 1's pairs from a guess end at a weakly pinned pose (MergeConfig.guess_ends_on_weak)
            weak = self.mc.guess_ends_on_weak
            tasks = [replace(t, end_on_weak=weak and t.start is not Start.NO_GUESS) for t in merge_pairs.first_tasks(self)]
        graph = None
        if not tasks:  # no pair overlaps under the poses: the scans apart are reached by the cue at once
            graph = self.graph()
            tasks = merge_rounds.next_tasks(self, *graph)
        last = self.mc.max_rounds + self.mc.join_rounds
        while tasks and self.round < last:
            self.round += 1
            self.register(tasks)
            graph = self.graph()
            tasks = []
            if self.mode == "sequence" and self.round == 1:  # odometry done: the loop candidates under its poses
                tasks = merge_sequence.loop_tasks(self, graph[0]) + merge_rounds.join_only(self, *graph)
            elif self.round < self.mc.max_rounds:
                tasks = merge_rounds.next_tasks(self, *graph)
            elif self.round < last:  # past the regular rounds: only the pairs that could join a group left apart
                tasks = merge_rounds.join_only(self, *graph)
        g, screened = graph or self.graph()
        # the final graph's scans it cannot vouch for are not placed (the rounds planned on every joined scan)
        g, screened = merge_graph.vouched(self, g, screened)
        pairs = merge_report.pair_statuses(self, g, screened)
        scans = merge_report.scan_reports(self, g, pairs)
        loops = merge_report.rings(self, g, screened)
        model = None
        if qualities is not None:
            qualities[0].result()  # (its error, if any, is raised here)
            placed = [k for k in range(self.n) if g.poses[k] is not None]
            self.note(Step.MODEL, f"fusing the {len(placed)} placed scans into one model")
            model = fuse([self.scans[k] for k in placed], [g.poses[k] for k in placed],
                         [built(self.shared, k)[1] for k in placed], qualities=[self.sample_quality(k) for k in placed])
        return MergeResult(list(g.poses), pairs, scans, model, time.perf_counter() - self.t0, self.t_pairs,
                           self.t_overlap, self.mode, self.round, self.registrations, self.reference,
                           rings=loops, skipped=len(self.skipped - set(self.pairs)),
                           forecasts=tuple(f for c in self.counters.values() for f in c.forecasts))

    def sample_quality(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Scan k's normals (N, 3) facing its sensor and sample quality (N,) (core.merge_tasks.quality: once in this
        process, shared with the tasks that ran here)."""
        return quality(self.shared, k)

    def normals(self, k: int) -> FacingNormals:
        """Scan k's normals facing its sensor, each worked out when first asked for (core.merge_tasks.facing_normals:
        once in this process, shared with the tasks that ran here)."""
        return facing_normals(self.shared, k)

    def region(self) -> tuple[float, float | None]:
        """A pair's region (degrees, units or None: unstated) from the stated per-scan one (module notes, step 3):
        the pair's guess between two scans' (core.guess.Guess.between)."""
        pair = Guess.between(self.stated, self.stated)
        return pair.rotation_deg, pair.translation

    def rel(self, i: int, j: int) -> np.ndarray:
        return invert(self.initial[i]) @ self.initial[j]

    def note(self, step: Step, text: str) -> None:
        """A progress event that says what a step does or found."""
        counter = self.counters[step]
        self.say(MergeProgress(step, self.round, counter.done, counter.total, time.perf_counter() - self.t0,
                               note=text))

    def measure(self, fn, items: list, step: Step) -> list:
        """``fn`` over ``items`` on the task map, counted as ``step`` (the time as overlaps and pairwise)."""
        t0 = time.perf_counter()
        done = self.counters[step].begin(len(items), self.round)
        label = f"{step}, round {self.round}" if self.round else str(step)
        out = self.map(fn, items, self.shared, label=label, done=done)
        dt = time.perf_counter() - t0
        if step is not Step.PAIRS:
            self.t_overlap += dt
        self.t_pairs += dt
        return out

    def register(self, tasks: list[PairTask]) -> None:
        self.note(Step.PAIRS, f"registering {len(tasks)} pairs")
        first = self.mc.first_fallback_steps
        tasks = [replace(t, fallback_steps=first) if t.attempt == 0 and first is not None else t for t in tasks]
        out = self.measure(pair_task, tasks, Step.PAIRS)
        # why each pair registered again was not used before: said from the results as they were, before
        # any of this round's changes them (the outlier test weighs every trusted pair's E)
        earlier = {(t.i, t.j): merge_report.reason_of(self, self.pairs[t.i, t.j]) for t in tasks
                   if (t.i, t.j) in self.pairs}
        for task, res in zip(tasks, out):
            k = (task.i, task.j)
            self.pairs[k] = self.result(task, res, earlier.get(k))
            self.tasks[k] = task
            self.tried[k] = self.tried.get(k, 0) + 1
        self.registrations += len(tasks)

    def result(self, task: PairTask, res: PairOutcome, earlier: str | None) -> PairResult:
        return PairResult(task.i, task.j, res.T, res.error, res.share, res.trusted, res.misfit, res.within_region,
                          res.seconds, self.round, task.start, earlier=earlier, stop=res.stop, failure=res.failure,
                          free=res.free, twin=res.twin)

    def _features(self) -> list[np.ndarray]:
        self.note(Step.FEATURES, f"computing the features of {self.n} scans (which scans are likely neighbours)")
        return self.measure(feature_task, list(range(self.n)), Step.FEATURES)

    def graph(self) -> tuple[Graph, Screened]:
        g, screened = merge_graph.build(self)
        self.last = (g, screened)
        self.note(Step.GRAPH, f"{len(g.kept)} of {len(self.pairs)} pairs used, {sum(g.placed)} of {self.n} scans placed")
        return g, screened

    def group_poses(self, inside: list[int]) -> list | None:
        """Poses of a group's scans among themselves (T_first_scan, None elsewhere), along a spanning tree
        of the usable pairs inside it that the last graph did not reject."""
        if self.last is None:
            return None
        g, screened = self.last
        members = set(inside)
        keys = [k for e, k in enumerate(screened.usable) if e not in g.rejected and set(k) <= members]
        es = [Edge(i, j, self.pairs[i, j].T_i_j) for i, j in keys]
        tree = spanning_tree(self.n, es, list(range(len(es))))
        return tree_poses(self.n, es, tree, inside[0])
