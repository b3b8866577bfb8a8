"""The refresher: the one owner of workers' results, and the run's progress on the page at >= 10 Hz.

Each tick it takes the run's state first, applies what workers handed over (under the tab's lock),
then pushes a snapshot inside ``client.atomic()``: the source node's pose (never its points), the
path, the chart, the status. A failed tick is logged with its traceback and the loop goes on.
"""

from __future__ import annotations

import logging
import threading
import time

from app.tab import scene3d

log = logging.getLogger("rangereg.workbench")

REFRESH = 0.07  # seconds between pushes of a run's progress: ~14 Hz, >= 10 Hz and no faster than a
# software-rendered page draws, so pushes never queue up in the browser (Pause shows at once)
SLICE_REFRESH = 1.0  # seconds between redraws of the path on the slice during a run
TERRAIN_REFRESH = 0.25  # seconds between redraws of the path on the 3-D terrain during a run: with it drawn on
# every push the bunny pair's SA run fell from 6.6 to 3.8 pushes/s (load ~3.5 on 2 cores)


class Refresher:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.was_running = False
        self.failures = 0
        self.terrain_at = 0.0
        self.thread = threading.Thread(target=self._loop, daemon=True, name="rangereg-refresh")

    def start(self) -> None:
        self.thread.start()

    def _loop(self) -> None:
        while not self.state.closed:
            time.sleep(REFRESH)
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
        # the light view only while the scan moves: a paused run shows every point again
        light = running and not st.run.paused
        if light != tab.run_drawing:
            tab.run_drawing = light
            tab.apply_visibility()
        trail = tab.trail()
        if running or self.was_running or trail.n != len(st.events):
            self.push(running)
        if self.was_running and not running:
            tab.run_panel.set_controls(running=False)
            tab.nodes.gizmo.visible = True
            scene3d.move_source(tab.nodes, st, st.T)
            tab.update_status()
            if st.slice is not None:
                tab.landscape.draw()
            tab.model.residuals.refresh()
            tab.replay.reset()
        self.was_running = running

    def push(self, running: bool) -> None:
        tab, st = self.tab, self.state
        trail = tab.trail()
        before = trail.n
        n = trail.update()
        if n == before and running:
            tab.update_status()
            return
        with st.lock:
            if n and running and st.result is None:  # once the run's result is in, its pose is the one shown
                st.T = st.events[n - 1].T
            T, E0 = st.T, st.E0
        with tab.client.atomic():
            scene3d.move_source(tab.nodes, st, T, gizmo=False)
            scene3d.draw_path(tab.nodes, trail)
            tab.run_panel.h.plot.data = trail.plot(E0)
            tab.update_status()
        if tab.landscape.terrain is not None and (not running or time.monotonic() - self.terrain_at > TERRAIN_REFRESH):
            self.terrain_at = time.monotonic()
            tab.landscape.update_terrain()
        if st.slice is not None and time.monotonic() - tab.landscape.drawn_at > SLICE_REFRESH:
            tab.landscape.draw()
