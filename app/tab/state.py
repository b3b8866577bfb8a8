"""The state of one browser tab: its scans, poses, run, slice and model. No viser in here.

Threading contract
------------------
Four kinds of thread touch a tab:

* viser's callback threads (a click, a drag, an upload): they read the GUI and write this state,
  always inside ``with state.lock``, and only while no run holds the scans (:meth:`require_idle`);
* worker threads (the run, the slice, the merge): they read what they were given when they were
  started and never write this state. They hand their result over with :meth:`hand`;
* the refresher (app/tab/refresher.py), the one owner of handed results: every tick it applies them
  under the lock (:meth:`apply_handed`), then pushes a snapshot to the page inside ``client.atomic()``.
  It logs what fails (``logging``) and keeps going;
* the run's own thread appends to ``run.events`` (a list only it grows); readers take ``len()`` first
  and read up to there.

Lock order: ``state.lock`` is taken inside ``client.atomic()``, never around it.

``slice_busy`` and ``slice_cancel`` are set under the lock when a slice starts and cleared by the
slice's handed result, so two slices never run at once and a new pair drops a stale one.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from rangereg.app.runner import Run
from rangereg.app.views import Display
from rangereg.core.errors import InputError
from rangereg.core.landscape import Slice
from rangereg.core.problem import Problem
from rangereg.core.register import Result
from rangereg.core.scan import Scan
from rangereg.core.surface import Surface


@dataclass(eq=False)
class SliceView:
    """A computed slice, the problem it was computed on, and a version the page compares to redraw."""

    slice: Slice
    problem: Problem
    version: int


@dataclass(eq=False)
class TabState:
    lock: threading.RLock = field(default_factory=threading.RLock)
    closed: bool = False
    pair: int = 0  # bumped by every new pair: a worker's result for an older pair is dropped
    source: Scan | None = None
    target: Scan | None = None
    surfaces: tuple[Surface, Surface] | None = None  # (source, target)
    frusta: dict = field(default_factory=dict)  # kind -> (source frustum, target frustum)
    display: Display | None = None
    T_file: np.ndarray = field(default_factory=lambda: np.eye(4))  # the pose the files imply (T_target_source)
    T_init: np.ndarray = field(default_factory=lambda: np.eye(4))  # where runs start
    T: np.ndarray = field(default_factory=lambda: np.eye(4))  # the pose shown
    T_truth: np.ndarray | None = None
    problem: Problem | None = None
    E0: float = float("nan")  # E at T_init on the current problem (kept, not re-evaluated per push)
    threshold: float | None = None
    run: Run | None = None
    run_method: str = ""
    run_header: object | None = None  # core.trace.TraceHeader of the run (or loaded trace) the events belong to
    events: list = field(default_factory=list)
    result: Result | None = None
    finished_text: str = ""
    slice: SliceView | None = None
    slice_busy: bool = False
    slice_cancel: threading.Event | None = None
    campaign_busy: bool = False  # a campaign merge works (set and cleared under the lock): one at a time
    model: object | None = None  # core.fuse's model (vertices, faces)
    model_version: int = 0
    residual_rgb: np.ndarray | None = None  # (N, 3) uint8 source colours by distance to the target (Model tab)
    _handed: deque = field(default_factory=deque)

    @property
    def run_start(self) -> np.ndarray:
        """The pose the events on show started from: their header's T_init (a loaded trace's own guess, which
        need not be this page's), else T_init. Paths on the slice and in a recording start here."""
        start = getattr(self.run_header, "T_init", None)
        return self.T_init if start is None else start

    @property
    def running(self) -> bool:
        return self.run is not None and self.run.running

    @property
    def paused(self) -> bool:
        return self.running and self.run.paused

    def require_idle(self) -> None:
        if self.running:
            raise InputError("a run holds the scans: pause is not enough, Cancel it first")

    def require_scans(self) -> None:
        if self.source is None:
            raise InputError("open two scans first")

    def reset_run(self, T: np.ndarray | None = None) -> None:
        """Forget the last run (its method, events, result and finished line); the shown pose goes to ``T``. Under the
        lock."""
        self.events, self.result, self.finished_text, self.run_method = [], None, "", ""
        self.run_header = None
        self.residual_rgb = None
        if T is not None:
            self.T = T

    def set_problem(self, problem: Problem) -> None:
        """A new overlap cut; E0 follows it. Under the lock."""
        self.problem = problem
        self.E0 = float(problem.error(self.T_init))

    def hand(self, apply: Callable[[TabState], None], then: Callable[[], None] | None = None) -> None:
        """From a worker: ``apply(state)`` will run under the lock on the refresher, then ``then()`` outside it."""
        self._handed.append((apply, then))

    def apply_handed(self) -> list[Callable[[], None]]:
        """On the refresher: apply every handed result under the lock; returns their follow-ups, in order."""
        follow = []
        with self.lock:
            while self._handed:
                apply, then = self._handed.popleft()
                apply(self)
                if then is not None:
                    follow.append(then)
        return follow

    def cancel_work(self) -> None:
        """Stop the run and the slice (a closed tab, a reset)."""
        if self.run is not None:
            self.run.cancel()
        if self.slice_cancel is not None:
            self.slice_cancel.set()
