"""The Run panel: the method buttons, Step / Next phase / Pause / Resume / Cancel / Reset, E's chart, the settings."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
import viser.uplot as uplot

from app.figures import PHASE_LABEL, PHASE_NAMES, PHASE_RGB, fmt, hex_colour, squared_unit, tidy
from app.runner import Run
from app.tab.fields import Range, parse_number, parse_optional
from app.tab.settings import PageSettings, page_config
from app.tab.state import TabState
from core.errors import InputError
from core.events import TraceHeader
from core.frustum import KINDS
from core.problem import prepare
from core.register import register

ANNEALS = "applies to Run hybrid and Run SA (the methods that anneal)"
SEED = Range(0, 2**63 - 1, integer=True)
RATIO = Range(0, 1, lo_open=True, hi_open=True)
RUN_BUTTONS = {"Run hybrid": "hybrid", "Run ICP": "icp", "Run SA": "sa", "ICP restarts": "icp-restarts",
               "Basin hopping": "basin-hopping", "Run global": "global"}


@dataclass(eq=False)
class SettingsHandles:
    threshold: viser.GuiTextHandle
    t_start: viser.GuiTextHandle
    t_min: viser.GuiTextHandle
    cooling: viser.GuiTextHandle
    seed: viser.GuiTextHandle
    icp_max: viser.GuiTextHandle
    sa_max: viser.GuiTextHandle
    frustum: viser.GuiDropdownHandle
    max_points: viser.GuiTextHandle
    coarse_to_fine: viser.GuiCheckboxHandle
    polish: viser.GuiCheckboxHandle
    lock: viser.GuiTextHandle


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


def _series(label: str, phase: str, size: int) -> uplot.Series:
    c = hex_colour(PHASE_RGB[phase])
    return uplot.Series(label=label, stroke=c, width=0, points=uplot.Series_Points(show=True, size=size, fill=c, stroke=c))


# E spans decades: the chart draws log10 E (Trail.plot) on linear axes, whose ticks uPlot spaces itself (its own
# log axis, distr 3, stacked a tick on every 1-9 of each decade and printed E below 0.01 as '0'). The threshold is a
# dashed line; annealing's temperature is in E's units, so it shares E's axis: an uphill move of about the
# temperature is what annealing may still take
CHART_SCALES = {"x": uplot.Scale(time=False, auto=True), "y": uplot.Scale(auto=True)}
CHART_TITLE = "log10 E against iteration"
THRESHOLD_RGB = (200, 30, 30)
TEMPERATURE_RGB = (110, 110, 110)


def chart_axes(units: str = "") -> tuple:
    """The chart's axes, labelled in the scans' units: iteration, and log10 of E, the threshold and annealing's
    temperature."""
    return (uplot.Axis(label="iteration", size=34),
            uplot.Axis(label=f"log10 E, temperature ({squared_unit(units)})", size=50, space=28))


CHART_AXES = chart_axes()


def build_chart(gui: viser.GuiApi) -> viser.GuiUplotHandle:
    """E against iteration, coloured by phase, with the threshold and the temperature (Trail.chart's series)."""
    return gui.add_uplot(
        data=(np.zeros(1), *(np.ones(1) for _ in PHASE_NAMES), np.ones(1), np.ones(1)),  # no first value may be NaN
        # points, not lines: each phase leaves gaps where the others ran (one series per phase, Trail.plot)
        series=(uplot.Series(label="iteration"), *(_series(PHASE_LABEL[p], p, 5 if p == "icp" else 3)
                                                   for p in PHASE_NAMES),
                uplot.Series(label="threshold", stroke=hex_colour(THRESHOLD_RGB), width=1.5, dash=(6.0, 4.0),
                             points=uplot.Series_Points(show=False)),
                uplot.Series(label="temperature", stroke=hex_colour(TEMPERATURE_RGB), width=1.5, dash=(2.0, 3.0),
                             points=uplot.Series_Points(show=False))),
        scales=CHART_SCALES, axes=CHART_AXES, title=CHART_TITLE, aspect=2.0)


def build(gui: viser.GuiApi, plot: viser.GuiUplotHandle) -> RunHandles:
    run = {label: gui.add_button(label) for label in RUN_BUTTONS}
    step = gui.add_button("Step", hint="one ICP iteration or one annealing move, then pause")
    next_phase = gui.add_button("Next phase", hint="run to the end of this ICP or SA leg, then pause")
    pause = gui.add_button("Pause", disabled=True)
    resume = gui.add_button("Resume", disabled=True)
    cancel = gui.add_button("Cancel", disabled=True)
    reset = gui.add_button("Reset", hint="back to the initial pose; clear the path")
    lock = gui.add_text("Locked parameters", "", hint="what the search may not move, e.g. rx,ry,tz (a turntable about "
                        "y: rx,rz,tx,ty,tz), rotation, translation, or turntable:px,py,pz,dx,dy,dz (an axis in the "
                        "target's frame, its units); empty: all six free")
    with gui.add_folder("Settings", expand_by_default=False):
        settings = SettingsHandles(
            threshold=gui.add_text("Threshold", "auto", hint="stop below this E; auto: from the scans' noise; "
                                   "0: search until annealing gives up"),
            t_start=gui.add_text("Start temperature", "auto",
                                 hint=f"auto: from the spread of E over the first simplex; {ANNEALS}"),
            t_min=gui.add_text("Minimum temperature ratio", "auto",
                               hint=f"annealing stops below this fraction of its start temperature, between 0 and 1; "
                                    f"auto: 0.01 for the hybrid, 1e-5 for annealing alone; {ANNEALS}"),
            cooling=gui.add_text("Cooling", "0.9", hint=f"temperature factor per block of moves, between 0 and 1; "
                                 f"{ANNEALS}"),
            seed=gui.add_text("Seed", "0", hint="a whole number >= 0: the same seed, the same run"),
            icp_max=gui.add_text("ICP iteration cap", "100", hint="iterations per ICP leg, >= 1"),
            sa_max=gui.add_text("SA evaluation cap", "20000", hint=f"evaluations of E per annealing leg, >= 7; {ANNEALS}"),
            frustum=gui.add_dropdown("Frustum", KINDS, initial_value="convex"),
            max_points=gui.add_text("Overlap sample size", "300", hint="source points in E, >= 3"),
            coarse_to_fine=gui.add_checkbox("Coarse to fine", False),
            polish=gui.add_checkbox("Unweighted polish", False),
            lock=lock)
    return RunHandles(run, step, next_phase, pause, resume, cancel, reset, plot, settings)


def read_settings(h: SettingsHandles) -> PageSettings:
    """The settings as typed on the page; a bad one raises InputError (never a clamped or rewritten value)."""
    return PageSettings(
        threshold=parse_optional(h.threshold.value, "threshold", Range(0)),
        t_start=parse_optional(h.t_start.value, "start temperature", Range(0, lo_open=True)),
        t_min_ratio=parse_optional(h.t_min.value, "minimum temperature ratio", RATIO),
        cooling=parse_number(h.cooling.value, "cooling", RATIO),
        seed=parse_number(h.seed.value, "seed", SEED),
        icp_max=parse_number(h.icp_max.value, "ICP iteration cap", Range(1, 10**6, integer=True)),
        sa_max=parse_number(h.sa_max.value, "SA evaluation cap", Range(7, 10**8, integer=True)),
        frustum=h.frustum.value,
        max_points=parse_number(h.max_points.value, "overlap sample size", Range(3, 10**7, integer=True)),
        coarse_to_fine=bool(h.coarse_to_fine.value), polish=bool(h.polish.value), lock=checked_lock(h.lock.value))


def checked_lock(text: str) -> str:
    """The lock as typed, once core takes it (a bad one raises InputError naming what is wrong)."""
    from app.options import parse_lock

    try:
        parse_lock(text.strip() or None)
    except InputError as exc:  # in the page's words: its field, not the CLI's flag
        raise InputError(f"Locked parameters: {str(exc).removeprefix('--lock: ')}") from None
    return text.strip()


class RunPanel:
    def __init__(self, tab, chart: viser.GuiUplotHandle):
        """``chart``: the E chart, built above the panel's tabs (build_chart) so that it shows whatever tab is open."""
        self.tab, self.state = tab, tab.state
        self.h = h = build(tab.gui, chart)
        guarded = tab.guarded
        for label, method in RUN_BUTTONS.items():
            h.run[label].on_click(lambda e, m=method: guarded(self.start, m))
        h.step.on_click(lambda e: guarded(self.step))
        h.next_phase.on_click(lambda e: guarded(self.next_phase))
        h.pause.on_click(lambda e: self.control(Run.pause))
        h.resume.on_click(lambda e: self.control(Run.resume))
        h.cancel.on_click(lambda e: self.control(Run.cancel))
        h.reset.on_click(lambda e: guarded(self.reset))
        h.settings.frustum.on_update(lambda e: guarded(tab.reprepare))
        h.settings.max_points.on_update(lambda e: self._sample_size_typed())

    def _sample_size_typed(self) -> None:
        """A new sample size re-cuts the overlap once it is a valid number (half-typed ones wait for the run)."""
        try:
            parse_number(self.h.settings.max_points.value, "overlap sample size", Range(3, 10**7, integer=True))
        except InputError:
            return
        self.tab.guarded(self.tab.reprepare)

    def settings(self) -> PageSettings:
        return read_settings(self.h.settings)

    def use_lesson_settings(self, seed: int) -> None:
        """The lesson's run (app/tab/lesson.py): the defaults, as ``rangereg bench --lesson`` runs, with its seed."""
        h = self.h.settings
        h.threshold.value, h.t_start.value, h.t_min.value, h.cooling.value = "auto", "auto", "auto", "0.9"
        h.seed.value, h.icp_max.value, h.sa_max.value, h.max_points.value = str(seed), "100", "20000", "300"
        h.frustum.value, h.coarse_to_fine.value, h.polish.value, h.lock.value = "convex", False, False, ""

    def lock_text(self) -> str:
        """The locked parameters as typed ("" when all six are free)."""
        return self.h.settings.lock.value.strip()

    def start(self, method: str, mode: str = "run") -> None:
        st = self.state
        st.require_scans()
        st.require_idle()
        cfg = page_config(self.settings(), method)
        with st.lock:
            source, target, T_init, surface = st.source, st.target, st.T_init, st.problem.surface

            def work(listener):
                # register widens the problem's error as it goes: each run gets its own prepared problem
                problem = prepare(source, target, T_init, cfg.problem, surface=surface, seed=cfg.seed)
                return register(source, target, T_init, cfg, listener, problem=problem)

            st.reset_run(T_init)
            st.run_method = method
            st.run_header = TraceHeader.of(source, target, T_init, cfg)  # the exported trace's first line
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
                st.finished_text = f"**Finished**: the run failed: {run.failure}"
                return
            r = run.result
            st.T, st.threshold = r.transform, r.threshold
            st.finished_text = (f"**Finished**: E = {fmt(r.error)}; trust {'yes' if r.below_threshold else 'no'}: "
                                f"{tidy(r.trust_text)}; stopped: {tidy(r.stop_text)}; {r.seconds:.2f} s")

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
        for b in [*h.run.values(), h.settings.frustum, h.settings.max_points, h.settings.lock]:
            b.disabled = running
        h.pause.disabled = h.resume.disabled = h.cancel.disabled = not running
        self.tab.run_drawing = running
        self.tab.lock_panels(running)

    def show_paused(self, paused: bool) -> None:
        """While a run holds the controls: Pause while it moves, Resume while it is paused."""
        self.h.pause.disabled, self.h.resume.disabled = paused, not paused
