"""rangereg from Python: one call per pair, a staged path for many, the optimiser's events, campaigns.

    register(source, target, init)   one pair, start to result: what ``rangereg register`` runs
    prepare(scan)                    a scan's surface and its closest-point structure, built once, to
                                     register many scans onto it
    stream(source, target, init)     ``register``, yielding the optimiser's events as they happen
    legs(events)                     events grouped into the run's ICP and annealing legs (for plots)
    merge(scans)                     a campaign: every scan's pose and one fused model (``rangereg merge``)
    as_scan(data)                    any accepted input as a core Scan

A scan may be given as a file path (any format ``rangereg`` reads, ``site.e57#3``), an (N, 3) array of x y z
points, an ``open3d.geometry.PointCloud`` (or an ``open3d.t.geometry.PointCloud``), a
:class:`rangereg.core.scan.Scan`, or a :class:`Prepared` scan. Points of an array or a cloud are copied;
the inputs come back unmodified. A scan with no viewpoint (an array, a cloud, a file that stores none)
gets one estimated, as the CLI does; give it with ``viewpoint=`` (``viewpoint_source=``,
``viewpoint_target=``) when it is known.

The options are the CLI's settings (``rangereg.app.options.Settings``: one table of names, ranges and
defaults for the CLI, the page and this module) under their Python names, ``--rotation-uncertainty`` as
``rotation_uncertainty``. No ``init``, no rough poses stored with both scans and neither uncertainty
means no guess: the global method searches every rotation and translation, as on the command line.
"""

from __future__ import annotations

import difflib
import os
import queue
import re
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rangereg.app.options import Settings, parse_init, says_nothing, to_config, to_guess
from rangereg.core.errors import InputError
from rangereg.core.events import Cancelled, Event, Listener
from rangereg.core.scan import Origin, Scan, clean_points

if TYPE_CHECKING:
    from rangereg.core.config import Config
    from rangereg.core.guess import Guess
    from rangereg.core.merge import MergeResult
    from rangereg.core.merge_progress import MergeProgress
    from rangereg.core.result import Result
    from rangereg.core.surface import Surface

__all__ = ["Leg", "Prepared", "Stream", "as_scan", "legs", "merge", "prepare", "register", "stream"]

OPTIONS = tuple(f.name for f in fields(Settings))  # every name register() takes as an option


@dataclass(frozen=True, eq=False)
class Prepared:
    """A scan with its surface triangulated and the surface's closest-point structure (Open3D's
    RaycastingScene, the vertices' k-d tree) built, to register many scans onto it: each registration
    onto a prepared target skips that work. scan: the core Scan; surface: its core.surface.Surface;
    seconds: what preparing took (wall time)."""

    scan: Scan
    surface: Surface
    seconds: float

    def __repr__(self) -> str:
        return (f"Prepared({self.scan.name!r}, {len(self.scan.points)} points, {self.surface.n_triangles} triangles, "
                f"units={self.scan.units}, prepared in {self.seconds:.3f} s)")


def as_scan(data, viewpoint=None, *, name: str | None = None, units: str | None = None) -> Scan:
    """``data`` (a path, an (N, 3) array, an Open3D cloud, a Scan or a Prepared scan) as a core Scan.

    viewpoint: (3,) the sensor position in the scan's frame, overriding any stored or estimated one;
    name: the scan's name (default: the file's stem, else "scan"); units: the points' units (default: a
    sidecar's, else as ``rangereg`` guesses for a file, "unknown" for points). Raises InputError."""
    return _scan(data, viewpoint, name, units, name or "scan")


def prepare(data, viewpoint=None, *, name: str | None = None, units: str | None = None) -> Prepared:
    """Make ``data`` (as :func:`as_scan` takes it) ready to be registered onto, once: its surface and the
    surface's closest-point structure. ``register(frame, prepared)`` then pays only for the search."""
    from rangereg.core.problem import check_registrable
    from rangereg.core.surface import Surface

    if isinstance(data, Prepared) and viewpoint is None and name is None and units is None:
        return data
    t0 = time.perf_counter()
    scan = as_scan(data, viewpoint, name=name, units=units)
    check_registrable(scan)
    surface = Surface.from_scan(scan)
    surface.closest(scan.points[:1])  # builds the query structure now (else the first query does)
    for cached in ("spacing", "size", "centroid", "flatness"):  # asked by every registration onto it
        getattr(scan, cached)
    return Prepared(scan, surface, time.perf_counter() - t0)


def register(source, target, init=None, *, rotation_uncertainty: float | None = None,
             translation_uncertainty: float | None = None, method: str | None = None, seed: int = 0,
             viewpoint_source=None, viewpoint_target=None, listener: Listener | None = None, **options) -> Result:
    """Register ``source`` onto ``target``: the pose ``T_target_source`` (4, 4) that maps the source's points
    into the target's frame, as ``rangereg register SOURCE TARGET`` finds it with the same settings and seed.

    source, target: as :func:`as_scan` takes them (a :class:`Prepared` target skips its surface's making);
    init: the guess, a :class:`rangereg.Guess` (its pose T_target_source and how far off it may be), or its
    pose alone, a (4, 4) rigid matrix (or ``--init``'s text: 16 numbers or a file); None: the scans' stored
    rough poses when both have one, else none. rotation_uncertainty (degrees, about the scan frame's origin)
    and translation_uncertainty (the target's units): how far off a pose given alone may be; neither, and no
    guess: any pose. method: "global" (the default), "hybrid", "icp", "sa", "icp-restarts",
    "basin-hopping"; seed: every random choice. viewpoint_source, viewpoint_target: (3,) sensor positions.
    listener: called with every :class:`rangereg.core.events.Event` (ICP iteration, annealing move,
    candidate) as it happens; it may raise :class:`Cancelled` to stop (the result is then the best pose so
    far). options: the CLI's other settings by their Python names (threshold, max_points, frustum,
    t_start, t_min_ratio, cooling, icp_max_iterations, sa_max_evaluations, hops, restarts, recut_rounds,
    polish, coarse_to_fine, candidates, rotation_samples, full_search, time_limit, lock, no_guess).

    Returns a :class:`rangereg.core.result.Result`: ``T_target_source``, ``below_threshold`` (whether to trust it,
    every method: the CLI's "trust yes"), ``trust_text`` (why), ``verdict`` (the pair threshold's test at the pose;
    None where a paper method's E ended above its threshold), ``error`` and ``threshold`` (squared units),
    ``found_by``, ``within_region``, ``stop_text``,
    ``seconds`` (the search, from the scans in memory to the pose). Raises InputError for bad input."""
    from rangereg.core.register import register as core_register

    pair = _pair(source, target, init, viewpoint_source, viewpoint_target,
                 dict(options, rotation_uncertainty=rotation_uncertainty,
                      translation_uncertainty=translation_uncertainty, method=method, seed=seed))
    return core_register(pair.source, pair.target, pair.guess, pair.config, listener, surface=pair.surface)


def stream(source, target, init=None, **options) -> Stream:
    """:func:`register` (the same arguments, bar ``listener``) run on a thread of its own, its events
    yielded as they happen: ``for event in run: ...``, then ``run.result``. The inputs are checked here,
    before the run starts; leaving the loop early cancels the run (its result: the best pose so far)."""
    from rangereg.core.register import register as core_register

    if "listener" in options:
        raise InputError("stream: the events are what it yields; register(..., listener=) takes a callback")
    viewpoints = options.pop("viewpoint_source", None), options.pop("viewpoint_target", None)
    pair = _pair(source, target, init, *viewpoints, options)
    return Stream(lambda listener: core_register(pair.source, pair.target, pair.guess, pair.config, listener,
                                                 surface=pair.surface))


class Stream:
    """A registration running on its own thread: iterate over it (once) for its events; ``result``
    waits for the run and returns its Result (or raises what the run raised); ``cancel()`` stops it."""

    _END = object()

    def __init__(self, run: Callable[[Listener], object]):
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._stop = threading.Event()
        self._outcome: list = []
        self._iterated = False
        self._thread = threading.Thread(target=self._work, args=(run,), name="rangereg-stream", daemon=True)
        self._thread.start()

    def _listen(self, e: Event) -> None:
        if self._stop.is_set():
            raise Cancelled()
        self._events.put(e)

    def _work(self, run) -> None:
        try:
            self._outcome.append(("result", run(self._listen)))
        except BaseException as exc:  # handed to the caller by .result and by the loop
            self._outcome.append(("error", exc))
        finally:
            self._events.put(self._END)

    def __iter__(self) -> Iterator[Event]:
        if self._iterated:
            raise InputError("a stream's events are yielded once; run.result holds the outcome")
        self._iterated = True
        try:
            while (e := self._events.get()) is not self._END:
                yield e
        finally:
            if self._thread.is_alive():  # the loop was left early: stop the run
                self._stop.set()
        self._raise_error()

    def cancel(self) -> None:
        """Stop the run at its next event; ``result`` is then the best pose so far."""
        self._stop.set()

    @property
    def result(self):
        """The run's Result, once it has ended (waits for it)."""
        self._thread.join()
        self._raise_error()
        return self._outcome[0][1]

    def _raise_error(self) -> None:
        if self._outcome and self._outcome[0][0] == "error":
            raise self._outcome[0][1]

    def __repr__(self) -> str:
        return f"Stream({'running' if self._thread.is_alive() else 'ended'})"


@dataclass(frozen=True, eq=False)
class Leg:
    """One leg of a run: phase ("icp", "sa" or "candidates"), its number in the run (from 1), and per step
    its iteration in the run (K,), E (K,) (squared units), temperature (K,) (annealing; NaN elsewhere) and
    whether the move was accepted (K,); local_minimum: the leg ended in a local minimum above the threshold."""

    phase: str
    leg: int
    iterations: np.ndarray
    errors: np.ndarray
    temperatures: np.ndarray
    accepted: np.ndarray
    local_minimum: bool

    def __repr__(self) -> str:
        end = f", E {self.errors[0]:.4g} -> {self.errors[-1]:.4g}" if len(self.errors) else ""
        return (f"Leg({self.phase} {self.leg}: {len(self.iterations)} steps{end}"
                f"{', ended in a local minimum' if self.local_minimum else ''})")


def legs(events: Sequence[Event]) -> list[Leg]:
    """``events`` (in the order they came) grouped into the run's legs, in order: consecutive events of one
    phase and leg number. The markers are not steps: before a leg's first step (``phase_iteration`` 0), and
    where ICP stopped in a local minimum (``local_minimum``, the leg's last pose again: the leg's flag)."""
    out: list[Leg] = []
    group: list[Event] = []

    def close() -> None:
        steps = [e for e in group if e.phase_iteration > 0 and not e.local_minimum]
        out.append(Leg(group[0].phase, group[0].leg, np.array([e.iteration for e in steps], dtype=np.int64),
                       np.array([e.error for e in steps], dtype=np.float64),
                       np.array([np.nan if e.temperature is None else e.temperature for e in steps], dtype=np.float64),
                       np.array([e.accepted for e in steps], dtype=bool), any(e.local_minimum for e in group)))

    for e in events:
        if group and (e.phase, e.leg) != (group[0].phase, group[0].leg):
            close()
            group = []
        group.append(e)
    if group:
        close()
    return out


def merge(scans: Iterable, init=None, *, rotation_uncertainty: float | None = None,
          translation_uncertainty: float | None = None, seed: int = 0, pairs: str | None = None,
          workers: int | None = 1, scheduler: str | None = None, threads: int | None = None,
          progress: Callable[[MergeProgress], None] | None = None, build_model: bool = True) -> MergeResult:
    """Register a campaign of scans and fuse them, as ``rangereg merge`` does.

    scans: two or more, each as :func:`as_scan` takes it (a path to an E57 without ``#K`` brings all its
    scans; arrays and clouds are named scan0, scan1, ...); init: the initial poses T_world_scan, a list of
    (4, 4) (one per scan), a {name: (4, 4)} mapping or a Stanford ``.conf`` path; None: the scans' stored rough
    poses when every scan has one, else no guess (every pair over all rotations). rotation_uncertainty,
    translation_uncertainty: how far off each initial pose may be; pairs: round 1's pairs ("init", "overlap",
    "chain", "all", "features"); workers: 1 a plain loop here, N a local Dask cluster, None: the CLI's
    choice; scheduler: an existing Dask cluster (tcp://HOST:PORT); threads: per task stream; progress:
    called with each progress event (core.merge_progress.MergeProgress; str() of it is the CLI's line);
    build_model: fuse the placed scans into one mesh.

    Returns a :class:`rangereg.core.merge.MergeResult`: ``poses`` (T_reference_scan, None for a scan not
    placed), ``placed``, ``scans`` (each one's report), ``pairs``, ``model`` (the fused mesh). Raises InputError."""
    from types import SimpleNamespace

    from rangereg.app.commands.merge import stated_config
    from rangereg.app.distributed import TaskRunner
    from rangereg.core.io import load_conf, load_scans
    from rangereg.core.merge import merge as core_merge

    if isinstance(scans, (str, os.PathLike, np.ndarray)) or not hasattr(scans, "__iter__"):
        raise InputError("merge: expected a list of scans (paths, arrays, clouds or Scans)")
    loaded: list[Scan] = []
    for k, s in enumerate(scans):
        loaded += load_scans([s]) if isinstance(s, (str, os.PathLike)) else [_scan(s, None, None, None, f"scan{k}")]
    names = [s.name for s in loaded]
    if len(set(names)) != len(names):
        raise InputError(f"merge: two scans share a name ({', '.join(names)}): name them apart (as_scan(..., name=))")
    initial = _initial_poses(init, loaded, load_conf)
    # as the command does: stated uncertainty needs poses to be about (the no-guess campaign takes none)
    have = initial is not None or all(s.guess is not None for s in loaded)
    lacking = [] if have or not any(s.guess is not None for s in loaded) else [s.name for s in loaded if s.guess is None]
    stated = SimpleNamespace(seed=seed, rotation_uncertainty=rotation_uncertainty,
                             translation_uncertainty=translation_uncertainty)
    config, guess = _python_names(stated_config, stated, have, lacking)
    if workers == 1 and scheduler is None:
        return core_merge(loaded, initial, config, progress=progress, pairs=pairs, build_model=build_model, stated=guess)
    with TaskRunner(workers, scheduler, progress=progress, threads=threads) as runner:
        return core_merge(loaded, initial, config, progress=progress, pairs=pairs, map_tasks=runner.map,
                          build_model=build_model, stated=guess)


# ---- the inputs -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class _Pair:
    source: Scan
    target: Scan
    guess: Guess
    config: Config
    surface: Surface | None  # the target's, when prepared


def _pair(source, target, init, viewpoint_source, viewpoint_target, options: dict) -> _Pair:
    """The checked pair, the guess and the config, as ``rangereg register`` makes them (app.options)."""
    from rangereg.core.guess import Guess
    from rangereg.core.problem import relative_guess

    settings = _settings(options)
    given = init if isinstance(init, Guess) else None
    if given is not None and (settings.rotation_uncertainty is not None or settings.translation_uncertainty is not None
                              or settings.no_guess):
        raise InputError("init is a Guess, which states its own uncertainty: give rotation_uncertainty, "
                         "translation_uncertainty or no_guess in it (Guess(T, rotation_deg, translation), "
                         "Guess.none()), not beside it")
    T_init = given.T_target_source if given is not None else _init(init)
    src = _scan(source, viewpoint_source, None, None, "source")
    tgt = _scan(target, viewpoint_target, None, None, "target")
    if given is None and says_nothing(T_init, src, tgt, settings):  # nothing said: any pose (the global method)
        settings = replace(settings, no_guess=True)
    config = _python_names(to_config, settings)
    guess = given or _python_names(to_guess, settings, T_init if T_init is not None else relative_guess(src, tgt))
    _engine_ready(config)
    return _Pair(src, tgt, guess, config, target.surface if isinstance(target, Prepared) else None)


def _engine_ready(config) -> None:
    """Import what the search needs and start KISS-Matcher's process (when it will be asked) before the run
    starts, as the CLI does: the global method's time bound counts seconds from the run's start, and
    Open3D's first import takes 1-2 s."""
    if config.method == "global" and config.candidates.enabled and config.candidates.kiss_matcher:
        from rangereg.core import kiss_matcher_candidates

        kiss_matcher_candidates.start()
    import open3d  # noqa: F401

    import rangereg.core.global_search  # noqa: F401


def _settings(options: dict) -> Settings:
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        near = difflib.get_close_matches(unknown[0], OPTIONS, 1)
        hint = f" (did you mean {near[0]!r}?)" if near else f"; the options are {', '.join(OPTIONS)}"
        raise InputError(f"unknown option {unknown[0]!r}{hint}")
    return _python_names(Settings, **options)


_FLAG = re.compile(r"--([a-z][a-z0-9-]*)")


def _python_names(fn, *args, **kwargs):
    """``fn(...)``, its InputError naming the option as Python spells it (``rotation_uncertainty``, not the
    CLI's ``--rotation-uncertainty``): the settings' checks are written once, for every front end."""
    try:
        return fn(*args, **kwargs)
    except InputError as exc:
        raise InputError(_FLAG.sub(lambda m: m.group(1).replace("-", "_"), str(exc))) from None


def _init(init) -> np.ndarray | None:
    """The guess as a checked rigid (4, 4) T_target_source, or None."""
    from rangereg.core.transforms import check_rigid

    if init is None:
        return None
    if isinstance(init, (str, os.PathLike)):
        return _python_names(parse_init, str(init))
    try:
        T = np.array(init, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"init: expected a 4 x 4 matrix of numbers, got {type(init).__name__}") from None
    try:
        return check_rigid(T, "init")
    except ValueError as exc:
        raise InputError(str(exc)) from None


def _initial_poses(init, scans: list[Scan], load_conf) -> list[np.ndarray] | None:
    if init is None:
        return None
    if isinstance(init, (str, os.PathLike)):
        init = load_conf(init)
    if isinstance(init, dict):
        missing = [s.name for s in scans if s.name not in init]
        if missing:
            raise InputError(f"init has no pose for {', '.join(missing)} (it lists {', '.join(sorted(init))})")
        init = [init[s.name] for s in scans]
    if len(init) != len(scans):
        raise InputError(f"init: {len(init)} initial poses for {len(scans)} scans")
    return [np.array(T, dtype=np.float64) for T in init]


def _scan(data, viewpoint, name: str | None, units: str | None, what: str) -> Scan:
    """Any accepted input as a Scan (module notes); ``what`` names it in messages and names points."""
    if isinstance(data, Prepared):
        if viewpoint is not None or units is not None:
            raise InputError(f"{what}: a prepared scan keeps the viewpoint and units it was prepared with; "
                             "give them to prepare()")
        return data.scan if name is None else replace(data.scan, name=name)
    if isinstance(data, (str, os.PathLike)):
        from rangereg.core.io import load_scan

        return load_scan(Path(data) if isinstance(data, os.PathLike) else data, viewpoint=_viewpoint(viewpoint, what),
                         name=name, units=None if units is None else str(units))
    if isinstance(data, Scan):
        scan = data
        if viewpoint is not None:
            scan = _checked_viewpoint(scan, _viewpoint(viewpoint, what), what)
        if name is not None:
            scan = replace(scan, name=name)
        return scan if units is None else replace(scan, units=str(units), units_from=Origin.GIVEN)
    from rangereg.core.assemble import Given, RawScan, assemble

    # bare points are read as a file's points are: the same rule decides the viewpoint, the kind and the units
    return assemble(RawScan(points=_points(data, what), what=what, name=name or what),
                    Given(viewpoint=_viewpoint(viewpoint, what), units=None if units is None else str(units)))


def _checked_viewpoint(scan: Scan, vp: np.ndarray, what: str) -> Scan:
    from rangereg.core.viewpoint import check_viewpoint

    check_viewpoint(scan.points, vp, scan.grid, scan.faces, what)
    return replace(scan, viewpoint=vp, viewpoint_from=Origin.GIVEN)


def _viewpoint(viewpoint, what: str) -> np.ndarray | None:
    from rangereg.core.sidefiles import vector3

    return None if viewpoint is None else vector3(viewpoint, f"{what}: the viewpoint")


def _points(data, what: str) -> np.ndarray:
    """(N, 3) float64, a copy: from an array-like or an Open3D point cloud; refused when not numbers, not
    (N, 3), not finite, fewer than 3, on a line or too small or large for the geometry (core.scan)."""
    module = type(data).__module__ or ""
    if module.startswith("open3d"):
        if hasattr(data, "point"):  # open3d.t.geometry.PointCloud: positions in a tensor map
            if "positions" not in data.point:
                raise InputError(f"{what}: the Open3D point cloud has no positions")
            raw = data.point.positions.numpy()
        elif hasattr(data, "points"):
            raw = np.asarray(data.points)
        else:
            raise InputError(f"{what}: expected a point cloud, got an Open3D {type(data).__name__}")
    else:
        try:
            raw = np.asarray(data)
        except (TypeError, ValueError):  # ragged lists
            raise InputError(f"{what}: expected an (N, 3) array of x y z points, got rows of different lengths") from None
    if raw.dtype.kind not in "iuf":
        raise InputError(f"{what}: expected an (N, 3) array of x y z numbers, got {type(data).__name__} of "
                         f"{raw.dtype}")
    if raw.ndim != 2 or raw.shape[1] != 3:
        raise InputError(f"{what}: expected an (N, 3) array of x y z points, got shape {raw.shape}")
    bad = ~np.all(np.isfinite(raw), axis=1)
    if bad.any():
        raise InputError(f"{what}: {int(bad.sum())} of {len(raw)} points are not finite (NaN or inf; the first is "
                         f"row {int(np.flatnonzero(bad)[0])}); drop them first, e.g. points[np.isfinite(points).all(1)]")
    points, _ = clean_points(np.array(raw, dtype=np.float64), what)
    return points
