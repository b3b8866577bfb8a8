"""The Run panel: the method buttons, Step / Next phase / Pause / Resume / Cancel / Reset, E's chart, the settings."""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot as uplot
from rangereg.app.figures import PHASE_LABEL, PHASE_NAMES, PHASE_RGB, fmt, hex_colour, squared_unit, tidy
from rangereg.app.options import Settings
from rangereg.app.runner import Run
from rangereg.app.tab.settings import (
    FRUSTUM,
    LOCK_LABEL,
    NO_GUESS_LABEL,
    NUMBERS,
    SettingsHandles,
    guess_text,
    page_config,
    page_guess,
    read_number,
    read_settings,
)
from rangereg.app.tab.state import TabState
from rangereg.app.views import Trail
from rangereg.core.errors import InputError
from rangereg.core.frustum import KINDS
from rangereg.core.register import register
from rangereg.core.result import StopReason
from rangereg.core.trace import TraceHeader

GLOBAL_BUTTON = "Run global"  # the default method, first: any start, trusted or said not to be
PAPERS_FOLDER = "The paper's methods"  # ICP, annealing and their hybrid round the initial pose (teaching, debugging)
RUN_BUTTONS = {GLOBAL_BUTTON: "global", "Run hybrid": "hybrid", "Run ICP": "icp", "Run SA": "sa",
               "ICP restarts": "icp-restarts", "Basin hopping": "basin-hopping"}


@dataclass(eq=False)
class RunHandles:
    run: dict[str, viser.GuiButtonHandle]
    step: viser.GuiButtonHandle
    next_phase: viser.GuiButtonHandle
    pause: viser.GuiButtonHandle
    resume: viser.GuiButtonHandle
    cancel: viser.GuiButtonHandle
    reset: viser.GuiButtonHandle
    plot: viser.GuiUplotHandle
    settings: SettingsHandles


def _series(label: str, phase: str, size: int, rgb: tuple[int, int, int] | None = None) -> uplot.Series:
    c = hex_colour(rgb or PHASE_RGB[phase])
    return uplot.Series(label=label, stroke=c, width=0, points=uplot.Series_Points(show=True, size=size, fill=c, stroke=c))


# E spans decades: the chart draws log10 E (Trail.plot) on linear axes, whose ticks uPlot spaces itself (its own
# log axis, distr 3, stacked a tick on every 1-9 of each decade and printed E below 0.01 as '0'). The threshold is a
# dashed line; annealing's temperature is in E's units, so it shares E's axis: an uphill move of about the
# temperature is what annealing may still take
CHART_SCALES = {"x": uplot.Scale(time=False, auto=True), "y": uplot.Scale(auto=True)}
CHART_TITLE = "log10 E against iteration"
THRESHOLD_RGB = (200, 30, 30)
TEMPERATURE_RGB = (110, 110, 110)
RESULT_RGB = (20, 20, 20)
CHART_ASPECT = 3.2  # width / height: at 1280 x 720 the tabs, the Lesson's Next and its sentence stay above the
# fold (2.0 pushed the tabs below it)


def chart_axes(units: str = "") -> tuple:
    """The chart's axes, labelled in the scans' units: iteration, and log10 of E, the threshold and annealing's
    temperature."""
    return (uplot.Axis(label="iteration", size=30, labelSize=18),
            uplot.Axis(label=f"log10 E ({squared_unit(units)})", size=46, space=24, labelSize=18))


CHART_AXES = chart_axes()


def build_chart(gui: viser.GuiApi, units: str = "", order: float | None = None) -> viser.GuiUplotHandle:
    """E against iteration, coloured by phase, with the threshold, the temperature (points: it has none during ICP,
    and a line joined its legs across every ICP leg) and the result's level (:meth:`RunPanel.chart_data`); its axes
    in ``units``, at ``order`` among the panel's elements (None: after the last)."""
    return gui.add_uplot(order=order,
        data=(np.arange(2.0), *(np.ones(2) for _ in PHASE_NAMES), np.ones(2), np.ones(2), np.ones(2)),
        # points, not lines: each phase leaves gaps where the others ran (one series per phase, Trail.plot)
        series=(uplot.Series(label="iteration"), *(_series(PHASE_LABEL[p], p, 5 if p == "icp" else 3)
                                                   for p in PHASE_NAMES),
                uplot.Series(label="threshold", stroke=hex_colour(THRESHOLD_RGB), width=1.5, dash=(6.0, 4.0),
                             points=uplot.Series_Points(show=False)),
                _series("temperature", "", 2, TEMPERATURE_RGB),
                uplot.Series(label="result", stroke=hex_colour(RESULT_RGB), width=1.0,
                             points=uplot.Series_Points(show=False))),
        scales=CHART_SCALES, axes=chart_axes(units), title=CHART_TITLE, aspect=CHART_ASPECT,
        legend=uplot.Legend(live=False), padding=(14, 12, 0, 0))


def build(gui: viser.GuiApi, plot: viser.GuiUplotHandle) -> RunHandles:
    run = {GLOBAL_BUTTON: gui.add_button(GLOBAL_BUTTON, hint="the default method: poses from the initial one and "
                                         "from the scans' features, each refined and tested by the pair threshold")}
    pause = gui.add_button("Pause", disabled=True)
    resume = gui.add_button("Resume", disabled=True)
    cancel = gui.add_button("Cancel", disabled=True)
    reset = gui.add_button("Reset", hint="back to the initial pose; clear the path")
    with gui.add_folder(PAPERS_FOLDER):
        gui.add_markdown("ICP, annealing and their hybrid (Luck et al. 2000) search round the initial pose: for "
                         "teaching and for debugging a local minimum. Step and Next phase walk a hybrid run.")
        run.update({label: gui.add_button(label) for label in RUN_BUTTONS if label != GLOBAL_BUTTON})
        step = gui.add_button("Step", hint="one ICP iteration or one annealing move, then pause")
        next_phase = gui.add_button("Next phase", hint="run to the end of this ICP or SA leg, then pause")
    lock = gui.add_text(LOCK_LABEL, "", hint="what the search may not move, e.g. rx,ry,tz (a turntable about "
                        "y: rx,rz,tx,ty,tz), rotation, translation, or turntable:px,py,pz,dx,dy,dz (an axis in the "
                        "target's frame, its units); empty: all six free")
    with gui.add_folder("Settings", expand_by_default=False):
        numbers = {name: gui.add_text(f.label, f.initial, hint=f.full_hint(name)) for name, f in NUMBERS.items()}
        settings = SettingsHandles(
            numbers=numbers, frustum=gui.add_dropdown("Frustum", KINDS, initial_value=FRUSTUM),
            coarse_to_fine=gui.add_checkbox("Coarse to fine", False), polish=gui.add_checkbox("Unweighted polish", False),
            lock=lock, no_guess=gui.add_checkbox(NO_GUESS_LABEL, False, hint="Run global takes the initial pose as "
                                                 "saying nothing: any rotation, any translation that makes the scans "
                                                 "overlap (the paper's methods keep their search round the pose)"))
    return RunHandles(run, step, next_phase, pause, resume, cancel, reset, plot, settings)


def page_advice(r) -> str:
    """What the user can do on the page about a result that is not trusted ('' when it is)."""
    if r.below_threshold:
        return ""
    if r.details is None:  # the paper's methods search round the initial pose only
        return ("Run global (any start; it tests the pose it finds), or set a better initial pose (drag the gizmo, "
                "or Align from point pairs) and run again")
    return ("state how far off the initial pose may be in Settings (Rotation / Translation uncertainty, or No "
            "guess), or set a better initial pose (drag the gizmo, or Align from point pairs) and run again")


def result_line(r, units: str = "", off: tuple[float, float] | None = None) -> str:
    """The Finished line (HTML): trust first, then E, why it stopped and the time; the distance from the truth when
    the scene knows it (``off``: degrees, units); what to do only when the pose is not trusted. A cancelled run
    did not finish: its line leads with the cancel (:func:`cancelled_line`)."""
    u = squared_unit(units)
    truth = f" · {fmt(off[0], 2)}° and {fmt(off[1], 2)} {html.escape(units)} from the truth" if off else ""
    if r.stop_reason is StopReason.CANCELLED:
        return cancelled_line(r, u, truth)
    trusted = r.below_threshold
    head = f"<b>Finished: trust {'yes' if trusted else 'no'}</b>: {html.escape(tidy(r.trust_text))}"
    body = f"E = {fmt(r.error)} {u} · stopped: {html.escape(tidy(r.stop_text))} · {r.seconds:.2f} s{truth}"
    advice = page_advice(r)
    return f"{head}<br>{body}" + (f'<br><b style="color:#b00">What to do:</b> {html.escape(advice)}' if advice else "")


def cancelled_line(r, u: str, truth: str) -> str:
    """A cancelled run's line (HTML): where it was cancelled and E there, the pose it left (not judged: the search did
    not end), then its steps and time. The global method gives back its initial pose when cancelled (core.global_search),
    the paper's methods their best pose so far."""
    it = r.iterations
    pose = "the initial pose kept" if r.found_by == "guess" else "the best pose so far"  # as status.E_LABEL
    steps = f"ICP {it.icp}, SA {it.sa}" + (f", candidates {it.candidates}" if it.candidates else "")
    return (f"<b>Cancelled at iteration {it.total}</b>: E = {fmt(r.error)} {u}, {pose} (not trusted)"
            f"<br>{steps} · {r.seconds:.2f} s{truth}")


class RunPanel:
    def __init__(self, tab, chart: viser.GuiUplotHandle):
        """``chart``: the E chart, built above the panel's tabs (build_chart) so that it shows whatever tab is open."""
        self.tab, self.state = tab, tab.state
        self.h = h = build(tab.gui, chart)
        action = tab.action
        for label, method in RUN_BUTTONS.items():
            h.run[label].on_click(action(self.start, method))
        h.step.on_click(action(self.step))
        h.next_phase.on_click(action(self.next_phase))
        h.pause.on_click(lambda e: self.control(Run.pause))
        h.resume.on_click(lambda e: self.control(Run.resume))
        h.cancel.on_click(lambda e: self.control(Run.cancel))
        h.reset.on_click(action(self.reset))
        h.settings.frustum.on_update(lambda e: tab.guarded(tab.reprepare))
        h.settings.numbers["max_points"].on_update(lambda e: self._sample_size_typed())
        for field_ in (h.settings.numbers["rotation_uncertainty"], h.settings.numbers["translation_uncertainty"],
                       h.settings.no_guess):  # the status names the stated region: said as it is typed
            field_.on_update(lambda e: tab.update_status())

    def _sample_size_typed(self) -> None:
        """A new sample size re-cuts the overlap once it is a valid number (half-typed ones wait for the run)."""
        try:
            read_number(self.h.settings, "max_points")
        except InputError:
            return
        self.tab.guarded(self.tab.reprepare)

    def settings(self) -> Settings:
        """The settings as typed (InputError naming a bad field); each Run button adds its method."""
        return read_settings(self.h.settings)

    def guess_line(self) -> str:
        """The status line's word on the initial pose: its stated region as Run global takes it."""
        st = self.state
        if st.source is None or st.target is None:
            return "Guess -"
        try:
            return f"Guess (Run global): {guess_text(self.settings(), st.T_init, st.source, st.target)}"
        except InputError as exc:
            return f"Guess: - ({exc})"

    def use_lesson_settings(self, seed: int) -> None:
        """The lesson's run (app/tab/lesson.py): the defaults, as ``rangereg bench --lesson`` runs, with its seed."""
        h = self.h.settings
        for name, field_ in NUMBERS.items():
            h.numbers[name].value = str(seed) if name == "seed" else field_.initial
        h.frustum.value, h.coarse_to_fine.value, h.polish.value, h.lock.value = FRUSTUM, False, False, ""
        h.no_guess.value = False

    def threshold_typed(self) -> bool:
        """Whether Settings' threshold is a number typed (not auto)."""
        return str(self.h.settings.numbers["threshold"].value).strip().lower() not in ("", "auto")

    def chart_data(self, trail: Trail, result=None) -> tuple[np.ndarray, ...]:
        """The chart's series (build_chart): Trail.chart's, then the result's E as a level over every iteration (a
        global run refines several candidates and may end on one it does not keep: the level shows which leg
        reached the result; a cancelled run has none). Every series starts with a number (uPlot takes a series' range
        from its first value); a lone first point draws no line. An empty run gets an x range of [0, 1]."""
        st = self.state
        it, *series = trail.chart(st.E0, st.threshold)
        ok = result is not None and result.error is not None and np.isfinite(result.error) and result.error > 0 \
            and result.stop_reason is not StopReason.CANCELLED  # a cancelled run has no result to draw
        level = np.full(len(it), np.log10(result.error) if ok else np.nan)
        if not ok:
            level[0] = series[0][0]
        if len(it) < 2:
            it, series, level = np.r_[it, 1.0], [np.r_[s_, np.nan] for s_ in series], np.r_[level, np.nan]
            series[-2][-1] = series[-2][0]  # the threshold across the empty chart
        return it, *series, level

    def lock_text(self) -> str:
        """The locked parameters as typed ("" when all six are free)."""
        return self.h.settings.lock.value.strip()

    def start(self, method: str, mode: str = "run", lesson: bool = False) -> None:
        """Run ``method`` from the initial pose; ``lesson``: the Lesson tab's run (any other run ends the lesson)."""
        st = self.state
        st.require_scans()
        st.require_idle()
        if not lesson:
            self.tab.lesson.forget()
        cfg = page_config(self.settings(), method)
        with st.lock:
            source, target, T_init, surface = st.source, st.target, st.T_init, st.problem.surface
            guess = page_guess(self.settings(), T_init, method)

            def work(listener):
                # each run cuts its own overlap (the paper's methods; the global method cuts per candidate) on
                # the target surface the page made once
                return register(source, target, guess, cfg, listener, surface=surface)

            st.reset_run(T_init)
            st.run_method = method
            st.run_header = TraceHeader.of(source, target, guess, cfg)  # the exported trace's first line
            st.run = run = Run(work, mode=mode, on_done=self._done)
            st.events = run.events
        self.tab.nodes.gizmo.visible = False
        self.set_controls(running=True)
        run.start()
        self.tab.model.residuals.refresh()  # a moving scan drops its residual colours

    def _done(self, run: Run) -> None:
        """On the run's thread: hand the outcome to the refresher (the state's owner)."""
        if run.failure is not None:
            self.tab.notify("The run failed", str(run.failure))

        def apply(st: TabState) -> None:
            if st.run is not run or st.events is not run.events:
                return  # a newer run, a reset or a new pair took over: this outcome is stale
            st.result = run.result
            if run.failure is not None:
                st.finished_text = f"<b>Finished: the run failed</b>: {html.escape(str(run.failure))}"
                return
            r = run.result
            st.T, st.threshold = r.transform, r.threshold
            off = None
            if st.T_truth is not None and r.transform is not None:
                from rangereg.core.transforms import pose_error

                off = pose_error(r.transform, st.T_truth, st.source.centroid)
            st.finished_text = result_line(r, st.target.units, off)

        self.state.hand(apply)

    def control(self, action) -> None:
        """``action(run)``: Run.pause, .resume or .cancel; said on the page at once (not at the next push)."""
        run = self.state.run
        if run is None:
            return
        action(run)
        if self.state.running:
            self.tab.update_status()

    def step(self) -> None:
        if self.state.running:
            self.state.run.step()
        else:
            self.start("hybrid", mode="step")

    def next_phase(self) -> None:
        if self.state.running:
            self.state.run.next_phase()
        else:
            self.start("hybrid", mode="phase")

    def reset(self) -> None:
        run = self.state.run
        if run is not None:
            run.cancel()
            run.join(2.0)
        self.tab.set_initial(self.state.T_init)
        self.tab.update_status()

    def set_controls(self, running: bool) -> None:
        """Lock what a run holds; the tab's other panels follow."""
        h = self.h
        for b in [*h.run.values(), h.settings.frustum, h.settings.numbers["max_points"], h.settings.lock]:
            b.disabled = running
        h.pause.disabled = h.resume.disabled = h.cancel.disabled = not running
        self.tab.run_drawing = running
        self.tab.lock_panels(running)

    def show_paused(self, paused: bool) -> None:
        """While a run holds the controls: Pause while it moves, Resume while it is paused."""
        self.h.pause.disabled, self.h.resume.disabled = paused, not paused
