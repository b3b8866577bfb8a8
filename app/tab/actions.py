"""A tab's GUI actions on one thread of their own, in the order the clicks came.

viser hands each plain callback to a pool of 32 threads, where a Reset and the Run clicked just after it started in
either order under load (the Reset then cancelled the new run). A coroutine callback it awaits on its event loop in
the order of the messages; the one :meth:`Actions.callback` makes only queues the action. Buttons, uploads, scene
clicks and the gizmo go through it; fields keep viser's plain callbacks (a value set in code calls them at once, as
the code setting it expects); Pause, Resume and Cancel are no actions: they never wait behind one.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Coroutine
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

log = logging.getLogger("rangereg.workbench")


class Actions:
    """``run(fn, *args)``: how an action is run (the tab's guarded); ``closed()``: whether the tab has gone."""

    def __init__(self, run: Callable[..., None], closed: Callable[[], bool]):
        self._run, self._closed = run, closed
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="rangereg-action")
        self._waiting: set = set()  # the actions queued with once=True and not yet started
        self._lock = threading.Lock()

    def callback(self, fn: Callable[..., None], *args, event: Callable[[Any], tuple] | None = None
                 ) -> Callable[[Any], Coroutine]:
        """A viser callback that queues ``fn(*args)``. ``event(e)``: what of viser's event ``fn`` takes after
        ``args``, read at the click (an upload's file, a click's ray). An action with nothing of its event that is
        still waiting is not queued again (a drag of the gizmo sends dozens; an action reads the tab's state when it
        runs)."""

        async def queue(e) -> None:
            if event is None:
                self.submit(fn, *args, once=True)
            else:
                self.submit(fn, *args, *event(e))

        return queue

    def submit(self, fn: Callable[..., None], *args, once: bool = False) -> None:
        """Queue ``fn(*args)``; ``once``: not while the same is waiting. Nothing once the tab has gone."""
        key = (fn, args)
        with self._lock:
            if self._closed() or (once and key in self._waiting):
                return
            if once:
                self._waiting.add(key)

        def act() -> None:
            if once:
                with self._lock:
                    self._waiting.discard(key)
            self._run(fn, *args)

        try:
            self._pool.submit(act).add_done_callback(_log_failure)
        except RuntimeError:  # closed since the check (close() shut the thread)
            pass

    def close(self, drain: bool = False) -> None:
        """No more actions: those waiting are dropped (``drain``: run to their end first, and waited for)."""
        self._pool.shutdown(wait=drain, cancel_futures=not drain)


def _log_failure(done: Future) -> None:
    """What escaped ``run`` (a notification to a client gone) goes to the log."""
    if not done.cancelled() and done.exception() is not None:
        log.error("workbench action failed", exc_info=done.exception())
