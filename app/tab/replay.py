"""Replay (Landscape tab): a timeline over the events of the last run or of a loaded ``--trace`` file.

Scrubbing sets the shown pose (not the initial guess), the E, phase and temperature line, and the
marker on the slice; Play walks the timeline at a chosen speed; the minimum buttons jump between the
local minima ICP stopped in. Play's thread only hands each step to the refresher (app/tab/state.py).

A loaded trace must be of the scans on the page: its header names both by content (point count and
SHA-256 of the points), so another pair, the same pair swapped, or an edited file is refused with a
notification and the page stays as it was. A trace without a header is
checked by E at its best pose, and the panel says it could not be checked by content.
The trace's method, seed and guess are shown; another guess or other settings are not a mismatch.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from rangereg.app.figures import fmt, squared_unit
from rangereg.app.tab import scene3d
from rangereg.app.tab.status import E_text, outcome
from rangereg.app.views import temperature_of
from rangereg.core.errors import InputError
from rangereg.core.events import Event
from rangereg.core.trace import NO_HEADER, Trace, parse_trace, read_trace  # noqa: F401  (parse_trace: the page's name)

AUTO = "auto"  # the speed that plays the whole timeline in about REPLAY_SECONDS, whatever its length
SPEEDS = (AUTO, "10", "30", "100", "300", "1000")  # events per second
REPLAY_SECONDS = 6.0  # a replay long enough to follow (a 39-event trace at 100 events a second was over in 0.4 s)
TICK = 0.1  # seconds between steps of Play
TRACE_SLACK = 10.0  # a trace fits the scans when E re-evaluated here is within this factor of its own record


def check_trace_fits(problem, events: list[Event], threshold: float, name: str = "trace") -> None:
    """Refuse a trace recorded on other scans: E at its best pose, evaluated on these scans, must be
    within TRACE_SLACK of what the trace recorded there (the overlap sample may differ, the pair may not)."""
    best = min(events, key=lambda e: e.error)
    here = float(problem.error(best.T))
    slack = max(float(threshold), 0.0)
    if not (best.error / TRACE_SLACK - slack <= here <= TRACE_SLACK * best.error + slack):
        raise InputError(f"{name} does not fit these scans: at its best pose it recorded E = {fmt(best.error)}, "
                         f"these scans give E = {fmt(here)}")


def read_checked(text: str, name: str, source, target, problem, threshold: float) -> Trace:
    """A trace file's text read and checked against the scans ``source``, ``target`` (core Scans): refused
    (InputError) when its header names other scans; without a header, when E at its best pose does not fit
    ``problem`` (the only check an old trace allows)."""
    trace = read_trace(text, name)
    if not trace.check_scans(source, target):
        check_trace_fits(problem, trace.events, threshold, name)
    return trace


def trace_line(trace: Trace, T_init: np.ndarray, units: str = "units") -> str:
    """One markdown line about a loaded trace: what run it was (method, seed, guess) or that it has no header."""
    h = trace.header
    if h is None:
        return f"Trace **{trace.name}**: {NO_HEADER}; it fits them by E."
    guess = h.differences(T_init, units=units)
    where = guess[0].replace("initial guess (", "its guess is ").rstrip(")") + " from this page's" if guess else (
        "its guess is this page's")
    return f"Trace **{trace.name}**: method {h.method}, seed {h.seed}, rangereg {h.version}; {where}."


def play_speed(chosen: str, n: int) -> float:
    """Events a second for Play: as chosen, or (auto) the ``n`` events in about REPLAY_SECONDS, at least one a tick."""
    if chosen != AUTO:
        return float(chosen)
    return max(n / REPLAY_SECONDS, 1.0)


class ReplayPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        with gui.add_folder("Replay"):
            self.info = gui.add_markdown("No run to replay yet.")
            self.slider = gui.add_slider("Event", 0, 1, 1, 0, disabled=True, visible=False,
                                         hint="0: the initial pose; k: the pose after the run's k-th event")
            self.speed = gui.add_dropdown("Speed (events/s)", SPEEDS, initial_value=AUTO,
                                          hint=f"auto: the whole run in about {REPLAY_SECONDS:g} s")
            self.play = gui.add_button("Play", disabled=True)
            self.pause = gui.add_button("Pause replay", disabled=True)
            self.previous_min = gui.add_button("Previous minimum", disabled=True)
            self.next_min = gui.add_button("Next minimum", disabled=True)
            self.upload = gui.add_upload_button("Load a trace", hint="a register --trace file (.jsonl) of these scans")
        self.events: list[Event] = []
        self.loaded: Trace | None = None  # the last trace loaded; shown while its events are the timeline's
        self.trace: Trace | None = None
        self.minima = np.zeros(0, int)
        self._playing: threading.Event | None = None
        self._drawn_at = 0.0
        self.slider.on_update(lambda e: tab.guarded(self.show, int(self.slider.value)))
        self.play.on_click(tab.action(self.start_play))
        self.pause.on_click(lambda e: self.stop_play())
        self.previous_min.on_click(tab.action(self.jump, -1))
        self.next_min.on_click(tab.action(self.jump, +1))
        self.upload.on_upload(tab.action(self.load_trace, event=lambda e: (e.target.value.name, e.target.value.content)))

    def reset(self) -> None:
        """Take the events of the run that just ended (or were loaded); the timeline ends at the last one."""
        self.stop_play()
        with self.state.lock:
            self.events = list(self.state.events)
            loaded = self.loaded is not None and self.state.events is self.loaded.events
        self.trace = self.loaded if loaded else None
        n = len(self.events)
        self.minima = np.array([k + 1 for k, e in enumerate(self.events) if e.local_minimum], int)
        self.slider.max = max(n, 1)
        self.slider.value = n
        self.lock(False)
        self.describe(n)

    def load_trace(self, name: str, content: bytes) -> None:
        st = self.state
        st.require_scans()
        st.require_idle()
        with st.lock:
            source, target, problem, threshold = st.source, st.target, st.problem, st.threshold or 0.0
        trace = read_checked(content.decode("utf-8", errors="replace"), name, source, target, problem, threshold)
        events = trace.events
        with st.lock:
            st.reset_run(events[0].T)
            st.events = events
            st.run_method = f"trace {name}"
            st.run_header = trace.header  # exported again as it came
        self.loaded = trace
        self.reset()
        self.show(len(events))
        self.tab.notify("Trace loaded", f"{name}: {len(events)} events" + (
            "" if trace.header else f"; {NO_HEADER}"), error=False)

    def describe(self, k: int) -> None:
        n = len(self.events)
        self.slider.visible = bool(n)  # no "60 of 149" beside "No run to replay yet"
        if not n:
            self.info.content = "No run to replay yet."
            return
        about = ""
        if self.trace is not None:
            about = "\n\n" + trace_line(self.trace, self.state.T_init, self.state.target.units)
        if k == 0:
            self.info.content = f"Event 0 of {n}: the initial pose" + (
                " (the trace's own guess)" if self.start() is not self.state.T_init else "") + about
            return
        e = self.events[k - 1]
        units = self.state.target.units
        u = squared_unit(units)
        temp = f"{fmt(temperature_of(e))} {u}" if np.isfinite(temperature_of(e)) else "-"
        mark = " · **local minimum**" if e.local_minimum else ""
        event = (f"iteration {e.iteration} · phase **{e.phase.upper()}** (leg {e.leg}) · E = {fmt(e.error)} {u} · "
                 f"temperature {temp}{mark}")
        result = self.end_result() if k == n else None
        if result is not None:  # the end shows the run's outcome, as the status does: its E and which pose it is
            self.info.content = (f"Event {k} of {n}, the run's end: **{E_text(result.error, outcome(result), units)}**"
                                 f", the pose shown. Its last event: {event}" + about)
            return
        self.info.content = f"Event {k} of {n} · {event}" + about

    def end_result(self):
        """The run's result (core Result) when the timeline is the tab's last run and it has one, else None: the end of
        that timeline shows its pose (:meth:`show`), the status its E."""
        with self.state.lock:
            result = self.state.result
        if self.trace is not None or result is None or result.transform is None:
            return None
        return result

    def start(self) -> np.ndarray:
        """Event 0's pose: the loaded trace's own guess (its header), else the page's initial guess."""
        if self.trace is not None and self.trace.start is not None:
            return self.trace.start
        return self.state.T_init

    def show(self, k: int) -> None:
        """Scrub to event ``k`` (0: the initial pose): the shown pose, the line above, the marker on the slice."""
        st, tab = self.state, self.tab
        if st.running or not self.events or tab.nodes is None:
            return
        k = int(np.clip(k, 0, len(self.events)))
        with st.lock:
            if st.events is not self.events and list(st.events) != self.events:
                return  # a new pair or a reset: nothing to replay
            T = self.start() if k == 0 else self.events[k - 1].T
            if k == len(self.events) and self.trace is not None:
                T = self.trace.end  # a loaded trace's outcome: its closing result line
            elif k == len(self.events) and st.result is not None and st.result.transform is not None:
                T = st.result.transform  # the end of the timeline is the run's outcome (its best pose)
            st.T = T
        with tab.client.atomic():
            scene3d.move_source(tab.nodes, st, T, gizmo=False)
            self.describe(k)
        tab.landscape.mark_terrain(T)
        if self.slider.value != k:
            self.slider.value = k
        if st.slice is not None and time.monotonic() - self._drawn_at > 0.3:
            self._drawn_at = time.monotonic()
            tab.landscape.draw()

    def jump(self, direction: int) -> None:
        if not len(self.minima):
            raise InputError("this run stopped in no local minimum (ICP marks one when it ends above the threshold)")
        k = int(self.slider.value)
        later = self.minima[self.minima > k] if direction > 0 else self.minima[self.minima < k][::-1]
        if not len(later):
            raise InputError("no later local minimum" if direction > 0 else "no earlier local minimum")
        self.show(int(later[0]))

    def start_play(self) -> None:
        self.stop_play()
        if not self.events:
            raise InputError("no run to replay yet")
        stop = self._playing = threading.Event()
        speed = play_speed(str(self.speed.value), len(self.events))
        start = 0 if int(self.slider.value) >= len(self.events) else int(self.slider.value)
        self.play.disabled, self.pause.disabled = True, False
        threading.Thread(target=self._play, args=(stop, start, speed), daemon=True, name="rangereg-replay").start()

    def _play(self, stop: threading.Event, k: float, speed: float) -> None:
        n = len(self.events)
        while not stop.is_set() and not self.state.closed:
            k = min(k + speed * TICK, n)
            self.state.hand(lambda st: None, lambda k=int(k), stop=stop: None if stop.is_set() else self.show(k))
            if k >= n:
                break
            time.sleep(TICK)
        self.state.hand(lambda st: None, lambda: self._ended(stop))

    def _ended(self, stop: threading.Event) -> None:
        if self._playing is stop:
            self._playing = None
            self.play.disabled, self.pause.disabled = not self.events, True
            if self.state.slice is not None:
                self.tab.landscape.draw()

    def stop_play(self) -> None:
        if self._playing is not None:
            self._playing.set()
            self._playing = None
        self.play.disabled, self.pause.disabled = not self.events, True

    def forget(self) -> None:
        """A new pair or a new initial pose: the last run's timeline is gone."""
        self.stop_play()
        self.events, self.minima = [], np.zeros(0, int)
        self.loaded = self.trace = None
        self.describe(0)
        self.lock(False)

    def lock(self, running: bool) -> None:
        """A run holds the timeline; a new run or pair empties it."""
        if running:
            self.stop_play()
            self.events, self.trace = [], None
            self.describe(0)
        off = running or not self.events
        self.slider.disabled = self.play.disabled = self.previous_min.disabled = self.next_min.disabled = off
        self.upload.disabled = running
