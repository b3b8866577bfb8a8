"""The Lesson tab: the paper's Fig. 7 on the ribbed corner, one click at a time.

The class opens the lesson's scene at one of its starts (core.scenes.LESSON), sees the slice of E through the
truth as a contour and a terrain (the small minima in the larger pit), and clicks Next through the hybrid:

    1 ICP runs                 the run starts in "phase" mode and pauses where ICP's first leg ends
    2 stuck above the threshold  (nothing runs: what the red marker means)
    3 annealing roams          Next phase: annealing's leg to its end, the temperature falling (the run pauses
                               before ICP's next leg: the page shows annealing's last move, its lower point)
    4 a lower point            (nothing runs: annealing hands a point below ICP's minimum to ICP)
    5 ICP again                Next phase: ICP's next leg to its end; above the threshold -> 2 again
    6 below the threshold      Resume: the run ends (re-cut and refined at the pose found)

Each step is one sentence. The run is the Run panel's (app/runner.py's pause, Next phase, Resume; the
refresher draws it), seeded as ``rangereg bench --lesson`` seeds that start, so the page shows the bench's run.
:class:`Story` is the step machine, with no viser in it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import viser
from rangereg.app.figures import fmt, squared_unit
from rangereg.app.tab.settings import page_guess, problem_config
from rangereg.app.tab.status import Progress
from rangereg.app.views import temperature_of
from rangereg.core.errors import InputError
from rangereg.core.events import Event
from rangereg.core.problem import prepare

STEPS = ("start", "icp", "stuck", "anneal", "lower", "icp-again", "below", "gave-up")
TITLES = {"start": "The start", "icp": "ICP runs", "stuck": "Stuck above the threshold",
          "anneal": "Annealing roams, temperature falling", "lower": "A lower point", "icp-again": "ICP again",
          "below": "Below the threshold", "gave-up": "Annealing gave up"}
CONTOUR_TITLE = "Lesson: contour"  # the panel's tab strip cuts a longer title at 360 px
CONTOUR_PANEL_WIDTH = 360  # pixels: the contour beside the scene (the canvas keeps 440 px at 1280 x 720)
CONTOUR_ASPECT = 1.3  # height / width (viser draws a Plotly figure width x aspect high): room under the contour for its
# legend (5 entries at the stuck step)
NUMBERS = {"start": 0, "icp": 1, "stuck": 2, "anneal": 3, "lower": 4, "icp-again": 5, "below": 6, "gave-up": 6}


@dataclass(frozen=True)
class Leg:
    """One leg of a run: its phase, number, events, E at its first and last event, its lowest E, annealing's first
    and last temperature (NaN for ICP), and whether it ended in a marked local minimum."""

    phase: str
    number: int
    events: int
    E_first: float
    E_last: float
    E_best: float
    T_first: float
    T_last: float
    minimum: bool


def legs(events: list[Event]) -> list[Leg]:
    """The run's legs in order (consecutive events of one phase and leg number)."""
    out: list[Leg] = []
    start = 0
    for k in range(1, len(events) + 1):
        if k == len(events) or (events[k].phase, events[k].leg) != (events[start].phase, events[start].leg):
            part = events[start:k]
            temps = [t for t in (temperature_of(e) for e in part) if np.isfinite(t)]
            E = [e.error for e in part]
            out.append(Leg(part[0].phase, part[0].leg, len(part), E[0], E[-1], min(E),
                           temps[0] if temps else float("nan"), temps[-1] if temps else float("nan"),
                           any(e.local_minimum for e in part)))
            start = k
    return out


@dataclass
class Story:
    """Where the class is in the lesson and what the next click does.

    ``advance(run)`` takes the run's state ("idle", "running", "paused", "finished") and the run's legs so far,
    moves to the next step when the run is where that step begins, and returns the action for the page:
    "start" (the hybrid, pausing at the end of ICP's first leg), "next" (Next phase), "resume" or None.
    """

    step: str = "start"
    history: list[str] = field(default_factory=list)

    def ready(self, run: str) -> bool:
        """Whether Next may be clicked: the run is not moving and the lesson is not over (at "below", a paused run
        still has its refinement to finish)."""
        if run == "running" or self.step == "gave-up":
            return False
        return run == "paused" if self.step == "below" else True

    def advance(self, run: str, run_legs: list[Leg], threshold: float) -> str | None:
        if not self.ready(run):
            return None
        step, action = self._next(run, run_legs, threshold)
        self.history.append(step)
        self.step = step
        return action

    def _next(self, run: str, run_legs: list[Leg], threshold: float) -> tuple[str, str | None]:
        last = run_legs[-1] if run_legs else None
        if self.step == "start":
            return "icp", "start"
        if self.step in ("icp", "icp-again"):
            icp = next((leg for leg in reversed(run_legs) if leg.phase == "icp"), None)
            if icp is not None and icp.E_best < threshold:
                return "below", "resume" if run == "paused" else None
            return "stuck", None
        if self.step == "stuck":
            return "anneal", "next"
        if self.step == "anneal":
            if run == "finished" or last is None:
                return "gave-up", None  # annealing cooled down without a point below ICP's minimum: the run ended
            return "lower", None  # paused where annealing's leg ended: on its lower point, ICP's next leg held
        if self.step == "lower":
            return "icp-again", "next"
        return "below", "resume"  # "below", paused: let the run finish


@dataclass(frozen=True)
class Facts:
    """What a sentence may quote: the threshold and units as the status shows them, the start's coordinates on the
    slice (as the contour draws it: tx in the scans' units, ry in degrees), the run as the status shows it
    (app/tab/status.Progress: the same counts, E and temperatures), whether it is over and how far from the truth
    it ended (degrees, units; as the Finished line says)."""

    threshold: float
    units: str
    start: tuple[float, float]
    progress: Progress = field(default_factory=Progress)
    finished: bool = False
    off: tuple[float, float] | None = None
    chosen: tuple[float, float] | None = None  # the start as the Start dropdown names it (core.scenes.Lesson.starts)


def sentence(step: str, f: Facts) -> str:
    """The one sentence of a step (markdown), numbered as in the module's table; each number is one the status
    (or, for the start, the contour) shows, written as it writes it."""
    u = squared_unit(f.units)
    p = f.progress
    head = f"**{NUMBERS[step]} · {TITLES[step]}.** "
    if step == "start":
        # the dropdown's shift is about the source's centre, the slice's tx about the overlap's (the turn is the same
        # about either): one start, two tx, and the sentence names both so that neither reads as a mistake
        chosen = "" if f.chosen is None else (
            f" (the Start's {fmt(f.chosen[0])} {f.units} is about the source's centre, the slice's about the overlap's)")
        return head + (f"On the slice the source (orange) starts at tx = {fmt(f.start[0])} {f.units} and ry = "
                       f"{fmt(f.start[1])}°, the white cross on the contour{chosen}; Next runs ICP.")
    if step == "icp":
        return head + ("Each iteration pairs every source point with the closest point on the target surface and "
                       "moves the scan to fit those pairs: downhill on E, the green path.")
    if step == "stuck":
        return head + (f"ICP has stopped at E = {fmt(p.E)} {u} after {p.n_icp} ICP iterations, above the threshold "
                       f"{fmt(f.threshold)} {u}: a local minimum (the red marker on the path and the contour), not "
                       "the registration.")
    if step == "anneal":
        return head + ("The simplex also takes uphill moves, fewer as the temperature falls, so it can leave the "
                       "minimum: the magenta path.")
    if step == "lower":
        if p.last is None or p.last.phase != "sa" or not np.isfinite(p.temperature):
            return head + "Annealing found a point lower than ICP's minimum: ICP takes over from there."
        return head + (f"After {p.n_sa} annealing moves, the temperature falling from {fmt(p.temperature_first)} to "
                       f"{fmt(p.temperature)} {u}, annealing found E = {fmt(p.E)} {u}, below ICP's minimum at "
                       f"{fmt(p.minimum_E)} {u}: ICP takes over from there.")
    if step == "icp-again":
        return head + "From annealing's point ICP runs downhill again, to the minimum nearest it."
    if step == "below":
        where = (f", {fmt(f.off[0], 2)}° and {fmt(f.off[1], 2)} {f.units} from the truth" if f.off is not None
                 else "")
        return head + (f"E = {fmt(p.E)} {u} is below the threshold {fmt(f.threshold)} {u}: registered{where}, in "
                       f"{p.n_icp} ICP and {p.n_sa} SA iterations." + ("" if f.finished else
                                                                       " Click Next to let the run finish."))
    if step == "gave-up":
        return head + ("Annealing cooled down without finding a point below ICP's minimum: the run ends above the "
                       "threshold.")
    return head


@dataclass(eq=False)
class LessonHandles:
    intro: viser.GuiMarkdownHandle
    start: viser.GuiDropdownHandle
    open: viser.GuiButtonHandle
    next: viser.GuiButtonHandle
    again: viser.GuiButtonHandle
    text: viser.GuiMarkdownHandle
    terrain: viser.GuiButtonHandle
    plot: viser.GuiPlotlyHandle | None = None  # the contour with the run's path, made with the lesson's slice


def start_label(k: int, start: tuple[float, float], units: str = "mm") -> str:
    return f"{k}: {fmt(start[0])} {units}, {fmt(start[1])}°"


class LessonPanel:
    """The Lesson tab's controls, its sentence and its contour; the run, the chart and the terrain are the page's."""

    def __init__(self, tab):
        from rangereg.core.scenes import LESSON

        self.tab, self.state, self.lesson = tab, tab.state, LESSON
        gui = tab.gui
        labels = [start_label(k, s) for k, s in enumerate(LESSON.starts)]
        self.h = LessonHandles(
            intro=gui.add_markdown("The paper's Fig. 7 on a ribbed corner: ICP sticks, annealing frees it, ICP "
                                   "finishes."),
            start=gui.add_dropdown("Start", labels, initial_value=labels[LESSON.shown],
                                   hint="the lesson's starts: the truth shifted along tx and turned about ry, about "
                                   "the source's centre"),
            open=gui.add_button("Open the lesson", hint="the ribbed corner at this start, with the slice through the "
                                "truth as contour and terrain"),
            next=gui.add_button("Next", disabled=True),
            text=gui.add_markdown(""),
            again=gui.add_button("Start again", disabled=True, hint="back to the start, the slice kept"),
            terrain=gui.add_button("Look at the terrain", disabled=True,
                                   hint="the camera on the 3-D terrain alone (Fit view: the scans and the terrain)"))
        # the contour with the path, the picture the sentences speak of, in a panel of its own docked left of the
        # scene (made with the lesson's first slice): under the sentence, at 1280 x 720 it began 100 px below the fold
        self.where = gui.add_markdown("The contour with the run's path is in the panel left of the scene.",
                                      visible=False)
        self.panel: viser.PanelHandle | None = None
        self.panel_tab: viser.GuiTabHandle | None = None  # the panel's one tab: a line while the slice is computed, then
        self.computing: viser.GuiMarkdownHandle | None = None  # the contour
        self.story: Story | None = None
        self.k = LESSON.shown
        self.run = None  # the lesson's run (a Run), once started
        self.line = ""  # the step's sentence
        self.start_xy: tuple[float, float] = (float("nan"), float("nan"))  # the start on the slice (contour)
        self.view = None  # the lesson's slice (a SliceView), once computed
        self.h.open.on_click(tab.action(self.open))
        self.h.next.on_click(tab.action(self.next))
        self.h.again.on_click(tab.action(self.again))
        self.h.terrain.on_click(tab.action(self.look_at_terrain))

    @property
    def title(self) -> str:
        """The step's number and title ('' when no lesson is open): the status's Lesson line."""
        return f"{NUMBERS[self.story.step]} · {TITLES[self.story.step]}" if self.story is not None else ""

    # ---- the clicks ------------------------------------------------------------------------------------------------
    def open(self) -> None:
        """Load the lesson's scene at the chosen start, its run's seed, and the slice through the truth."""
        from rangereg.core.landscape import project

        st, tab = self.state, self.tab
        st.require_idle()
        self.k = int(str(self.h.start.value).split(":")[0])
        source, target = tab.wb.scene_pair(self.lesson.scene)
        tab.run_panel.use_lesson_settings(seed=self.k)
        tab.load_pair(source, target, scene=self.lesson.scene)
        tab.set_initial(self.lesson.start(st.source, st.target, self.k))
        # the slice through the truth, on the overlap cut there: the error surface the registration ends on, as in
        # the paper's Fig. 3 and 7 (under the start's cut the same grid shows 5 of its minima against 11)
        settings = tab.run_panel.settings()
        at_truth = prepare(st.source, st.target, page_guess(settings, st.T_truth), problem_config(settings),
                           surface=st.surfaces[1], seed=settings.seed)
        self.start_xy = tuple(float(v) for v in project(at_truth, st.T_truth, self.lesson.params, [st.T_init])[0])
        h = tab.landscape.h
        h.span_a.value, h.span_b.value = (fmt(v) for v in self.lesson.spans)
        self.view = None
        tab.landscape.compute_at(st.T_truth, self.lesson.params, self.lesson.spans, self.lesson.steps, terrain=True,
                                 problem=at_truth)
        self.story = Story()
        self.run = None
        self.h.again.disabled = False
        self.h.intro.visible = False  # room for the sentence under Next (at 1280 x 720, above the fold)
        self.show_contour(True)
        self.show()

    def again(self) -> None:
        """The same start once more: the run forgotten, the slice kept."""
        st = self.state
        if st.running:
            st.run.cancel()
            st.run.join(2.0)
        if self.story is None:
            return
        view = self.view
        self.tab.set_initial(self.lesson.start(st.source, st.target, self.k))  # forgets the lesson: taken back
        self.story, self.run, self.view = Story(), None, view
        self.h.again.disabled, self.h.intro.visible = False, False
        self.h.terrain.disabled = view is None
        if self.h.plot is not None and view is not None:
            self.show_contour(True)
            self.tab.landscape.draw()  # the contour without the forgotten run's path
        self.show()

    def next(self) -> None:
        st, panel = self.state, self.tab.run_panel
        if self.story is None:
            return
        with st.lock:
            events = list(st.events[:min(self.tab.trail().n, len(st.events))])  # the run as the status shows it
        action = self.story.advance(self.run_state(), legs(events), st.threshold or 0.0)
        if action == "start":
            panel.start("hybrid", mode="phase", lesson=True)
            self.run = st.run
        elif action == "next" and st.running:
            st.run.next_phase()
        elif action == "resume" and st.running:
            st.run.resume()
        self.show()

    def look_at_terrain(self) -> None:
        """Point the camera at the terrain alone, so that it fills the view."""
        from rangereg.app.tab import scene3d

        terrain = self.tab.landscape.terrain
        if terrain is None:
            raise InputError("no terrain is shown (Landscape: Show as 3-D terrain)")
        scene3d.fit_camera(self.tab.client, terrain.extent())

    # ---- what the page shows ---------------------------------------------------------------------------------------
    def run_state(self) -> str:
        st = self.state
        if self.run is None or st.run is not self.run:
            return "idle"
        if st.running:
            return "paused" if st.run.paused else "running"
        return "finished"

    def write(self, progress: Progress) -> None:
        """The step's sentence from the status's own Progress (Tab.update_status calls this as it writes the status)."""
        if self.story is None:
            return
        st = self.state
        with st.lock:
            threshold, units, result, T_truth, source = (st.threshold, st.target.units, st.result, st.T_truth,
                                                         st.source)
        finished = self.run_state() == "finished" and result is not None
        off = None
        if finished and T_truth is not None and result.transform is not None:
            from rangereg.core.transforms import pose_error

            off = pose_error(result.transform, T_truth, source.centroid)
        line = sentence(self.story.step, Facts(threshold or 0.0, units, self.start_xy, progress, finished, off,
                                                   self.lesson.starts[self.k]))
        if line != self.line:
            self.line = self.h.text.content = line

    def show(self) -> None:
        """Whether Next may be clicked (every click and refresher tick), and the sentence with the status."""
        if self.story is None:
            return
        run = self.run_state()
        done = self.story.step == "gave-up" or (self.story.step == "below" and run in ("finished", "idle"))
        disabled = done or not self.story.ready(run)
        if self.h.next.disabled != disabled:
            self.h.next.disabled = disabled
        if not self.line.startswith(f"**{self.title}."):
            self.tab.update_status()  # a new step: its sentence, and the status's Lesson line

    def slice_drawn(self, view, figure) -> None:
        """The Landscape panel drew ``figure`` of ``view``: the lesson's own slice is shown here too."""
        if self.story is None or view.problem is None:
            return
        if self.view is None:
            self.view = view  # the first slice drawn after Open the lesson is the lesson's
            self.h.terrain.disabled = False
        if view is not self.view:
            return
        if self.h.plot is None:
            self.show_contour(True)
            with self.panel_tab:
                self.h.plot = self.tab.gui.add_plotly(figure, aspect=CONTOUR_ASPECT)
            self.computing.visible = False
        else:
            self.h.plot.figure = figure
        self.show_contour(True)

    def show_contour(self, shown: bool) -> None:
        """The contour's panel beside the scene (docked as the lesson opens, so that the terrain, when it appears, is
        framed in the canvas left beside it), and the Lesson tab's line saying where it is."""
        if self.panel is None and shown:
            self.panel = self.tab.gui.add_panel()
            self.panel_tab = self.panel.add_tab(CONTOUR_TITLE)
            with self.panel_tab:
                self.computing = self.tab.gui.add_markdown("Computing the slice through the truth...")
            self.panel.dock_left()
            self.panel.set_width(CONTOUR_PANEL_WIDTH)
        if self.panel is not None and self.panel.visible != shown:
            self.panel.visible = shown
        if self.where.visible != shown:
            self.where.visible = shown

    def forget(self) -> None:
        """Another pair, pose or run was chosen outside the lesson: the lesson waits to be opened again."""
        if self.story is None:
            return
        self.story, self.run, self.line, self.view = None, None, "", None
        self.h.next.disabled = self.h.again.disabled = self.h.terrain.disabled = True
        self.h.text.content = ""
        self.h.intro.visible = True
        self.show_contour(False)
