"""A registration run on a worker thread that the page can pause, resume, single-step or cancel.

The optimiser calls its listener for every ICP iteration and annealing move (core.events); the
listener here records the event and, when asked to, blocks (pause, step) or raises ``Cancelled``.
Next phase stops at a leg's end: after ICP's local minimum, or before recording the first event of the
next leg (held until the run goes on), so what the page shows when paused is the leg that ended.
All of that happens on the worker thread, so the server's event loop never waits on a run.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from rangereg.core.events import Cancelled, Event
from rangereg.core.register import Result

POLL = 0.05  # seconds a paused run sleeps between looks at its controls (a control also wakes it at once)


class Run:
    """One registration on its own thread. ``work(listener)`` must return a core ``Result``."""

    def __init__(self, work: Callable[[Callable[[Event], None]], Result], mode: str = "run",
                 on_done: Callable[[Run], None] | None = None):
        """mode: "run" (go), "step" (pause after the first event) or "phase" (pause after the first leg)."""
        self.events: list[Event] = []
        self.result: Result | None = None
        self.failure: Exception | None = None
        self._cond = threading.Condition()
        self._mode = mode  # run | paused | step | phase
        self._cancel = False
        self._phase_at_request: tuple[str, int] | None = None  # the leg "phase" mode runs to its end
        self._held: Event | None = None  # the first event of the next leg, held while paused at a leg's end
        self._work, self._on_done = work, on_done
        self.thread = threading.Thread(target=self._main, daemon=True, name="rangereg-run")

    def start(self) -> Run:
        self.thread.start()
        return self

    @property
    def running(self) -> bool:
        return self.thread.is_alive()

    @property
    def paused(self) -> bool:
        with self._cond:
            return self._mode == "paused"

    @property
    def cancelled(self) -> bool:
        """Cancel was asked for (the run stops at its next event)."""
        return self._cancel

    def pause(self) -> None:
        self._set("paused")

    def resume(self) -> None:
        self._set("run")

    def step(self) -> None:
        """Let exactly one more event through (one ICP iteration or one annealing move), then pause."""
        self._set("step")

    def next_phase(self) -> None:
        """Run to the end of the current ICP or SA leg, then pause; paused where a leg ended (ICP's local minimum,
        or the first event of the next leg held back), run the next leg to its end."""
        with self._cond:
            last = self.events[-1] if self.events else None
            if self._held is not None:  # the held event begins the leg to run
                self._phase_at_request = (self._held.phase, self._held.leg)
            else:  # None: the leg is the one the next event belongs to
                self._phase_at_request = None if last is None or last.local_minimum else (last.phase, last.leg)
            self._mode = "phase"
            self._cond.notify_all()

    def cancel(self) -> None:
        with self._cond:
            self._cancel = True
            self._cond.notify_all()

    def join(self, timeout: float | None = None) -> None:
        self.thread.join(timeout)

    def _set(self, mode: str) -> None:
        with self._cond:
            self._mode = mode
            self._cond.notify_all()

    def _listener(self, e: Event) -> None:
        with self._cond:
            if self._mode == "phase":
                if self._phase_at_request is None:
                    self._phase_at_request = (e.phase, e.leg)
                if (e.phase, e.leg) != self._phase_at_request:
                    # a new leg begins: the leg asked for ended with the event before, and the page shows it so
                    # (its phase, E and temperature); this event waits until the run goes on
                    self._mode, self._held = "paused", e
                    self._wait()
                    self._held = None
            self.events.append(e)
            if self._mode == "step" or (self._mode == "phase" and e.local_minimum):
                self._mode = "paused"  # one event through; or ICP's leg ended in its local minimum
            self._wait()

    def _wait(self) -> None:
        """Under the condition: block while paused; raise Cancelled once cancelled."""
        while self._mode == "paused" and not self._cancel:
            self._cond.wait(POLL)
        if self._cancel:
            raise Cancelled()

    def _main(self) -> None:
        try:
            self.result = self._work(self._listener)
        except Exception as exc:  # reported to the page by on_done; the session lives on
            self.failure = exc
        finally:
            if self._on_done is not None:
                self._on_done(self)
