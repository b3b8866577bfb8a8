"""The global method's one event stream: every stage's events numbered in one run (core.events), and the
bound on the fallback's steps and on time, raised as :class:`TimeBound` from the stream."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from ..events import Cancelled, Event, Listener
from ..lock import LockFrame
from ..result import Iterations


class TimeBound(Cancelled):
    """The search's bound ran out (CandidateConfig.fallback_steps or time_limit)."""


class EventStream:
    """Numbers the events of every stage in one stream (iteration over the run, phase_iteration within
    the leg, as core.events documents); forwards them to the listener; raises :class:`TimeBound` when
    the fallback's steps or the time run out."""

    def __init__(self, listener: Listener | None, frame: LockFrame | None, setup_t0: float, time_limit: float | None):
        self.listener, self.frame = listener, frame
        self.n = {"candidates": 0, "icp": 0, "sa": 0}  # steps per phase over the run
        self.legs = {"candidates": 0, "icp": 0, "sa": 0}
        self.in_leg = 0
        self.t0, self.time_limit = setup_t0, time_limit
        self.steps_left: int | None = None  # set while the fallback runs

    def leg(self, phase: str) -> None:
        """A new leg of ``phase`` begins (a round's scoring, one candidate's ICP)."""
        self.legs[phase] += 1
        self.in_leg = 0

    def emit(self, phase: str, T: np.ndarray, E: float) -> None:
        """A step of the stages (a candidate scored, a refinement's ICP iteration); a refinement past the
        time bound raises :class:`TimeBound` (the step is not taken)."""
        if phase == "icp" and self.time_limit is not None and time.perf_counter() - self.t0 > self.time_limit:
            raise TimeBound()
        self.n[phase] += 1
        self.in_leg += 1
        if self.listener is not None:
            coords = None if self.frame is None else self.frame.coords_of(T)  # as core.search.state's events
            self.listener(Event(phase, self.total(), self.in_leg, self.legs[phase], T, E, coords=coords))

    def forward(self, e: Event) -> None:
        """An event of the fallback hybrid's own run, renumbered into this stream (a local-minimum marker is
        not a step); its legs follow this stream's. Raises :class:`TimeBound` past the bound."""
        if self.time_limit is not None and time.perf_counter() - self.t0 > self.time_limit:
            raise TimeBound()
        if not e.local_minimum:
            if self.steps_left is not None:
                if self.steps_left <= 0:
                    raise TimeBound()  # the bound's steps are spent: this one is not taken
                self.steps_left -= 1
            self.n[e.phase] += 1
        if self.listener is not None:
            self.listener(replace(e, iteration=self.total(), leg=self.legs[e.phase] + e.leg))

    def total(self) -> int:
        return self.n["candidates"] + self.n["icp"] + self.n["sa"]

    def iterations(self) -> Iterations:
        return Iterations(self.n["icp"], self.n["sa"], self.n["candidates"])
