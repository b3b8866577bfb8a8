"""The Lesson tab: the paper's Fig. 7 on the ribbed corner, one click at a time.

The class opens the lesson's scene at one of its starts (core.scenes.LESSON), sees the slice of E through the
truth as a contour and a terrain (the small minima in the larger pit), and clicks Next through the hybrid:

    1 ICP runs                 the run starts in "phase" mode and pauses where ICP's first leg ends
    2 stuck above the threshold  (nothing runs: what the red marker means)
    3 annealing roams          Next phase: annealing's leg to its end, the temperature falling
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
from rangereg.app.tab.settings import problem_config
from rangereg.app.views import temperature_of
from rangereg.core.events import Event
from rangereg.core.problem import prepare

STEPS = ("start", "icp", "stuck", "anneal", "lower", "icp-again", "below", "gave-up")
TITLES = {"start": "The start", "icp": "ICP runs", "stuck": "Stuck above the threshold",
          "anneal": "Annealing roams, temperature falling", "lower": "A lower point", "icp-again": "ICP again",
          "below": "Below the threshold", "gave-up": "Annealing gave up"}
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
            if run == "finished" or last is None or last.phase != "icp":
                return "gave-up", None  # annealing cooled down without a point below ICP's minimum
            return "lower", None
        if self.step == "lower":
            return "icp-again", "next"
        return "below", "resume"  # "below", paused: let the run finish


@dataclass(frozen=True)
class Facts:
    """What a sentence may quote: the threshold, the units, the shown start, the run's legs and its outcome."""

    threshold: float
    units: str
    start: tuple[float, float]  # (tx, ry) off the truth, in the scans' units and degrees
    run_legs: tuple[Leg, ...] = ()
    finished: bool = False
    error: float | None = None  # the result's E, once the run is over
    off: tuple[float, float] | None = None  # the result's distance from the truth (degrees, units)
    iterations: tuple[int, int] | None = None  # the result's (ICP, SA) iterations


def sentence(step: str, f: Facts) -> str:
    """The one sentence of a step (markdown), numbered as in the module's table."""
    u = squared_unit(f.units)
    icp = [leg for leg in f.run_legs if leg.phase == "icp"]
    sa = [leg for leg in f.run_legs if leg.phase == "sa"]
    head = f"**{NUMBERS[step]} · {TITLES[step]}.** "
    if step == "start":
        return head + (f"The source (orange) lies {fmt(f.start[0])} {f.units} along tx and {fmt(f.start[1])}° "
                       "about ry from the truth. Click Next: ICP runs from here.")
    if step == "icp":
        return head + ("Each iteration pairs every source point with the closest point on the target surface and "
                       "moves the scan to fit those pairs: downhill on E, the green path.")
    if step == "stuck":
        stuck = [leg for leg in icp if leg.minimum]
        leg = stuck[-1] if stuck else (icp[-1] if icp else None)
        got = f"E = {fmt(leg.E_best)} {u} after {leg.events} iterations" if leg else "E"
        return head + (f"ICP has stopped at {got}, above the threshold {fmt(f.threshold)} {u}: a local minimum "
                       "(the red marker), not the registration.")
    if step == "anneal":
        return head + ("The simplex also takes uphill moves, fewer as the temperature falls, so it can leave the "
                       "minimum: the magenta path.")
    if step == "lower":
        leg = sa[-1] if sa else None
        k = f.run_legs.index(leg) if leg is not None else 0
        before = [g for g in f.run_legs[:k] if g.phase == "icp"]  # the ICP minimum annealing started from
        below = before[-1].E_best if before else float("nan")
        if leg is None:
            return head + "Annealing found a point lower than ICP's minimum."
        return head + (f"After {leg.events} moves, the temperature falling from {fmt(leg.T_first)} to "
                       f"{fmt(leg.T_last)} {u}, annealing found E = {fmt(leg.E_best)} {u}, below ICP's "
                       f"{fmt(below)} {u}: ICP takes over from there.")
    if step == "icp-again":
        return head + "From annealing's point ICP runs downhill again, to the minimum nearest it."
    if step == "below":
        E = f.error if f.error is not None else (icp[-1].E_best if icp else float("nan"))
        where = (f", {fmt(f.off[0], 2)}° and {fmt(f.off[1], 2)} {f.units} from the truth" if f.off is not None
                 else "")
        count = f", in {f.iterations[0]} ICP and {f.iterations[1]} SA iterations" if f.iterations else ""
        return head + (f"E = {fmt(E)} {u} is below the threshold {fmt(f.threshold)} {u}: registered{where}"
                       f"{count}." + ("" if f.finished else " Click Next to let the run finish."))
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


def start_label(k: int, start: tuple[float, float], units: str = "mm") -> str:
    return f"{k}: {fmt(start[0])} {units}, {fmt(start[1])}°"


class LessonPanel:
    """The Lesson tab's controls; the run, the chart, the slice and the terrain are the page's own."""

    def __init__(self, tab):
        from rangereg.core.scenes import LESSON

        self.tab, self.state, self.lesson = tab, tab.state, LESSON
        gui = tab.gui
        labels = [start_label(k, s) for k, s in enumerate(LESSON.starts)]
        self.h = LessonHandles(
            intro=gui.add_markdown("The paper's Fig. 7 on a ribbed corner: ICP sticks in a local minimum, annealing "
                                   "frees it, ICP finishes. Open the lesson, then click Next."),
            start=gui.add_dropdown("Start", labels, initial_value=labels[LESSON.shown],
                                   hint="the lesson's starts: shift along tx, turn about ry, from the truth"),
            open=gui.add_button("Open the lesson", hint="the ribbed corner at this start, with the slice through the "
                                "truth as contour and terrain"),
            next=gui.add_button("Next", disabled=True),
            again=gui.add_button("Start again", disabled=True, hint="back to the start, the slice kept"),
            text=gui.add_markdown(""))
        self.story: Story | None = None
        self.k = LESSON.shown
        self.run = None  # the lesson's run (a Run), once started
        self.line = ""  # the step's sentence, also shown in the status
        self.h.open.on_click(lambda e: tab.guarded(self.open))
        self.h.next.on_click(lambda e: tab.guarded(self.next))
        self.h.again.on_click(lambda e: tab.guarded(self.again))

    # ---- the clicks ------------------------------------------------------------------------------------------------
    def open(self) -> None:
        """Load the lesson's scene at the chosen start, its run's seed, and the slice through the truth."""
        st, tab = self.state, self.tab
        st.require_idle()
        self.k = int(str(self.h.start.value).split(":")[0])
        source, target = tab.wb.scene_pair(self.lesson.scene)
        tab.run_panel.use_lesson_settings(seed=self.k)
        tab.load_pair(source, target)
        tab.set_initial(self.lesson.start(st.source, st.target, self.k))
        # the slice through the truth, on the overlap cut there: the error surface the registration ends on, as in
        # the paper's Fig. 3 and 7 (under the start's cut the same grid shows 5 of its minima against 11)
        settings = tab.run_panel.settings()
        at_truth = prepare(st.source, st.target, st.T_truth, problem_config(settings), surface=st.surfaces[1],
                           seed=settings.seed)
        h = tab.landscape.h
        h.span_a.value, h.span_b.value = (fmt(v) for v in self.lesson.spans)
        tab.landscape.compute_at(st.T_truth, self.lesson.params, self.lesson.spans, self.lesson.steps, terrain=True,
                                 problem=at_truth)
        self.story = Story()
        self.run = None
        self.h.again.disabled = False
        self.show()

    def again(self) -> None:
        """The same start once more: the run forgotten, the slice kept."""
        st = self.state
        if st.running:
            st.run.cancel()
            st.run.join(2.0)
        if self.story is None:
            return
        self.tab.set_initial(self.lesson.start(st.source, st.target, self.k))
        self.tab.update_status()
        self.story, self.run = Story(), None
        self.show()

    def next(self) -> None:
        st, panel = self.state, self.tab.run_panel
        if self.story is None:
            return
        action = self.story.advance(self.run_state(), legs(list(st.events)), st.threshold or 0.0)
        if action == "start":
            panel.start("hybrid", mode="phase")
            self.run = st.run
        elif action == "next" and st.running:
            st.run.next_phase()
        elif action == "resume" and st.running:
            st.run.resume()
        self.show()

    # ---- what the page shows ---------------------------------------------------------------------------------------
    def run_state(self) -> str:
        st = self.state
        if self.run is None or st.run is not self.run:
            return "idle"
        if st.running:
            return "paused" if st.run.paused else "running"
        return "finished"

    def facts(self) -> Facts:
        st = self.state
        with st.lock:
            events, threshold, result, units = list(st.events), st.threshold, st.result, st.target.units
            T_truth, source = st.T_truth, st.source
        off = iterations = error = None
        finished = self.run_state() == "finished" and result is not None
        if finished:
            from rangereg.core.transforms import pose_error

            error, iterations = result.error, (result.iterations.icp, result.iterations.sa)
            if T_truth is not None:
                off = pose_error(result.transform, T_truth, source.centroid)
        return Facts(threshold or 0.0, units, self.lesson.starts[self.k], tuple(legs(events)), finished, error, off,
                     iterations)

    def show(self) -> None:
        """The step's sentence and whether Next may be clicked (called on every click and refresher tick)."""
        if self.story is None:
            return
        run = self.run_state()
        line = sentence(self.story.step, self.facts())
        if line != self.line:
            self.line = self.h.text.content = line
            self.tab.update_status()  # the status says the step too
        done = self.story.step == "gave-up" or (self.story.step == "below" and run in ("finished", "idle"))
        disabled = done or not self.story.ready(run)
        if self.h.next.disabled != disabled:
            self.h.next.disabled = disabled

    def forget(self) -> None:
        """Another pair or pose was chosen outside the lesson: the lesson waits to be opened again."""
        if self.story is None:
            return
        self.story, self.run, self.line = None, None, ""
        self.h.next.disabled = self.h.again.disabled = True
        self.h.text.content = ""
