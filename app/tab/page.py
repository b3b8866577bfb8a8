"""One browser tab of the workbench: its scans, its GUI, its runs. Tabs never share mutable state.

Everything the page does calls core: loading (core.io), the overlap (core.problem), the runs
(core.register through app.runner), the slice (core.landscape), the model (core.fuse). The panels
sit in viser tabs (Run, Lesson, Pose, Scans, Landscape, Model, Export), one module each, under the status, the
colour legend, Fit view and the E chart; the tab's state and its threading contract are in app/tab/state.py; the
refresher pushes a run's progress; the clicks' actions run in their order on one thread (app/tab/actions.py).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Coroutine
from typing import Any

import numpy as np
import viser
from rangereg.app.figures import fmt, legend_html, squared_unit
from rangereg.app.tab import scene3d, status
from rangereg.app.tab.actions import Actions
from rangereg.app.tab.export import ExportPanel
from rangereg.app.tab.landscape import LandscapePanel
from rangereg.app.tab.lesson import LessonPanel
from rangereg.app.tab.model import ModelPanel
from rangereg.app.tab.pairs import PairsPanel
from rangereg.app.tab.pose import PosePanel
from rangereg.app.tab.refresher import Refresher
from rangereg.app.tab.replay import ReplayPanel
from rangereg.app.tab.run import RunPanel, build_chart
from rangereg.app.tab.scans import ScansPanel
from rangereg.app.tab.settings import page_guess, problem_config
from rangereg.app.tab.state import TabState
from rangereg.app.views import Display, Trail
from rangereg.core.errors import InputError
from rangereg.core.frustum import KINDS, frustum_of
from rangereg.core.problem import prepare, relative_guess
from rangereg.core.register import estimate_threshold
from rangereg.core.scan import Scan
from rangereg.core.surface import Surface
from rangereg.core.transforms import check_rigid, invert

log = logging.getLogger("rangereg.workbench")


class Tab:
    def __init__(self, workbench, client: viser.ClientHandle):
        self.wb, self.client, self.gui = workbench, client, client.gui
        # +y up from the first message on, and the opening pose sent again if the browser still read it in viser's +z
        # (scene3d.CameraKeeper)
        client.scene.set_up_direction("+y")
        client.flush()
        self.camera = scene3d.CameraKeeper(client)
        self.state = TabState()
        self._acting = threading.RLock()  # one GUI action at a time (guarded); re-entrant: an action may call another
        self.actions = Actions(self.guarded, lambda: self.state.closed)  # clicks in their order (app/tab/actions.py)
        self.nodes: scene3d.SceneNodes | None = None
        self.run_drawing = False  # a run moves the scan: the light clouds are drawn
        self._trail: Trail | None = None
        self.status = self.gui.add_html("Loading...")
        self.e_init = self.gui.add_markdown("")
        self.legend = self.gui.add_html(legend_html())
        self.fit = self.gui.add_button("Fit view", hint="frame the scans (and the terrain, when shown)")
        self.fit.on_click(self.action(self.fit_view))
        chart = build_chart(self.gui)  # above the tabs: E shows whatever tab is open
        self.chart_units = ""
        tabs = self.gui.add_tab_group()
        with tabs.add_tab("Run"):
            self.run_panel = RunPanel(self, chart)
        with tabs.add_tab("Lesson"):
            self.lesson = LessonPanel(self)
        with tabs.add_tab("Pose"):
            self.pose = PosePanel(self)
            self.pairs = PairsPanel(self)
        with tabs.add_tab("Scans"):
            self.scans = ScansPanel(self)
        with tabs.add_tab("Landscape"):
            self.landscape = LandscapePanel(self)
            self.replay = ReplayPanel(self)
        with tabs.add_tab("Model"):
            self.model = ModelPanel(self)
        with tabs.add_tab("Export"):
            self.export = ExportPanel(self)
        self.refresher = Refresher(self)
        self.refresher.start()

    # ---- the page's voice --------------------------------------------------------------------------
    def notify(self, title: str, body: str, error: bool = True) -> None:
        self.client.add_notification(title, body, color="red" if error else "green", auto_close_seconds=8.0)

    def action(self, fn: Callable[..., None], *args, event: Callable[[Any], tuple] | None = None
               ) -> Callable[[Any], Coroutine]:
        """The viser callback of a button, an upload, a scene click or the gizmo: ``fn(*args)`` queued in the order
        of the clicks (app/tab/actions.py; ``event``: what of the event ``fn`` also takes)."""
        return self.actions.callback(fn, *args, event=event)

    def guarded(self, fn, *args) -> None:
        """Run a GUI action; bad input becomes a notification and leaves the tab as it was. One action of the tab at a
        time (the lock: the first pair's load and a field's callback come from other threads)."""
        try:
            with self._acting:
                fn(*args)
        except InputError as exc:
            self.notify("Not done", str(exc))
        except Exception as exc:  # never a dead page: say what happened, keep the tab
            log.exception("workbench action failed")
            self.notify("Something went wrong", f"{type(exc).__name__}: {exc}")
        if self.state.closed:  # the tab closed while this action ran: what it started stops too
            self.state.cancel_work()

    # ---- a pair of scans ---------------------------------------------------------------------------
    def load_pair(self, source: Scan, target: Scan, keep_pose: bool = False, scene: str | None = "-") -> None:
        """Show a new pair; everything is checked before anything of the old pair is dropped. ``scene``: the bundled
        scene it is, "-" for files (the Scans tab's Scene dropdown says so), None: the same pair again."""
        st = self.state
        st.require_idle()
        settings = self.run_panel.settings()
        T_file = relative_guess(source, target)
        T_init = st.T_init if keep_pose else T_file
        surfaces = Surface.from_scan(source), Surface.from_scan(target)
        frusta = {k: (frustum_of(source, k), frustum_of(target, k)) for k in KINDS}
        problem = prepare(source, target, page_guess(settings, T_init), problem_config(settings), surface=surfaces[1],
                          seed=settings.seed)
        threshold = settings.threshold
        if threshold is None:
            threshold = estimate_threshold(problem, settings.seed)
        T_truth = invert(target.pose) @ source.pose if source.pose is not None and target.pose is not None else None
        with st.lock:
            if st.slice_cancel is not None:
                st.slice_cancel.set()
            st.pair += 1
            st.source, st.target, st.surfaces, st.frusta = source, target, surfaces, frusta
            st.T_file, st.T_init, st.T_truth, st.threshold = T_file, T_init, T_truth, threshold
            st.display = Display(target, source)
            st.set_problem(problem)
            st.reset_run(T_init)
            st.slice, st.model = None, None
        # the page is drawn outside the state's lock: the lock is always taken inside client.atomic(), never around it
        with self.client.atomic():
            if self.nodes is not None:
                self.nodes.remove()
            self.nodes = scene3d.draw_pair(self.client, st, settings.frustum, self.scans.h.show.overlap.value)
        self.camera.keep()
        self.nodes.gizmo.on_update(self.action(self.pose.dragged))
        self.chart_in(target.units)
        self.lesson.forget()
        self.scans.show_viewpoints(source, target)
        if scene is not None:
            self.scans.name_scene(scene)
        self.pose.lock(False)
        self.pose.name_units(target.units)
        self.model.forget()
        self.pairs.forget()
        self.replay.forget()
        self.landscape.forget()
        self.landscape.update_terrain()
        self.model.residuals.refresh()
        self.apply_visibility()
        self.clear_run_views()
        self.pose.show(T_init)
        self.update_status()

    def reprepare(self) -> None:
        """A new overlap cut (frustum kind or sample size changed, or a new initial pose)."""
        st = self.state
        if st.source is None or st.running:
            return
        settings = self.run_panel.settings()
        problem = prepare(st.source, st.target, page_guess(settings, st.T_init), problem_config(settings),
                          surface=st.surfaces[1], seed=settings.seed)
        with st.lock:
            st.set_problem(problem)
        scene3d.redraw_frustums(self.client.scene, self.nodes, st, settings.frustum)
        self.recolour()
        self.update_status()

    def set_initial(self, T: np.ndarray) -> None:
        st = self.state
        st.require_idle()
        st.require_scans()
        T = check_rigid(np.asarray(T, dtype=np.float64), "initial pose")
        with st.lock:
            st.T_init = T
            st.reset_run(T)
        self.reprepare()
        self.lesson.forget()
        scene3d.move_source(self.nodes, st, T)
        self.clear_run_views()
        self.pose.show(T)
        self.replay.forget()
        self.model.residuals.refresh()

    # ---- the page ----------------------------------------------------------------------------------
    def trail(self) -> Trail:
        """The drawing arrays of the current run's events (a new run, a new trail)."""
        events = self.state.events
        if self._trail is None or self._trail.events is not events or self._trail.display is not self.state.display:
            self._trail = Trail(self.state.display, events)
        return self._trail

    def fit_view(self) -> None:
        """Point the camera so that the scans, and the terrain when it is shown, fill the view."""
        if self.nodes is None:
            return
        with self.state.lock:
            points = scene3d.shown_extent(self.state, self.nodes)
        if self.landscape.terrain is not None:
            points = np.r_[points, self.landscape.terrain.extent()]
        scene3d.fit_camera(self.client, points)

    def chart_in(self, units: str) -> None:
        """The E chart with its axes in ``units``: a new chart in the old one's place when they change. viser's client
        keeps a chart's x range as a share of its data's across an update of its options (new axes), and read the
        range it held then against the next data: after the lesson (148 iterations on the corner, mm) a bunny run of
        72 iterations (m) was drawn on 0-10,000."""
        if units == self.chart_units:
            return
        old = self.run_panel.h.plot
        self.run_panel.h.plot = build_chart(self.gui, units, order=old.order)
        old.remove()
        self.chart_units = units

    def recolour(self) -> None:
        if self.nodes is not None:
            with self.client.atomic():
                scene3d.recolour(self.nodes, self.state, bool(self.scans.h.show.overlap.value))

    def apply_visibility(self) -> None:
        if self.nodes is None:
            return
        model = bool(self.model.h.show.value and self.state.model is not None)
        with self.client.atomic():
            scene3d.apply_visibility(self.client.scene, self.nodes, self.scans.visibility(model), self.run_drawing)

    def lock_panels(self, running: bool) -> None:
        """A run holds the scans: what would change them is disabled until it ends."""
        self.apply_visibility()
        self.pose.lock(running)
        self.scans.lock(running)
        self.model.lock(running)
        self.replay.lock(running)

    def clear_run_views(self) -> None:
        with self.client.atomic():
            scene3d.clear_path(self.nodes)
            self.run_panel.h.plot.data = self.run_panel.chart_data(Trail(self.state.display, []))
        if self.landscape.terrain is not None:
            self.landscape.update_terrain()

    def update_status(self) -> None:
        """The status (app/tab/status.py) and the lesson's sentence, from one Progress of the drawn run."""
        st = self.state
        trail = self.trail()
        guess = self.run_panel.guess_line()  # reads the settings' fields: outside the state's lock
        lock = self.run_panel.lock_text()
        typed = self.run_panel.threshold_typed()
        with st.lock:
            running, E0, result = st.running, st.E0, st.result
            p = status.progress(trail, st.events, E0, result, running)
            state = ("cancelling" if st.run.cancelled else "paused" if st.run.paused else "running") if running \
                else "idle"
            units = st.target.units if st.target is not None else ""
            name, basis = status.threshold_label(result if not running else None, typed)
            pair = f"{st.source.name if st.source else '-'} → {st.target.name if st.target else '-'}"
            rows = status.rows(p, pair=pair, units=units, overlap=int(st.problem.used.sum()) if st.problem else 0,
                               method=st.run_method, state=state, lock=lock, threshold=st.threshold,
                               threshold_name=name, threshold_basis=basis, guess=guess)
            more = [st.finished_text] if st.finished_text and not running else []
        self.pose.show_result(None if running else result)
        self.lesson.write(p)
        if self.lesson.title:
            more.append(f"Lesson: <b>{self.lesson.title}</b>")
        content = status.page_html(rows, more)
        if self.status.content != content:
            self.status.content = content
        e_init = f"Initial E = {fmt(E0)} {squared_unit(units)}"
        if self.e_init.content != e_init:
            self.e_init.content = e_init

    def close(self) -> None:
        """The browser tab went away: its run and its slice stop."""
        self.state.closed = True
        self.state.cancel_work()
        self.actions.close()
