"""The Model panel: fuse the two scans at the current pose into one mesh (core.fuse)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import viser

from app.tab import scene3d
from app.tab.residuals import ResidualsPanel
from app.tab.state import TabState


@dataclass(eq=False)
class ModelHandles:
    merge: viser.GuiButtonHandle
    show: viser.GuiCheckboxHandle


class ModelPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        self.h = ModelHandles(gui.add_button("Merge", hint="fuse the two scans at the current pose into one mesh"),
                              gui.add_checkbox("Show model", False, disabled=True))
        self.residuals = ResidualsPanel(tab)
        self.h.merge.on_click(lambda e: tab.guarded(self.start))
        self.h.show.on_update(lambda e: tab.guarded(tab.apply_visibility))

    def start(self) -> None:
        from core.fuse import fuse

        st = self.state
        st.require_scans()
        st.require_idle()
        with st.lock:
            source, target, T, surfaces, pair = st.source, st.target, st.T, st.surfaces, st.pair
        self.h.merge.disabled = True

        def work() -> None:
            try:
                model = fuse([target, source], [np.eye(4), T], [surfaces[1], surfaces[0]])
            except Exception as exc:  # said on the page; the tab lives on
                self.tab.notify("Merge failed", str(exc))
                self.state.hand(lambda st: None, lambda: setattr(self.h.merge, "disabled", False))
                return

            def apply(st: TabState) -> None:
                if st.pair == pair:
                    st.model = model

            self.state.hand(apply, lambda: self._show(model))

        threading.Thread(target=work, daemon=True, name="rangereg-merge").start()

    def _show(self, model) -> None:
        self.h.merge.disabled = False
        if self.state.model is not model:
            return
        scene3d.show_model(self.tab.client.scene, self.tab.nodes, self.state)
        self.h.show.disabled = False
        self.h.show.value = True
        self.tab.apply_visibility()
        self.tab.notify("Model", f"{len(model.vertices)} vertices, {len(model.faces)} triangles", error=False)

    def forget(self) -> None:
        """A new pair: no model yet."""
        self.h.show.value, self.h.show.disabled = False, True

    def lock(self, running: bool) -> None:
        self.h.merge.disabled = running
