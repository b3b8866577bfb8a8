"""The global method's one event stream: every stage's events numbered in one run (core.events), each
refinement step charged to the search's budget (core.search.budget) before it is taken."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..events import Event, Listener
from ..lock import LockFrame
from ..result import Iterations
from ..search.budget import Budget


class EventStream:
    """Numbers the events of every stage in one stream (iteration over the run, phase_iteration within
    the leg, as core.events documents) and forwards them to the listener; a refinement's step is charged to
    ``budget`` first (:class:`~core.search.budget.BudgetSpent` when it is spent: the step is not taken)."""

    def __init__(self, listener: Listener | None, frame: LockFrame | None, budget: Budget):
        self.listener, self.frame, self.budget = listener, frame, budget
        self.n = {"candidates": 0, "icp": 0, "sa": 0}  # steps per phase over the run
        self.legs = {"candidates": 0, "icp": 0, "sa": 0}
        self.in_leg = 0

    def leg(self, phase: str) -> None:
        """A new leg of ``phase`` begins (a round's scoring, one candidate's ICP)."""
        self.legs[phase] += 1
        self.in_leg = 0

    def emit(self, phase: str, T: np.ndarray, E: float, charge: bool = True) -> None:
        """A step of the stages (a candidate scored: charged by the stage beforehand; a refinement's ICP
        iteration: charged here, unless ``charge`` is False: the last refinement on the whole scans)."""
        if phase != "candidates" and charge:
            self.budget.take_or_stop("steps")
        self.n[phase] += 1
        self.in_leg += 1
        if self.listener is not None:
            coords = None if self.frame is None else self.frame.coords_of(T)  # as core.search.state's events
            self.listener(Event(phase, self.total(), self.in_leg, self.legs[phase], T, E, coords=coords))

    def forward(self, e: Event) -> None:
        """An event of the fallback hybrid's own run (which charges its steps to its share of the budget
        itself), renumbered into this stream (a local-minimum marker is not a step); its legs follow this
        stream's."""
        if not e.local_minimum:
            self.n[e.phase] += 1
        if self.listener is not None:
            self.listener(replace(e, iteration=self.total(), leg=self.legs[e.phase] + e.leg))

    def total(self) -> int:
        return self.n["candidates"] + self.n["icp"] + self.n["sa"]

    def iterations(self) -> Iterations:
        return Iterations(self.n["icp"], self.n["sa"], self.n["candidates"])
