"""A set of scans -> globally consistent poses -> one model (the paper's Fig. 2, for many views).

1. Poses to start from (``T_world_scan``): given (a Stanford .conf, or the scans' stored rough poses),
   each within the stated uncertainty (``Config.problem``: rotation about the scan frame's origin, and
   translation); or none: no guess, every pair registered over all rotations and translations.
2. Round 1's pairs (:class:`MergeConfig` ``pairs``): with poses, those that overlap under them
   ("init": each scan's best partners; "overlap": every overlapping pair; "chain": consecutive scans);
   with none, every pair ("all") up to ``all_pairs_up_to`` scans, else each scan's likeliest
   neighbours by a cheap cue ("features": the share of mutually nearest FPFH features).
3. Each pair is registered by the ``global`` pipeline (core.register) in the pair's region: a relative
   guess between two poses each within R degrees and T units is within 2R and 2T, so the pair's region
   is twice the stated one (no guess: rotation 180, translation unstated). Trusted pairs are polished.
   Pairs are independent tasks (core.merge_tasks), run by ``map_tasks`` (serially by default;
   app.distributed runs them on Dask), each with its own seed: the result does not depend on where.
4. The pose graph (core.posegraph) of the trusted pairs keeps only pairs that close; untrusted pairs
   weigh nothing, trusted ones their matching share over their misfit. A scan the kept pairs do not
   join to the first scan is not placed (pose None): never placed wrong silently. (When the first
   scan's group is not the largest, the largest group is placed in its first scan's frame instead,
   and ``MergeResult.reference`` says which.)
5. Further rounds, while they add pairs: every pair not used that overlaps under the poses found is
   registered again from the graph's pose (once) before it is given up; pairs that now overlap under
   the poses found are registered; a scan no trusted pair reaches tries its likeliest partners by the
   cue with no guess. Then the graph again.
6. :func:`core.fuse.fuse` builds one surface model from the placed scans. Poses are ``T_reference_scan``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from .errors import InputError
from .fuse import fuse
from .merge_cue import NeighbourCue
from .merge_result import MergeResult, PairResult, ScanReport
from .merge_tasks import (
    PairOutcome,
    PairTask,
    Shared,
    clear_geometry_cache,
    feature_task,
    overlap_task,
    pair_task,
    scan_arrays,
    share_task,
    token,
)
from .posegraph import Edge, Graph, Tolerance, components, information_matrix, solve
from .problem import check_registrable
from .region import Region
from .register import Config
from .scan import Scan
from .transforms import check_rigid, invert

__all__ = ["MergeConfig", "MergeResult", "PairResult", "ScanReport", "clear_geometry_cache", "merge", "serial_map"]


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
    # the region about the graph's pose (a pair registered again, or found under the poses found)
    found_rotation_deg: float = 5.0
    # a pair closes when its cycle's residual is within these (rotation; translation in point spacings)
    cycle_rotation_deg: float = 2.0
    cycle_translation: float = 4.0
    max_rounds: int = 4

    PAIR_MODES: ClassVar[tuple[str, ...]] = ("init", "overlap", "chain", "all", "features")

    def validate(self) -> None:
        if self.pairs is not None and self.pairs not in self.PAIR_MODES:
            raise InputError(f"pairs must be one of {', '.join(self.PAIR_MODES)}, got {self.pairs!r}")
        if not 0 < self.min_overlap_any <= self.min_overlap < 1:
            raise InputError(f"overlaps must satisfy 0 < min_overlap_any <= min_overlap < 1, got "
                             f"{self.min_overlap_any} and {self.min_overlap}")
        for name in ("max_partners", "polish_steps", "polish_points", "all_pairs_up_to", "cue_partners", "reach_partners",
                     "max_rounds"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < (0 if name == "polish_steps" else 1):
                raise InputError(f"{name} must be a whole number >= {0 if name == 'polish_steps' else 1}, got {v!r}")
        for name in ("polish_gate", "outlier_error", "outlier_misfit", "found_rotation_deg", "cycle_rotation_deg",
                     "cycle_translation", "align_from"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be a number > 0, got {v!r}")
        if self.found_rotation_deg > 180 or self.cycle_rotation_deg > 180:
            raise InputError("rotations must be at most 180 degrees")


TaskMap = Callable[..., list]
"""``map_tasks(fn, items, shared, label=None) -> [fn(shared, item) for item in items]``, in order, run
anywhere; ``label`` names the work for progress ("pairs, round 2")."""


def serial_map(fn: Callable[[Any, Any], Any], items: Sequence[Any], shared: Any, label: str | None = None) -> list:
    """The default :data:`TaskMap`: a plain loop in this process."""
    return [fn(shared, item) for item in items]


def merge(scans: list[Scan], initial: list[np.ndarray] | None = None, config: Config | None = None,
          progress: Callable[[str], None] | None = None, build_model: bool = True, pairs: str | None = None,
          map_tasks: TaskMap | None = None, settings: MergeConfig | None = None) -> MergeResult:
    """Register and fuse ``scans`` (module notes). ``initial``: T_world_scan per scan (None: the scans'
    stored rough poses when all have one, else no guess); ``config.problem``'s rotation and translation
    uncertainty: how far each initial pose may be off; ``pairs``: overrides ``settings.pairs``;
    ``map_tasks``: runs the tasks (default :func:`serial_map`)."""
    settings = settings or MergeConfig()
    if pairs is not None:
        settings = replace(settings, pairs=pairs)
    settings.validate()
    if len(scans) < 2:
        raise InputError("merge needs at least two scans")
    config = replace(config or Config(), method="global")
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
    run = _Campaign(scans, initial, have, config, settings,
                    progress or (lambda _msg: None), map_tasks or serial_map)
    return run.go(build_model)


class _Campaign:
    """One merge's state: the pairs registered so far and the graph of the trusted ones."""

    def __init__(self, scans, initial, have, config, settings, say, run):
        self.scans, self.initial, self.have, self.config, self.mc, self.say, self.map = (
            scans, initial, have, config, settings, say, run)
        self.n = len(scans)
        self.shared = Shared(token(scans, config), tuple(scan_arrays(s) for s in scans), config,
                             settings.polish_steps, settings.polish_gate, settings.polish_points)
        self.spacing = float(np.median([s.spacing for s in scans]))
        self.centers = [s.centroid for s in scans]
        self.radius = [float(np.linalg.norm(s.points - s.centroid, axis=1).max()) for s in scans]
        self.pairs: dict[tuple[int, int], PairResult] = {}
        self.tried: dict[tuple[int, int], int] = {}  # registrations per pair
        self.neighbours = NeighbourCue(self.n, self._features)
        self.infos: dict[tuple[int, int, int], np.ndarray] = {}
        self.init_overlap: dict[tuple[int, int], float] = {}
        self.shares: dict[tuple[int, int], float] = {}  # matching share under the poses found (the last measured)
        self.last_graph: Graph | None = None
        self.reference = 0  # the scan whose frame the poses are in
        self.t_pairs = self.t_overlap = 0.0
        self.round = 0
        self.registrations = 0
        pc = config.problem
        if have:
            self.stated = (pc.rotation_uncertainty_deg, pc.translation_uncertainty)
        else:
            self.stated = (180.0, None)
        self.mode = settings.pairs or ("init" if have else ("all" if self.n <= settings.all_pairs_up_to else "features"))
        if not have and self.mode in ("init", "overlap"):
            raise InputError(f"pairs={self.mode!r} needs initial poses (--init, or stored rough poses)")

    # ---- the rounds ----

    def go(self, build_model: bool) -> MergeResult:
        t0 = time.perf_counter()
        tasks = self.first_tasks()
        graph = None
        if not tasks:  # no pair overlaps under the poses: the scans apart are reached by the cue at once
            graph = self.graph()
            tasks = self.next_tasks(graph)
        while tasks and self.round < self.mc.max_rounds:
            self.round += 1
            self.register(tasks)
            graph = self.graph()
            if self.round < self.mc.max_rounds:
                tasks = self.next_tasks(graph)
        graph = graph or self.graph()
        pairs, scans = self.statuses(graph)
        model = None
        if build_model:
            placed = [k for k in range(self.n) if graph.poses[k] is not None]
            self.say(f"fusing the {len(placed)} placed scans into one model")
            model = fuse([self.scans[k] for k in placed], [graph.poses[k] for k in placed])
        return MergeResult(list(graph.poses), pairs, scans, model, time.perf_counter() - t0, self.t_pairs,
                           self.t_overlap, self.mode, self.round, self.registrations, self.reference)

    def region(self, scale: float = 2.0) -> tuple[float, float | None]:
        """A pair's region from the stated per-scan one (module notes, step 3). A translation not stated
        stays unstated, not doubled: the pair's default (a share of the target's size, core.region), to
        which the move the pair's rotation implies at the centroid is added."""
        rot, trans = self.stated
        return min(180.0, scale * rot), None if trans is None else scale * trans

    def rel(self, i: int, j: int) -> np.ndarray:
        return invert(self.initial[i]) @ self.initial[j]

    def first_tasks(self) -> list[PairTask]:
        n, mode = self.n, self.mode
        rot, trans = self.region()
        if mode == "all":
            chosen = [(i, j) for i in range(n) for j in range(i + 1, n)]
        elif mode == "chain":
            chosen = [(i, i + 1) for i in range(n - 1)] + ([(0, n - 1)] if n > 2 else [])
        elif mode == "features":
            chosen = self.cue_pairs()
        else:
            items = [(i, j) for i in range(n) for j in range(i + 1, n)]
            self.init_overlap = dict(zip(items, self.initial_overlaps(items)))
            chosen = [c[:2] for c in choose([(i, j, f) for (i, j), f in self.init_overlap.items()], n, mode, self.mc)]
        start = "rough poses" if self.have else "no guess"
        return [PairTask(i, j, self.rel(i, j), rot, trans, start=start) for i, j in chosen]

    def initial_overlaps(self, items: list[tuple[int, int]]) -> list[float]:
        """The overlap of each pair under the initial poses (core.merge_tasks.overlap_task)."""
        self.say(f"measuring the overlap of {len(items)} pairs under the initial poses")
        guesses = [self.rel(i, j) for i, j in items]
        # where the stated region lets a scan move by about its size at its centroid (a rotation about an
        # origin far from the scans: a sensor's, a turntable's), the rough poses say little about where it
        # lies: its overlap is also measured with its centroid on the partner's, counting the points that
        # face the partner's sensor (10-stop turntable, 15 deg about the sensor: round 1 then picks the
        # 20 pairs within 2 stops, all trusted; measured as given, 14 pairs of which 8 far apart)
        aligned = [k for k, ((i, j), T) in enumerate(zip(items, guesses)) if self.loose(i, j, T)]
        fracs = self.timed_map(overlap_task, [(i, j, T) for (i, j), T in zip(items, guesses)]
                               + [(*items[k], self.centred(*items[k], guesses[k]), True) for k in aligned], "overlaps")
        for m, k in enumerate(aligned):
            fracs[k] = max(fracs[k], fracs[len(items) + m])
        return fracs[:len(items)]

    def loose(self, i: int, j: int, T: np.ndarray) -> bool:
        """Whether pair (i, j)'s region (guess T_i_j) lets scan j's centroid move by align_from x scan i's size."""
        rot, trans = self.region()
        pc = replace(self.config.problem, rotation_uncertainty_deg=rot, translation_uncertainty=trans)
        return Region.stated(T, pc, self.scans[j], self.scans[i]).translation >= self.mc.align_from * self.scans[i].size

    def centred(self, i: int, j: int, T: np.ndarray) -> np.ndarray:
        """T_i_j moved so that scan j's centroid lands on scan i's."""
        out = T.copy()
        out[:3, 3] += self.centers[i] - (T[:3, :3] @ self.centers[j] + T[:3, 3])
        return out

    def register(self, tasks: list[PairTask]) -> None:
        t0 = time.perf_counter()
        self.say(f"round {self.round}: registering {len(tasks)} pairs")
        out = self.map(pair_task, tasks, self.shared, label=f"pairs, round {self.round}")
        # why each pair registered again was not used before: said from the results as they were, before
        # any of this round's changes them (the outlier test weighs every trusted pair's E)
        earlier = {(t.i, t.j): self.reason_of(self.pairs[t.i, t.j]) for t in tasks if (t.i, t.j) in self.pairs}
        for task, res in zip(tasks, out):
            key = (task.i, task.j)
            self.pairs[key] = self.result(task, res, earlier.get(key))
            self.tried[key] = self.tried.get(key, 0) + 1
        self.registrations += len(tasks)
        self.t_pairs += time.perf_counter() - t0

    def result(self, task: PairTask, res: PairOutcome, earlier: str | None) -> PairResult:
        return PairResult(task.i, task.j, res.T, res.error, res.share, res.trusted, res.misfit, res.within_region,
                          res.seconds, self.round, task.start, earlier=earlier, stop=res.stop)

    def _features(self) -> list[np.ndarray]:
        self.say(f"computing the features of {self.n} scans (which scans are likely neighbours)")
        return self.timed_map(feature_task, list(range(self.n)), "features")

    def timed_map(self, fn, items: list, label: str) -> list:
        t0 = time.perf_counter()
        out = self.map(fn, items, self.shared, label=label)
        dt = time.perf_counter() - t0
        self.t_overlap += dt
        self.t_pairs += dt
        return out

    # ---- the graph ----

    def usable(self) -> tuple[list[tuple[int, int]], dict[tuple[int, int], str]]:
        """The trusted pairs (keys) the graph may use, and why the others may not."""
        why: dict[tuple[int, int], str] = {}
        trusted = [k for k, p in self.pairs.items() if p.trusted]
        for k, p in self.pairs.items():
            if not p.trusted:
                why[k] = (p.stop if p.stop.startswith("not registered") else
                          "not trusted: too little of the pair overlaps to judge it" if p.misfit is None else
                          f"not trusted (misfit {p.misfit:.3g})")
        if len(trusted) >= 3:
            median = float(np.median([self.pairs[k].error for k in trusted]))
            misfits = [self.pairs[k].misfit for k in trusted if self.pairs[k].misfit is not None]
            typical = float(np.median(misfits)) if misfits else None
            for k in trusted:
                p = self.pairs[k]
                if p.error > self.mc.outlier_error * median:
                    why[k] = f"E far above the other trusted pairs' ({p.error / median:.3g} x their median)"
                elif typical and p.misfit is not None and p.misfit > self.mc.outlier_misfit * typical:
                    why[k] = (f"misfit far above the other trusted pairs' ({p.misfit:.3g}, {p.misfit / typical:.3g} x "
                              "their median)")
        return [k for k in trusted if k not in why], why

    def graph(self) -> Graph:
        keys, _ = self.usable()
        edges = []
        for i, j in keys:
            p = self.pairs[i, j]
            info_key = (i, j, self.tried[i, j])
            if info_key not in self.infos:
                self.infos[info_key] = information_matrix(self.scans[j].points, self.scans[i], 3 * self.spacing,
                                                          p.T_i_j)
            edges.append(Edge(i, j, p.T_i_j, weight(p), self.infos[info_key]))
        tol = Tolerance(self.mc.cycle_rotation_deg, self.mc.cycle_translation * self.spacing)
        g = solve(self.n, edges, self.centers, tol, 3 * self.spacing, self.config.seed)
        # the poses are the first scan's frame when its group is the largest; else the largest group's
        # (a first scan no trusted pair reaches leaves the others placed among themselves)
        label = _labels(self.n, [keys[k] for k in g.kept])
        size = {c: label.count(c) for c in set(label)}
        best = max(size.values())
        self.reference = 0 if size[label[0]] == best else min(k for k in range(self.n) if size[label[k]] == best)
        if self.reference != 0:
            g = solve(self.n, edges, self.centers, tol, 3 * self.spacing, self.config.seed, self.reference)
        self.last_graph, self.last_keys = g, keys
        self.say(f"pose graph: {len(g.kept)} of {len(self.pairs)} pairs used, {sum(g.placed)} of {self.n} scans placed")
        return g

    # ---- the next round ----

    def next_tasks(self, g: Graph) -> list[PairTask]:
        P, placed = g.poses, g.placed
        keys, _ = self.usable()
        used = {keys[k] for k in g.kept}
        found = self.mc.found_rotation_deg
        # pairs among placed scans: every pair not used (registered or not) that overlaps under the poses
        near = [(i, j) for i in range(self.n) for j in range(i + 1, self.n)
                if placed[i] and placed[j] and (i, j) not in used and self.close(P, i, j)]
        shares = self.timed_map(share_task, [(i, j, invert(P[i]) @ P[j]) for i, j in near], "overlaps") if near else []
        over = {(i, j): f for (i, j), f in zip(near, shares)}
        self.shares.update(over)
        tasks = []
        # not used, registered once, and overlapping under the poses found: again from the graph's pose,
        # before it is given up (a pair matching less than min_overlap cannot be trusted: the pair
        # threshold asks 30 % of the source's sample to match)
        for (i, j), f in over.items():
            if (i, j) in self.pairs and self.tried[i, j] == 1 and f >= self.mc.min_overlap:
                tasks.append(PairTask(i, j, invert(P[i]) @ P[j], found, None, attempt=1, start="graph pose"))
        # pairs that now overlap: each scan's best partners under the poses found, not registered yet
        fresh = [(i, j, f) for (i, j), f in over.items() if (i, j) not in self.pairs]
        for i, j, _ in choose(fresh + [(i, j, 1.0) for i, j in used], self.n, "init", self.mc):
            if (i, j) not in self.pairs and (i, j) in over:
                tasks.append(PairTask(i, j, invert(P[i]) @ P[j], found, None, start="graph pose"))
        # scans no trusted pair joins to the first: per group of them (joined among themselves, or alone),
        # the pairs across to the placed scans, by overlap under the rough poses (in their region), then
        # by the cue (no guess)
        label = _labels(self.n, [keys[k] for k in g.kept])
        rot, trans = self.region()
        for group in sorted({label[k] for k in range(self.n) if not placed[k]}):
            inside = [k for k in range(self.n) if label[k] == group]
            reach = [_key(u, m) for u in inside for m in range(self.n) if placed[m]]
            across = [c for c in reach if c not in self.pairs]
            rough = sorted((c for c in across if self.init_overlap.get(c, 0.0) >= self.mc.min_overlap_any),
                           key=lambda c: -self.init_overlap[c])
            # a pair tried only from the rough poses gets one try with no guess: a rough pose may be
            # further off than stated
            again = [c for c in reach if c in self.pairs and self.tried[c] == 1
                     and self.pairs[c].start == "rough poses" and not self.pairs[c].trusted]
            cue = sorted((c for c in across + again if c not in rough), key=lambda c: (-self.cue(*c), c))
            picks = [(c, True) for c in rough] + [(c, False) for c in cue]
            for (i, j), by_pose in picks[:self.mc.reach_partners]:
                tasks.append(PairTask(i, j, self.rel(i, j), rot if by_pose else 180.0, trans if by_pose else None,
                                      attempt=self.tried.get((i, j), 0),
                                      start="rough poses" if by_pose else "no guess"))
        return tasks

    def close(self, P: list, i: int, j: int) -> bool:
        """Whether scans i and j could overlap under poses P: their bounding spheres meet."""
        ci = P[i][:3, :3] @ self.centers[i] + P[i][:3, 3]
        cj = P[j][:3, :3] @ self.centers[j] + P[j][:3, 3]
        return float(np.linalg.norm(ci - cj)) < self.radius[i] + self.radius[j]

    # ---- the cue: which scans are likely neighbours when nothing is known ----

    def cue(self, i: int, j: int) -> float:
        """The share of mutually nearest FPFH features of scans i and j (higher: likelier neighbours)."""
        return self.neighbours.score(i, j)

    def cue_pairs(self) -> list[tuple[int, int]]:
        """Each scan's cue_partners best partners by the cue; joined into one group by the best links."""
        return self.neighbours.pairs(self.mc.cue_partners)

    # ---- the report ----

    def statuses(self, g: Graph) -> tuple[list[PairResult], list[ScanReport]]:
        keys, why = self.usable()
        index = {k: e for e, k in enumerate(keys)}
        out = []
        for key, p in sorted(self.pairs.items()):
            e = index.get(key)
            if key in why:
                status, reason = "rejected", why[key]
            elif e in g.rejected:
                status, reason = "rejected", g.rejected[e]
            elif g.poses[p.i] is None:
                status, reason = "rejected", (f"its scans are not joined to {self.scans[self.reference].name} "
                                              "(the frame of the poses) by used pairs")
            else:
                status, reason = "used", ""
            if status == "rejected" and self.tried[key] == 1 and self.shares.get(key, 1.0) < self.mc.min_overlap:
                reason += (f"; not registered again: under the poses found its scans match by "
                           f"{self.shares[key]:.0%}, too little to be trusted")
            out.append(replace(p, status=status, reason=reason, cycle=g.cycle.get(e) if e is not None else None))
        scans = []
        for k, s in enumerate(self.scans):
            trusted = tuple(sorted(p.j if p.i == k else p.i for p in out if p.trusted and k in (p.i, p.j)))
            placed = g.poses[k] is not None
            scans.append(ScanReport(s.name, placed, trusted, g.scan_cycle[k] if placed else None,
                                    "" if placed else self.why_not(k, out)))
        return out, scans

    def reason_of(self, p: PairResult) -> str:
        """Why pair p, as registered so far, is not used (it is about to be registered again)."""
        if not p.trusted:
            return "not trusted" + ("" if p.misfit is None else f" (misfit {p.misfit:.3g})")
        keys, why = self.usable()
        if (p.i, p.j) in why:
            return why[p.i, p.j]
        g = self.last_graph
        e = {k: m for m, k in enumerate(self.last_keys)}.get((p.i, p.j)) if g is not None else None
        return g.rejected.get(e, "not used") if e is not None else "not used"

    def why_not(self, k: int, pairs: list[PairResult]) -> str:
        mine = [p for p in pairs if k in (p.i, p.j)]
        if not mine:
            return "no pair with it was registered"
        trusted = [p for p in mine if p.trusted]
        if not trusted:
            return f"no trusted pair reaches it ({len(mine)} registered, none trusted)"
        return "its trusted pairs were rejected: " + "; ".join(
            f"with {self.scans[p.j if p.i == k else p.i].name}: {p.reason}" for p in trusted)


def weight(p: PairResult) -> float:
    """A trusted pair's weight in the pose graph's consensus: its matching share over its misfit (the pair
    threshold's, about 1 at the noise level), so a pair that fits at the noise level outweighs one the
    threshold passed near its bound (simulated turntable, crops: right pairs misfit 0.4-0.6, wrong ones
    the threshold trusted 1.8-4.4; bunny, right pairs 1.3-3.2)."""
    return max(p.overlap, 1e-3) / max(p.misfit if p.misfit is not None else 1.0, 0.25)


def choose(overlaps: list, n: int, mode: str, mc: MergeConfig) -> list:
    """Candidate pairs (i, j, overlap) from measured overlaps: "overlap" every pair above min_overlap;
    "init" each scan's max_partners best (both ways, or either where that leaves separate groups);
    "chain" as given above min_overlap_any. A scan left with none keeps its best above min_overlap_any."""
    floor = mc.min_overlap_any if mode == "chain" else mc.min_overlap
    candidates = [c for c in overlaps if c[2] >= floor]
    if mode == "init":
        # a pair both of whose scans count the other among their best partners (the union where that
        # leaves separate groups): a scan seen from behind can look overlapping near its silhouette
        # (12-stop turntable: 48 % "overlap" at 180 degrees, ranked 4th by the far scan alone)
        best = {k: {c[:2] for c in sorted((c for c in candidates if k in c[:2]), key=lambda c: -c[2])[:mc.max_partners]}
                for k in range(n)}
        mutual = [c for c in candidates if c[:2] in best[c[0]] and c[:2] in best[c[1]]]
        either = [c for c in candidates if c[:2] in best[c[0]] or c[:2] in best[c[1]]]
        candidates = mutual if len(set(_labels(n, [c[:2] for c in mutual]))) == 1 else either
    for k in range(n):
        if not any(k in c[:2] for c in candidates):
            mine = [c for c in overlaps if k in c[:2]]
            top = max(mine, key=lambda c: c[2]) if mine else None
            if top is not None and top[2] >= mc.min_overlap_any:
                candidates.append(top)
    return sorted(candidates, key=lambda c: c[:2])


def _key(a: int, b: int) -> tuple[int, int]:
    return (a, b) if a < b else (b, a)


def _labels(n: int, pairs) -> list[int]:
    return components(n, [tuple(p[:2]) for p in pairs])
