"""Where the global method's candidates come from, stage by stage, cheapest first (core.candidates,
core.kiss_matcher_candidates, Open3D's FPFH + RANSAC)."""

from __future__ import annotations

import atexit
import threading
import weakref
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from dataclasses import dataclass

import numpy as np

from ..candidates import FPFH_FINER_BELOW, feature_spacing, fpfh_candidates, rotation_candidates, voxel_cells
from ..intrusion import wide
from ..kiss_matcher_candidates import kiss_available, kiss_candidates
from ..scan import Scan, ScanKind
from .setup import Setup


@dataclass(frozen=True, eq=False)
class Hypotheses:
    """A stage's poses (each (4, 4) T_target_source), or why it has none (``why_none``); labels: where each
    pose came from ("guess", "kiss-matcher", ...), beside ``poses``."""

    poses: list
    why_none: str = ""
    labels: tuple = ()

    def label(self, k: int) -> str:
        return self.labels[k]

    def __add__(self, other: Hypotheses) -> Hypotheses:
        return Hypotheses(self.poses + other.poses, self.why_none or other.why_none, self.labels + other.labels)

    @property
    def source_note(self) -> int | str:
        """For the result's candidate sources: how many, or why none."""
        return self.why_none or len(self.poses)


def sampled(setup: Setup) -> Hypotheses:
    """The rotation samples within the region (core.candidates.rotation_candidates), shifted to fit."""
    cc, region = setup.config.candidates, setup.region
    if not cc.enabled:
        return Hypotheses([], "candidates off")
    poses = rotation_candidates(setup.source, setup.target, setup.T_guess, region.rotation + region.slack_rotation,
                                region.translation, cc.rotation_samples)
    poses = list(setup.basis.shift_to_fit(np.stack(poses))) if poses else []
    return Hypotheses(poses, labels=("rotation samples",) * len(poses))


def matched(setup: Setup, method: str, voxels: tuple[float, ...] | None = None,
            wanted: Callable[[], bool] = lambda: True) -> Hypotheses:
    """Feature-matching hypotheses of ``method`` ("fpfh-ransac" at ``voxels`` spacings, or "kiss-matcher", at
    ``voxels`` when given), wherever they lie (the region orders them, it drops none); ``wanted()`` is asked before
    each costly step, which is skipped once it says no (a stage made ahead for a search that has ended)."""
    cc, source, target = setup.config.candidates, setup.source, setup.target
    spacing = feature_spacing(source, target)
    if method == "fpfh-ransac":
        voxels = voxels or cc.fpfh_voxels
        poses = fpfh_candidates(source, target, spacing, voxels, cc.fpfh_seeds, setup.config.seed, wanted)
        return Hypotheses(poses, labels=(f"fpfh-ransac {max(voxels):g} spacings",) * len(poses))
    if not kiss_available():
        return Hypotheses([], "not installed (pip kiss-matcher; wheels for Python 3.11/3.12)")
    if voxels:
        poses, labels = [], []
        for v in voxels:
            if not wanted():
                break
            found = kiss_candidates(source, target, spacing, v)
            poses += found
            labels += [f"kiss-matcher {v:g} spacings"] * len(found)
        return Hypotheses(poses, "" if poses else "none found", tuple(labels))
    poses = setup.ahead.result() if setup.ahead is not None else kiss_candidates(source, target, spacing,
                                                                                   max(cc.fpfh_voxels))
    return Hypotheses(poses, labels=("kiss-matcher",) * len(poses))


@dataclass(frozen=True)
class Stage:
    """name; make: the stage's hypotheses; refine: how many of them (the best by score) ICP refines;
    start_free: its hypotheses ignore the guess (KISS-Matcher's other grids; FPFH + RANSAC, about the cost of the
    whole Open3D pipeline), so once a pose beyond the region is trusted it is skipped: it would give that pose again
    rather than one inside (on the TSDF rooms from the identity the other grids cost 0.5 s for that); doubted: called after
    a pose it refined that does not end the search (core.global_search.refinement.run_stage): later stages start
    ahead."""

    name: str
    make: Callable[[], Hypotheses]
    refine: int
    start_free: bool = False
    doubted: Callable[[], None] | None = None


def stages(setup: Setup) -> Iterator[Stage]:
    """The stages, cheapest first. A rotation stated within ``guess_first_deg``: the guess alone, then
    KISS-Matcher's one hypothesis (computed ahead, in its own process), then the rotation samples. A wider
    one: the guess and KISS-Matcher's hypothesis scored together (the lower refined first), then the
    samples. FPFH + RANSAC last: it costs about what the whole Open3D pipeline does. But with no guess, where either
    scan is a fused cloud, FPFH + RANSAC instead of the rotation samples: the samples place each turn by the
    centroids, which partly overlapping fragments of a room do not share. Measured (benchmarks/written_files.py, 24
    fused pairs from no guess; the sensor sweep's fragments family): no right pose came from them, but twins of a
    room's corner did (tsdf-13, whose truth FPFH found after them in 6.1-6.4 s, and without them in 3.3-3.7 s); the
    pairs nothing registers end 2-3 s sooner (tsdf-14 7.8-9.1 -> 5.4-6.2 s, walk15-1 7.0-7.4 -> 4.2-4.8 s), at the
    same poses; the sensor sweep's fragments family is bitwise as before. So too where either scan views a scene
    (:func:`scene`: a panorama, or a view 2 m across or more): each view's centroid lies on the walls it faced.
    Measured (2026-12-07): the sensor sweep with no guess (the shared LiDAR pair, the Kinect triples, the simulated
    streets and rooms: 13 starts, 16 registrations) took no pose from the rotation samples, and gives the same poses
    without them; the RGB-D drives of benchmarks/sequences.py registered 41 pairs with no guess whose best pose was a
    rotation sample's, none right (benchmarks/campaign_stages.py). A fused cloud of a scene skips the samples with a
    guess too (they turn about its centroid and move it toward the other's, as far as the guess's translation allows;
    a fused object keeps them: nothing was measured on one), FPFH +
    RANSAC coming after KISS-Matcher's grids: measured (2026-12-07) on the fused pairs of the sensor sweep, of
    benchmarks/held_out_sensors.py, slid_guesses.py and tsdf_modes.py (154 registrations with a guess), the samples
    ran in 17 and gave no trusted pose (the one best pose they gave, sim-fragments-0 at 5 deg, was wrong and doubted).
    Without them the same 154 end at the same verdicts and, but for that start, the same errors (as printed: 0.01 deg,
    1 mm); from the identity on
    the TSDF rooms (KISS-Matcher's pose trusted beyond the region, nothing inside it) 1-3 s sooner (tsdf-11 5.2-5.5 ->
    3.7-4.0 s, tsdf-14 6.4-7.5 -> 4.3-4.6 s), while sim-fragments-0's starts that nothing trusts now reach FPFH +
    RANSAC within the work bound and take 0.4-2 s longer. A scene's view that is not fused makes its FPFH +
    RANSAC in turn, not ahead, where KISS-Matcher's pose is scored with the guess (no guess, KISS-Matcher on): that
    stage starts nothing ahead. Where either scan is fused, KISS-Matcher on other
    grids follows its first pose (``kiss_grids``), before FPFH + RANSAC (with a guess, before the rotation samples
    where the cloud is an object's). Measured on the 10 TSDF fragment pairs of benchmarks/tsdf_modes.py
    (rooms 11-20; right: within 1 deg / 5 cm of the rigid fit nearest the cameras' poses) from the identity, 15, 30
    and 60 deg about the sensor and no guess: 44 -> 50 of 50 right and trusted (rooms 14 and 17 ended on 90-degree
    twins, doubted, from the identity, 60 deg and no guess), medians 1.5-2.3 -> 1.3-2.0 s about the sensor and with
    no guess. The other grids are
    made ahead (:class:`Ahead`, in KISS-Matcher's process) from when a pose of the stage holding KISS-Matcher's first
    is doubted, and FPFH + RANSAC too (on a thread: only its RANSAC lets this one run meanwhile): with no guess from
    when any pose of the first stage is doubted, with a guess (a fused cloud of a scene) with the other grids; both
    stop when the search ends. FPFH + RANSAC ahead with a guess, measured (2026-12-07) on the TSDF rooms of
    benchmarks/tsdf_modes.py: the same 50 verdicts, errors and finders; from the identity, alternating with the code
    before (3 runs each, load ~1.5), tsdf-13 (found by FPFH + RANSAC) 6.2 against 8.1 s, tsdf-14 and tsdf-17 (found by
    the other grids, the RANSAC made for nothing) 4.0 against 4.2 s and 5.2 against 5.2 s."""
    cc = setup.config.candidates
    kiss = cc.enabled and cc.kiss_matcher
    guess = Hypotheses([setup.T_guess], labels=("guess",))
    fused = cc.enabled and ScanKind.UNSTRUCTURED in (setup.source.kind, setup.target.kind)
    # FPFH + RANSAC instead of the rotation samples
    unplaced = cc.enabled and setup.guess.is_none and (fused or scene(setup.source) or scene(setup.target))
    fused_scene = fused and (scene(setup.source) or scene(setup.target))
    other = tuple(v for v in cc.kiss_grids if v != max(cc.fpfh_voxels))  # the first KISS-Matcher pose's grid
    grids = Ahead(lambda wanted: matched(setup, "kiss-matcher", other, wanted)) if fused and kiss and other else None
    ahead = (Ahead(lambda wanted: matched(setup, "fpfh-ransac", (max(cc.fpfh_voxels),), wanted))
             if unplaced or fused_scene else None)
    doubted = _starting(grids, ahead) if fused else None
    try:
        if setup.region.stated_rotation_deg > cc.guess_first_deg and kiss:
            yield Stage("guess, kiss-matcher", lambda: guess + matched(setup, "kiss-matcher"), 2, doubted=doubted)
        else:
            # (grids started while the guess is refined would hold KISS-Matcher's process from the next stage's pose)
            yield Stage("guess", lambda: guess, 1, doubted=_starting(ahead) if unplaced else None)
            if kiss:
                yield Stage("kiss-matcher", lambda: matched(setup, "kiss-matcher"), 1, doubted=doubted)
        if not cc.enabled:
            return
        if grids is not None:
            yield Stage("kiss-matcher, other grids", grids, 2, start_free=True, doubted=doubted)
        if unplaced:
            yield from fpfh_stages(setup, ahead)
            yield Stage("rotation samples", lambda: Hypotheses([], UNPLACED), 0)
            return
        if fused_scene:
            yield from fpfh_stages(setup, ahead)
            yield Stage("rotation samples", lambda: Hypotheses([], FUSED), 0)
            return
        yield Stage("rotation samples", lambda: sampled(setup), cc.refine)
        yield from fpfh_stages(setup)
    finally:  # the search has ended (or moved past them): what was started ahead stops at its next step
        for a in (grids, ahead):
            if a is not None:
                a.cancel()


# why a fused cloud or a scene's view with no guess gets no rotation samples (stages' notes)
UNPLACED = ("not run: with no guess the samples are placed by the centroids, which partly overlapping views of a "
            "scene or fragments do not share")
FUSED = ("not run: the samples are placed toward the centroids, which partly overlapping fragments of a scene do not "
         "share; a fused cloud of a scene gets FPFH + RANSAC instead")


def scene(scan: Scan) -> bool:
    """Whether ``scan`` views a scene rather than an object: a panorama, or a view whose bounding box's diagonal is at
    least SCENE_METRES in known units (core.intrusion.wide; the paper's corner and ribbed scenes, 2.7 m, are scenes,
    the bunny and the simulated turntable's object are not). Each view of a room or a street holds the walls it faced,
    so two views' centroids lie apart by about the scene's size, not by their motion."""
    return scan.kind is ScanKind.PANORAMA or wide(scan)


def fpfh_stages(setup: Setup, ahead: Ahead | None = None) -> Iterator[Stage]:
    """FPFH + RANSAC, the coarse grid first (``ahead``: its hypotheses, made ahead); a finer one only where the
    coarser left too few cells."""
    cc = setup.config.candidates
    coarser = None
    for v in sorted(cc.fpfh_voxels, reverse=True):  # coarse first: 5 spacings costs ~1/5 of 2 spacings
        if coarser is not None and not too_few_cells(setup, coarser):
            break  # the coarser grid held enough of both scans: a finer one adds cost, not poses
        make = ahead if ahead is not None and coarser is None else (lambda v=v: matched(setup, "fpfh-ransac", (v,)))
        yield Stage(f"fpfh-ransac {v:g} spacings", make, cc.fpfh_seeds, start_free=True)
        coarser = v


class Ahead:
    """A stage's hypotheses, made on a thread of their own from :meth:`start` on while the search refines the poses
    of the stages before: ``make(wanted)`` -> Hypotheses, asking ``wanted()`` before each costly step. The same
    hypotheses as made when the stage is reached (KISS-Matcher's process takes one request at a time; Open3D's RANSAC
    runs on one thread under its seed either way, core.threads). Called before :meth:`start`, it starts and waits.
    :meth:`cancel` (the search has ended) skips the steps not begun; the one under way (a RANSAC: ~1.2 s on a 300k
    fragment pair) runs to its end on the daemon thread, holding Open3D's thread count at one (:func:`wait_ahead`)."""

    def __init__(self, make: Callable[[Callable[[], bool]], Hypotheses]) -> None:
        self._make = make
        self._future: Future | None = None
        self._lock = threading.Lock()
        self._cancelled = threading.Event()
        self._in_turn = False

    def start(self) -> None:
        with self._lock:
            if self._future is not None:
                return
            self._future = Future()
        _STARTED.add(self)
        try:
            threading.Thread(target=self._run, name=AHEAD_THREAD, daemon=True).start()
        except RuntimeError:  # no thread to be had: made in turn, where the stage is reached
            with self._lock:
                self._future = None
                self._in_turn = True

    def cancel(self) -> None:
        self._cancelled.set()

    def _run(self) -> None:
        try:
            self._future.set_result(self._made())
        except BaseException as exc:  # handed to the search, which raises it where the stage is reached
            self._future.set_exception(exc)

    def _made(self) -> Hypotheses:
        hyp = self._make(lambda: not self._cancelled.is_set())
        return Hypotheses([], CANCELLED) if self._cancelled.is_set() else hyp

    def __call__(self) -> Hypotheses:
        if self._in_turn:
            return self._made()
        self.start()
        return self._made() if self._in_turn else self._future.result()


AHEAD_THREAD = "stage-ahead"
CANCELLED = "not made: the search had ended"


def wait_ahead() -> None:
    """Wait for the stages made ahead that are still under way (of searches that have ended: cancelled, each ends
    with its current step). For a benchmark that times runs one after another in one process, or runs a peer that
    uses Open3D's threads, after one of ours; and at the process's exit."""
    for t in threading.enumerate():
        if t.name == AHEAD_THREAD:
            t.join()


def _at_exit() -> None:
    """Every stage made ahead cancelled (a search left running on a daemon thread never cancels its own), then
    waited for: each ends with its step under way. Before Open3D's module is torn down: a RANSAC still under way
    then wrote Open3D's debug lines ("[Open3D DEBUG] Thread ...: registration fitness=...") to standard output after
    `register --json`'s result (TSDF room 17 with no guess, 2 runs of 2), and may crash. A step ends within ~1.2 s
    (one RANSAC)."""
    for a in list(_STARTED):
        a.cancel()
    wait_ahead()


_STARTED: weakref.WeakSet = weakref.WeakSet()  # the stages made ahead that were started (:func:`_at_exit`)
atexit.register(_at_exit)


def _starting(*aheads: Ahead | None) -> Callable[[], None]:
    """A call that starts each of ``aheads`` (None: none)."""

    def start() -> None:
        for a in aheads:
            if a is not None:
                a.start()

    return start


def too_few_cells(setup: Setup, voxel: float) -> bool:
    """Whether a grid of ``voxel`` point spacings leaves either scan fewer than FPFH_FINER_BELOW cells."""
    size = voxel * feature_spacing(setup.source, setup.target)
    return min(voxel_cells(setup.source, size), voxel_cells(setup.target, size)) < FPFH_FINER_BELOW


