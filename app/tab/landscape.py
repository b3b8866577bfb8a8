"""The Landscape panel: a 2-D slice of E around the pose, with the run's path on it."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import viser

from app.tab.fields import Range, parse_number
from app.tab.state import SliceView, TabState
from app.tab.terrain import PathOnSlice, Terrain
from app.views import slice_figure
from core.errors import InputError
from core.events import Cancelled
from core.landscape import Slice, compute_slice, default_span, project
from core.problem import Problem
from core.transforms import PARAM_NAMES

STEPS = Range(2, 201, integer=True)


def compute(problem: Problem, center, params: tuple[str, str], spans: tuple[float, float], steps: int,
            cancel: threading.Event, progress=None) -> Slice | None:
    """``compute_slice`` that stops within one row of ``cancel`` being set (then None). progress(fraction)."""

    def row_done(fraction: float) -> None:
        if cancel.is_set():
            raise Cancelled()
        if progress is not None:
            progress(fraction)

    if cancel.is_set():
        return None
    try:
        return compute_slice(problem, center, params, spans, steps, progress=row_done)
    except Cancelled:
        return None


@dataclass(eq=False)
class LandscapeHandles:
    param_a: viser.GuiDropdownHandle
    param_b: viser.GuiDropdownHandle
    span_a: viser.GuiTextHandle
    span_b: viser.GuiTextHandle
    steps: viser.GuiTextHandle
    compute: viser.GuiButtonHandle
    cancel: viser.GuiButtonHandle
    progress: viser.GuiProgressBarHandle
    terrain: viser.GuiCheckboxHandle
    folder: viser.GuiFolderHandle
    plot: viser.GuiPlotlyHandle | None = None  # made with the first slice


def build(gui: viser.GuiApi) -> LandscapeHandles:
    with gui.add_folder("Error slice") as folder:
        return LandscapeHandles(
            param_a=gui.add_dropdown("Parameter A", PARAM_NAMES, initial_value="tx"),
            param_b=gui.add_dropdown("Parameter B", PARAM_NAMES, initial_value="ry"),
            span_a=gui.add_text("Span A (0: auto)", "0", hint="+- this much around the pose (scan units or deg)"),
            span_b=gui.add_text("Span B (0: auto)", "0", hint="+- this much around the pose (scan units or deg)"),
            steps=gui.add_text("Steps", "41", hint=f"grid points per axis, {STEPS.lo:g} to {STEPS.hi:g}"),
            compute=gui.add_button("Compute slice"),
            cancel=gui.add_button("Cancel slice", disabled=True),
            progress=gui.add_progress_bar(0.0, visible=False),
            terrain=gui.add_checkbox("Show as 3-D terrain", False,
                                     hint="the slice as a height field beside the scans, with the run's path on it"),
            folder=folder)


def picture(st: TabState) -> tuple:
    """(slice, path (K, 2), phases (K,), current pose (2,), title) for the page's figure and the PNG."""
    view = st.slice
    sl, problem = view.slice, view.problem
    events = st.events[: len(st.events)]
    xy = project(problem, sl.T_center, sl.params, [st.T_init] + [e.T for e in events]) if events else None
    phases = ["icp"] + [e.phase for e in events] if events else None
    current = project(problem, sl.T_center, sl.params, [st.T])[0]
    title = f"{st.source.name} → {st.target.name}: log10 E({sl.params[0]}, {sl.params[1]})"
    return sl, xy, phases, current, title


class LandscapePanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.h = build(tab.gui)
        self.h.compute.on_click(lambda e: tab.guarded(self.start))
        self.h.cancel.on_click(lambda e: self.cancel())
        self.h.terrain.on_update(lambda e: tab.guarded(self.update_terrain))
        self.drawn_at = 0.0
        self.terrain: Terrain | None = None
        self.terrain_lock = threading.Lock()  # one builder at a time (a checkbox and the refresher may race); taken
        # outside client.atomic() and the state's lock, never inside them

    def start(self) -> None:
        st, h = self.state, self.h
        st.require_scans()
        params = (h.param_a.value, h.param_b.value)
        if params[0] == params[1]:
            raise InputError("choose two different parameters for the slice")
        steps = parse_number(h.steps.value, "steps", STEPS)
        typed = [parse_number(s.value, f"span {k}", Range(0)) for s, k in ((h.span_a, "A"), (h.span_b, "B"))]
        with st.lock:
            if st.slice_busy:
                raise InputError("a slice is already being computed")
            problem, pair = st.problem, st.pair
            spans = tuple(float(s) or default_span(problem, n) for s, n in zip(typed, params))
            if not all(np.isfinite(s) and s > 0 for s in spans):
                raise InputError(f"spans must be positive numbers, got {spans}")
            center = st.T if not st.running else st.T_init
            st.slice_busy, st.slice_cancel = True, threading.Event()
            cancel = st.slice_cancel
        h.progress.value, h.progress.visible = 0.0, True
        h.compute.disabled, h.cancel.disabled = True, False
        threading.Thread(target=self._work, args=(problem, pair, center, params, spans, steps, cancel), daemon=True,
                         name="rangereg-slice").start()

    def _work(self, problem, pair, center, params, spans, steps, cancel: threading.Event) -> None:
        """On the slice's thread: compute, then hand the slice to the refresher."""
        bar, sl, failure = self.h.progress, None, None
        try:
            sl = compute(problem, center, params, spans, steps, cancel, lambda f: setattr(bar, "value", 100.0 * f))
        except Exception as exc:  # said on the page; the tab lives on
            failure = exc

        def apply(st: TabState) -> None:
            if st.slice_cancel is cancel:
                st.slice_busy, st.slice_cancel = False, None
            if sl is not None and st.pair == pair:
                st.slice = SliceView(sl, problem, (st.slice.version + 1) if st.slice else 1)

        def then() -> None:
            bar.visible = False
            self.h.compute.disabled, self.h.cancel.disabled = False, True
            if self.state.closed:
                return
            if failure is not None:
                self.tab.notify("Slice failed", str(failure))
            elif sl is None:
                self.tab.notify("Slice", "cancelled", error=False)
            else:
                self.draw()

        self.state.hand(apply, then)

    def cancel(self) -> None:
        """Stop the slice being computed (it ends within one row of the grid)."""
        with self.state.lock:
            if self.state.slice_cancel is not None:
                self.state.slice_cancel.set()

    def draw(self) -> None:
        """Draw (or redraw) the slice with the run's path so far."""
        st = self.state
        with st.lock:
            if st.slice is None:
                return
            args = picture(st)
            units = st.target.units
        self.drawn_at = time.monotonic()
        self.update_terrain()
        fig = slice_figure(*args, units=units)
        if self.h.plot is None:
            with self.h.folder:
                self.h.plot = self.tab.gui.add_plotly(fig, aspect=1.2)
        else:
            self.h.plot.figure = fig

    def update_terrain(self) -> None:
        """The 3-D terrain of the current slice with the path so far, when shown; gone otherwise."""
        with self.terrain_lock:
            self._update_terrain()

    def mark_terrain(self, T) -> None:
        """Move the terrain's marker of the shown pose (replay)."""
        with self.terrain_lock:
            if self.terrain is not None:
                self.terrain.mark(T)

    def _update_terrain(self) -> None:
        st, tab = self.state, self.tab
        with st.lock:
            view, events, T_init, T, units = st.slice, st.events, st.T_init, st.T, st.target.units if st.target else ""
        if not self.h.terrain.value or view is None or tab.nodes is None:
            if self.terrain is not None:
                self.terrain.remove()
                self.terrain = None
            return
        with tab.client.atomic():
            if self.terrain is None or self.terrain.view is not view:
                if self.terrain is not None:
                    self.terrain.remove()
                self.terrain = Terrain(tab.client.scene, view, units, T_init, events)
            elif self.terrain.path.events is not events:
                self.terrain.path = PathOnSlice(view.problem, view.slice, T_init, events)
            self.terrain.update(T)
