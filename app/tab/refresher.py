"""The refresher: the one owner of workers' results, and the run's progress on the page at >= 10 Hz.

Each tick it takes the run's state first, applies what workers handed over (under the tab's lock),
then pushes a snapshot inside one ``client.atomic()`` (one message batch, one frame in the browser):
the source node's pose (never its points), the path, the status, the terrain's marker; the E chart
and the terrain's path ride along less often, and the contour (a Plotly figure rebuilt in Python and
redrawn in the browser) less often still. Ticks keep a fixed cadence: the time a push takes is not
added to the wait. A failed tick is logged with its traceback and the loop goes on.
"""

from __future__ import annotations

import logging
import threading
import time

from rangereg.app.tab import scene3d

log = logging.getLogger("rangereg.workbench")

REFRESH = 0.07  # seconds between pushes of a run's progress: ~14 Hz, >= 10 Hz; a browser slower than that
# takes the latest (viser keeps only the newest value of each property it has not sent yet)
PLOT_REFRESH = 0.5  # seconds between redraws of the E chart during a run (uPlot redraws its 2000 points on the
# page's main thread, which also waits for every frame of a software-rendered canvas)
TERRAIN_REFRESH = 0.25  # seconds between redraws of the path on the 3-D terrain during a run (its marker moves
# on every push)
SLICE_REFRESH = 2.0  # seconds between redraws of the contour during a run: rebuilding the Plotly figure took
# 90-180 ms of the refresher's time and projecting every event onto it 0.5-1.2 s before the projection was kept
# (bunny SA run, load ~12 on 2 cores), which held the pushes to 4.8/s


class Refresher:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.was_running = False
        self.failures = 0
        self.terrain_at = self.plot_at = 0.0
        self.plotted = self.terrain_drawn = self.sliced = (None, 0)  # (trail, events) last drawn in the chart, on the
        # terrain, on the contour
        self.paused_shown = None  # (run, paused) as Pause / Resume last showed it (None: no run)
        self.thread = threading.Thread(target=self._loop, daemon=True, name="rangereg-refresh")

    def start(self) -> None:
        self.thread.start()

    def _loop(self) -> None:
        due = time.monotonic()
        while not self.state.closed:
            due += REFRESH
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            else:
                due = time.monotonic()  # late (a slow push): go on from now, no burst of pushes to catch up
            try:
                self.tick()
            except Exception:
                if self.state.closed:
                    return  # the tab went away mid-push
                self.failures += 1
                log.exception("workbench refresh failed (client %s); carrying on", self.tab.client.client_id)
                time.sleep(0.5)

    def tick(self) -> None:
        tab, st = self.tab, self.state
        running = st.running  # before the hand-over: a run that ends now has handed its result already
        for then in st.apply_handed():
            try:
                then()
            except Exception:
                log.exception("applying a worker's result failed; carrying on")
        if st.source is None or tab.nodes is None:
            return
        tab.lesson.show()
        # the light view only while the scan moves: a paused run shows every point again
        light = running and not st.run.paused
        if light != tab.run_drawing:
            tab.run_drawing = light
            tab.apply_visibility()
        shown = (st.run, st.run.paused) if running else None  # a new run is a new Run: its buttons are set afresh
        if shown is not None and shown != self.paused_shown:
            tab.run_panel.show_paused(shown[1])
        self.paused_shown = shown
        trail = tab.trail()
        if running or self.was_running or trail.n != len(st.events):
            self.push(running)
        if self.was_running and not running:
            tab.run_panel.set_controls(running=False)
            tab.apply_visibility()  # the gizmo comes back unless the model is shown or points are being picked
            scene3d.move_source(tab.nodes, st, st.T)
            tab.update_status()
            tab.model.residuals.refresh()
            tab.replay.reset()
        self.was_running = running

    def push(self, running: bool) -> None:
        tab, st = self.tab, self.state
        trail = tab.trail()
        before = trail.n
        n = trail.update()
        now = time.monotonic()
        moved = n != before or not running
        # the chart and the terrain's path follow at their own pace; a paused run (Step) gets them on a later tick
        plot_due = (not running or now - self.plot_at >= PLOT_REFRESH) and (self.plotted != (trail, n) or not running)
        terrain_due = (not running or now - self.terrain_at >= TERRAIN_REFRESH) and (
            self.terrain_drawn != (trail, n) or not running)
        # the contour at its own pace, and once more when a paused run has events it has not drawn (a lesson's step)
        slice_due = st.slice is not None and self.sliced != (trail, n, running) and (
            not running or now - tab.landscape.drawn_at > SLICE_REFRESH or st.run.paused)
        if not (moved or plot_due or terrain_due):
            tab.update_status()
            if slice_due:
                self.sliced = (trail, n, running)
                tab.landscape.draw(terrain=not running)
            return
        with st.lock:
            if n and running and st.result is None:  # once the run's result is in, its pose is the one shown
                st.T = st.events[n - 1].T
            T, result = st.T, (st.result if not running else None)
        # the arrays first, the messages then: the batch is held back from the browser only while it is assembled
        path = (trail.segments(), trail.minima()) if moved else None
        plot = tab.run_panel.chart_data(trail, result) if plot_due else None
        with tab.client.atomic():
            if path is not None:
                scene3d.move_source(tab.nodes, st, T, gizmo=False)
                scene3d.draw_path(tab.nodes, *path)
            if plot is not None:
                tab.run_panel.h.plot.data = plot
                self.plot_at, self.plotted = now, (trail, n)
            if moved or terrain_due:
                tab.landscape.follow(T, path=terrain_due)
            if terrain_due:
                self.terrain_at, self.terrain_drawn = now, (trail, n)
            tab.update_status()
        if slice_due:
            self.sliced = (trail, n, running)
            tab.landscape.draw(terrain=not running)
