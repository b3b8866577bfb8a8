"""The Landscape panel: a 2-D slice of E around the pose, with the run's path on it.

The run's path on the slice is projected once per event (app/tab/terrain.PathOnSlice), shared by the
contour and the 3-D terrain; during a run the refresher moves the terrain's marker on every push and
redraws its path and the contour less often (app/tab/refresher.py).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.options import KNOBS
from rangereg.app.tab.fields import Range, parse_number, parse_setting
from rangereg.app.tab.state import SliceView, TabState
from rangereg.app.tab.terrain import PathOnSlice, Terrain
from rangereg.app.views import slice_figure
from rangereg.core.errors import InputError
from rangereg.core.events import Cancelled
from rangereg.core.landscape import Slice, compute_slice, default_span, project
from rangereg.core.problem import Problem
from rangereg.core.transforms import PARAM_NAMES

COVER = 1.15  # automatic spans reach this far past the run's start, so the contour shows where it began
MAX_FIGURE_PATH = 600  # the contour's path is thinned to this many points: its figure is sent as JSON (2000 points
# made 168 kB) and redrawn by Plotly in the browser; a 360-pixel plot shows no more


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
            steps=gui.add_text("Steps", "41", hint=f"grid points per axis, {KNOBS['steps'].describe()}"),
            compute=gui.add_button("Compute slice"),
            cancel=gui.add_button("Cancel slice", disabled=True),
            progress=gui.add_progress_bar(0.0, visible=False),
            terrain=gui.add_checkbox("Show as 3-D terrain", False,
                                     hint="the slice as a height field beside the scans, with the run's path on it"),
            folder=folder)


def picture(st: TabState, path: PathOnSlice | None = None, most: int | None = None) -> tuple:
    """(slice, path (K, 2), phases (K,), current pose (2,), title, the run's local minima (R, 2)) for the page's
    figure and the PNG.

    ``path``: the run's events already projected (else projected here); ``most``: thin the path to this many points.
    """
    view = st.slice
    sl, problem = view.slice, view.problem
    if path is None:
        path = PathOnSlice(problem, sl, st.run_start, st.events)
        path.update()
    xy = phases = None
    run_minima = path.xy[path.minimum]
    if path.n:
        keep = path.thinned(most) if most else slice(None)
        xy, phases = path.xy[keep], list(path.phases[keep])
    current = project(problem, sl.T_center, sl.params, [st.T])[0]
    title = f"{st.source.name} → {st.target.name}: log10 E({sl.params[0]}, {sl.params[1]})"
    return sl, xy, phases, current, title, run_minima


class LandscapePanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.h = build(tab.gui)
        self.h.compute.on_click(tab.action(self.start))
        self.h.cancel.on_click(lambda e: self.cancel())
        self.h.terrain.on_update(lambda e: tab.guarded(self.update_terrain))
        self.drawn_at = 0.0
        self.terrain: Terrain | None = None
        self.path: PathOnSlice | None = None  # the last run projected on the slice, shared by contour and terrain
        self.terrain_lock = threading.Lock()  # one drawer at a time (a checkbox, a replay and the refresher may
        # race): guards the terrain and the path; taken before the state's lock, never inside it

    def start(self) -> None:
        """Compute the slice typed in the panel around the shown pose (automatic spans cover the run's start)."""
        st, h = self.state, self.h
        st.require_scans()
        params = (h.param_a.value, h.param_b.value)
        if params[0] == params[1]:
            raise InputError("choose two different parameters for the slice")
        steps = parse_setting(h.steps.value, "steps", "Steps")
        typed = [parse_number(s.value, f"span {k}", Range(0)) for s, k in ((h.span_a, "A"), (h.span_b, "B"))]
        with st.lock:
            problem, center, start = st.problem, (st.T if not st.running else st.T_init), st.run_start
            reach = np.abs(project(problem, center, params, [start])[0])
            # automatic spans: the initial uncertainty, widened to take in where the run started
            spans = tuple(float(s) or max(default_span(problem, n), COVER * float(r))
                          for s, n, r in zip(typed, params, reach))
        self.compute_at(center, params, spans, steps)

    def compute_at(self, center, params: tuple[str, str], spans: tuple[float, float], steps: int,
                   terrain: bool = False, problem: Problem | None = None) -> None:
        """Compute the slice of E over ``params`` (+- ``spans``, ``steps`` per axis) around pose ``center`` (4, 4) on
        a worker thread; the panel's fields say what was asked. ``terrain``: show it as the 3-D terrain too;
        ``problem``: the overlap cut to evaluate E on (default: the page's, under the initial guess)."""
        st, h = self.state, self.h
        if not all(np.isfinite(s) and s > 0 for s in spans):
            raise InputError(f"spans must be positive numbers, got {spans}")
        with st.lock:
            if st.slice_busy:
                raise InputError("a slice is already being computed")
            problem, pair = problem or st.problem, st.pair
            st.slice_busy, st.slice_cancel = True, threading.Event()
            cancel = st.slice_cancel
        h.param_a.value, h.param_b.value = params
        h.steps.value = str(steps)
        if terrain:
            h.terrain.value = True
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

    def _path(self, view: SliceView, events: list, start: np.ndarray) -> PathOnSlice:
        """The events projected on the slice, brought up to date (under terrain_lock)."""
        if self.path is None or not self.path.follows(view.problem, view.slice, start, events):
            self.path = PathOnSlice(view.problem, view.slice, start, events)
        self.path.update()
        return self.path

    def draw(self, terrain: bool = True) -> None:
        """Draw (or redraw) the slice with the run's path so far; and the terrain, unless ``terrain`` is False (the
        refresher keeps it in step during a run)."""
        st = self.state
        with st.lock:
            if st.slice is None:
                return
            view, events, start, units = st.slice, st.events, st.run_start, st.target.units
        self.drawn_at = time.monotonic()
        if terrain:
            self.update_terrain()
        with self.terrain_lock:
            path = self._path(view, events, start)
            with st.lock:
                if st.slice is not view:
                    return
                args = picture(st, path, MAX_FIGURE_PATH)
        *args, run_minima = args
        fig = slice_figure(*args, units=units, run_minima=run_minima)
        if self.h.plot is None:
            with self.h.folder:
                # first in its folder, above the slice's fields: the picture is what a class looks at
                self.h.plot = self.tab.gui.add_plotly(fig, aspect=1.2, order=self.h.param_a.order - 0.5)
        else:
            self.h.plot.figure = fig
            if not self.h.plot.visible:
                self.h.plot.visible = True
        self.tab.lesson.slice_drawn(view, fig)

    def forget(self) -> None:
        """A new pair: the old pair's slice is gone (TabState.slice), and its picture with it (the corner's contour,
        its path and the title naming its scans stayed on the Landscape tab beside the bunny)."""
        if self.h.plot is not None and self.h.plot.visible:
            self.h.plot.visible = False

    def update_terrain(self) -> None:
        """The 3-D terrain of the current slice with the path so far, when shown; gone otherwise."""
        with self.terrain_lock:
            self._update_terrain()

    def mark_terrain(self, T) -> None:
        """Move the terrain's marker of the shown pose (replay)."""
        with self.terrain_lock:
            if self.terrain is not None:
                self.terrain.mark(T)

    def follow(self, T, path: bool) -> None:
        """During a run (the refresher, inside its push): the marker to the shown pose ``T``, and the path so far when
        ``path``. Nothing when no terrain is shown or it is out of date (update_terrain rebuilds it)."""
        with self.terrain_lock:
            terrain = self.terrain
            if terrain is None:
                return
            if terrain.path is not self.path or terrain.path.events is not self.state.events:
                self._update_terrain()  # a new run (or slice): its own path
            else:
                terrain.update(T, path=path)

    def _update_terrain(self) -> None:
        st, tab = self.state, self.tab
        with st.lock:
            view, events, start, T, units = st.slice, st.events, st.run_start, st.T, st.target.units if st.target else ""
        if not self.h.terrain.value or view is None or tab.nodes is None:
            if self.terrain is not None:
                self.terrain.remove()
                self.terrain = None
            return
        path = self._path(view, events, start)  # outside atomic(): a long run's first projection takes a while
        appears = self.terrain is None or self.terrain.view is not view
        with tab.client.atomic():
            if appears:
                if self.terrain is not None:
                    self.terrain.remove()
                self.terrain = Terrain(tab.client.scene, view, units, start, events, path=path)
            elif self.terrain.path is not path:
                self.terrain.path, self.terrain.drawn = path, -1
            self.terrain.update(T)
        if appears:
            tab.fit_view()  # a new terrain comes into view beside the scans
