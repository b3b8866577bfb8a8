"""A merge's progress as events (core.merge): what step it is at, how many of its tasks are done out of
how many, in which round, the time so far and an estimate of the time left. The command line and the
page render the same events; nothing reads their text back.

The estimate is the mean time of the step's tasks so far, less its first few, times the tasks left.
The first tasks of a process build the geometry of the scans they touch before any other: taken alone
they say nothing of the rest (a 96-scan campaign's overlaps were once estimated at 4489 s from the
first task's 1 s, for 40 s of work); after them a new scan's geometry is built every few tasks (the
pairs come in order), which a mean counts and a median would not (100 stops, 1307 overlaps: the
median's estimate 1.5 s, the time taken 5.3 s)."""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import StrEnum

WARM = 3  # a step's first tasks, left out of its estimate


class Step(StrEnum):
    """The steps of a merge, in the order they first run."""

    FEATURES = "features"  # each scan's FPFH features (which scans are likely neighbours)
    OVERLAPS = "overlaps"  # overlaps of candidate pairs under poses
    PAIRS = "pairs"  # pair registrations
    GRAPH = "graph"  # the pose graph
    MODEL = "model"  # fusing the placed scans


@dataclass(frozen=True)
class MergeProgress:
    """One progress event. ``done`` / ``total``: the step's tasks (the pairs count over every round);
    ``round``: the merge's round (0 before the first registrations); ``elapsed``: seconds since the
    merge began; ``estimate``: seconds the step's tasks left should take (None: not known yet, or done);
    ``note``: what the step found, in words (e.g. the graph's counts), '' while tasks run."""

    step: Step
    round: int
    done: int
    total: int
    elapsed: float
    estimate: float | None = None
    note: str = ""

    @property
    def finished(self) -> bool:
        return self.done >= self.total

    def line(self) -> str:
        """The event for people, e.g. ``pairs, round 2 21/23, 0:42 elapsed, ETA 0:04``, or the step's note
        (``graph, round 2: 25 of 39 pairs used, 15 of 15 scans placed``)."""
        where = f"{self.step}" + (f", round {self.round}" if self.round else "")
        if self.note:
            return f"{where}: {self.note}"
        tail = "done" if self.finished else ("ETA unknown" if self.estimate is None else f"ETA {clock(self.estimate)}")
        return f"{where} {self.done}/{self.total}, {clock(self.elapsed)} elapsed, {tail}"

    def __str__(self) -> str:
        return self.line()


def clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


@dataclass(frozen=True)
class Forecast:
    """An estimate checked: once a tenth of a map's tasks (at least 3) were done, ``estimated`` seconds
    for the ``left`` tasks left; they took ``measured`` seconds."""

    step: Step
    round: int
    left: int
    estimated: float
    measured: float


class Counter:
    """The counts of one step over a merge (a later round's pairs add to the total), turned into events
    for ``say``: every task's end at most once per ``every`` seconds, and the last."""

    def __init__(self, step: Step, say: Callable[[MergeProgress], None], t0: float, every: float = 1.0):
        self.step, self.say, self.t0, self.every = step, say, t0, every
        self.done = self.total = 0
        self.durations: list[float] = []
        self.round = 0
        self.forecasts: list[Forecast] = []
        self._last = -1e9
        self._mark = 0.0

    def begin(self, tasks: int, round_: int) -> Callable[[int], None]:
        """A map of ``tasks`` tasks starts: add them to the total; returns the callback the map calls with
        the count of its tasks done so far."""
        self.total += tasks
        self.round = round_
        base = self.done
        self._mark = time.perf_counter()
        forecast: list = []  # (tasks left, estimate, when) once a tenth of the map (>= 3 tasks) is done

        def done(count: int) -> None:
            now = time.perf_counter()
            finished = base + count
            new = finished - self.done
            if new > 0:  # tasks finished since the last call share its wait (a cluster returns batches)
                self.durations.extend([(now - self._mark) / new] * new)
                self.done, self._mark = finished, now
            if not forecast and max(3, tasks // 10) <= count < tasks:
                forecast.append((tasks - count, self.estimate(), now))
            if count == tasks and forecast:
                left, estimate, then = forecast[0]
                self.forecasts.append(Forecast(self.step, self.round, left, estimate, now - then))
            if self.done < self.total and now - self._last < self.every:
                return
            self._last = now
            self.say(self.event(now))

        return done

    def estimate(self) -> float | None:
        """Seconds the tasks left should take: the mean task time so far, less the step's first
        ``WARM`` tasks, x the tasks left (None before any task past those is done)."""
        if len(self.durations) <= WARM or self.done >= self.total:
            return None
        steady = self.durations[WARM:]
        return sum(steady) / len(steady) * (self.total - self.done)

    def event(self, now: float | None = None) -> MergeProgress:
        now = time.perf_counter() if now is None else now
        return MergeProgress(self.step, self.round, self.done, self.total, now - self.t0,
                             self.estimate())
