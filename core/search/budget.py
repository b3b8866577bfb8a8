"""A bound on a search's work, counted as it is spent: candidate poses scored and refinement steps (ICP
iterations and annealing moves), and seconds only when a user asks for them.

A search consults its :class:`Budget` before each unit of work (``take``); the budget answers with the
:class:`~core.result.Stop` that ends the search when that unit would pass a bound, else it records the unit.
Work, not seconds: the same pair with the same seed spends the same steps on any machine, however busy, and so
ends at the same pose. Seconds (``seconds``) are a user's explicit choice; they start when the search does,
after the setup, and a run bounded by them may end otherwise on a slower or busier machine.

A budget may hand out a share (``share``): the fallback hybrid of the global method gets at most its own steps
out of what the whole search has left, and every step it takes is charged to both.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..result import Stop, StopReason

WORK = ("steps", "candidates")  # what a budget counts


class BudgetSpent(Exception):  # noqa: N818 (a stop, not an error)
    """Raised where a search consulted its budget and was told to stop; ``stop`` says which bound and where.
    The run that owns the budget catches it and returns its best pose with that stop (never a listener's)."""

    def __init__(self, stop: Stop):
        super().__init__(str(stop))
        self.stop = stop


class Budget:
    """Limits on ``steps`` and ``candidates`` (None: no limit) and optionally ``seconds`` from now on
    ``clock`` (injected by tests; only read when ``seconds`` is given). ``used`` counts what was taken."""

    def __init__(self, steps: int | None = None, candidates: int | None = None, seconds: float | None = None,
                 clock: Callable[[], float] | None = None, parent: Budget | None = None, where: str = ""):
        self.limits = {"steps": steps, "candidates": candidates}
        self.used = {"steps": 0, "candidates": 0}
        self.clock = clock if clock is not None else time.perf_counter
        self.seconds, self.parent, self.where = seconds, parent, where
        self.t0 = self.clock() if seconds is not None else 0.0

    def __repr__(self) -> str:
        lim = ", ".join(f"{k} {self.used[k]}/{'-' if v is None else v}" for k, v in self.limits.items())
        return f"Budget({lim}{f', {self.seconds:g} s' if self.seconds is not None else ''})"

    def left(self, what: str) -> int | None:
        """Units of ``what`` ("steps", "candidates") this budget (and its parent) still allows; None: no limit."""
        lim = self.limits[what]
        own = None if lim is None else max(0, lim - self.used[what])
        up = self.parent.left(what) if self.parent is not None else None
        return own if up is None else up if own is None else min(own, up)

    def out_of_time(self) -> bool:
        if self.parent is not None and self.parent.out_of_time():
            return True
        return self.seconds is not None and self.clock() - self.t0 > self.seconds

    def spent(self) -> Stop | None:
        """The stop when no further step may be taken (a limit reached, or the seconds gone), else None."""
        if self.out_of_time():
            return self._stop("seconds")
        if self.left("steps") == 0:
            return self._stop("steps")
        return None

    def take(self, what: str, n: int = 1) -> Stop | None:
        """Ask for ``n`` units of ``what``: None and recorded when allowed, else the stop (nothing recorded)."""
        if self.out_of_time():
            return self._stop("seconds")
        left = self.left(what)
        if left is not None and left < n:
            return self._stop(what)
        self._record(what, n)
        return None

    def take_or_stop(self, what: str, n: int = 1) -> None:
        """:meth:`take`, raising :class:`BudgetSpent` with the stop when refused."""
        stop = self.take(what, n)
        if stop is not None:
            raise BudgetSpent(stop)

    def grant(self, what: str, n: int) -> int:
        """Take as many of ``n`` units as allowed (at least 0); returns how many were taken."""
        if self.out_of_time():
            return 0
        left = self.left(what)
        k = n if left is None else min(n, left)
        self._record(what, k)
        return k

    def share(self, steps: int | None, where: str) -> Budget:
        """A budget of at most ``steps`` more steps (None: whatever this one has left), charged to this one too."""
        return Budget(steps=steps, candidates=None, seconds=None, clock=self.clock, parent=self, where=where)

    def _record(self, what: str, n: int) -> None:
        self.used[what] += n
        if self.parent is not None:
            self.parent._record(what, n)

    def bound_text(self) -> str:
        """The bounds in words, e.g. "1200 steps, 300 of them the hybrid's, and 2.5 s"."""
        parts, b = [], self
        while b is not None:
            if b.limits["steps"] is not None:
                parts.append(f"{b.limits['steps']} steps" + (f" for {b.where}" if b.where else ""))
            if b.limits["candidates"] is not None:
                parts.append(f"{b.limits['candidates']} candidates scored")
            if b.seconds is not None:
                parts.append(f"{b.seconds:g} s")
            b = b.parent
        return ", ".join(parts) or "no bound"

    def _stop(self, what: str) -> Stop:
        reason = StopReason.TIME_BOUND if what == "seconds" else StopReason.WORK_BOUND
        spent = {"seconds": "the seconds are gone", "steps": "its steps are spent",
                 "candidates": "its candidates are spent"}[what]
        return Stop(reason, f"{reason.value}: {spent} ({self.bound_text()})")
