"""The Export panel: the transform, the trace, the registered scans, the slice picture, the model, as downloads."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.figures import SOURCE_RGB, TARGET_RGB
from rangereg.app.plots import slice_png_bytes
from rangereg.app.tab.landscape import picture
from rangereg.app.views import ply_bytes
from rangereg.core.errors import InputError
from rangereg.core.transforms import apply


@dataclass(eq=False)
class ExportHandles:
    transform: viser.GuiButtonHandle
    trace: viser.GuiButtonHandle
    scans: viser.GuiButtonHandle
    slice: viser.GuiButtonHandle
    model: viser.GuiButtonHandle
    recording: viser.GuiButtonHandle


class ExportPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        self.h = ExportHandles(gui.add_button("Transform (JSON)"), gui.add_button("Trace (JSON lines)"),
                               gui.add_button("Registered scans (PLY)"), gui.add_button("Slice (PNG)"),
                               gui.add_button("Model (PLY)"),
                               gui.add_button("Recording (HTML)", hint="the run as one HTML file that plays in a "
                                              "browser with no server: scans, moving scan, path, 3-D landscape"))
        for button, fn in ((self.h.transform, self.transform), (self.h.trace, self.trace), (self.h.scans, self.scans),
                           (self.h.slice, self.slice), (self.h.model, self.model), (self.h.recording, self.recording)):
            button.on_click(tab.action(fn))

    def _download(self, name: str, data: bytes) -> None:
        self.tab.client.send_file_download(name, data, save_immediately=True)

    def transform(self) -> None:
        st = self.state
        st.require_scans()
        with st.lock:
            T, r = st.T, st.result
            # the run's own E when its pose is the one shown (the status and the Finished line say the same), else
            # E at the shown pose on the page's overlap cut
            E = r.error if r is not None and r.transform is not None and np.array_equal(T, r.transform) else (
                float(st.problem.error(T)))
            extra = {"error": float(E), "source": st.source.name, "target": st.target.name,
                     "convention": "maps SOURCE coordinates into TARGET's frame (T_target_source)"}
            name = f"{st.source.name}_to_{st.target.name}.json"
        if r is not None:
            extra.update(method=r.method, threshold=r.threshold, stop_reason=r.stop_text)
        self._download(name, (json.dumps({"transform": T.tolist(), **extra}, indent=1) + "\n").encode())

    def trace(self) -> None:
        """As ``register --trace`` writes it: the header (when the run's is known), the events, the result."""
        st = self.state
        with st.lock:
            events, header, result = list(st.events), st.run_header, st.result
        if not events:
            raise InputError("no run yet: nothing to export")
        rows = ([header.to_json()] if header is not None else []) + [e.to_json() for e in events]
        if result is not None and result.transform is not None:
            rows.append({"result": result.to_json()})
        self._download("trace.jsonl", "".join(json.dumps(r) + "\n" for r in rows).encode())

    def scans(self) -> None:
        st = self.state
        st.require_scans()
        with st.lock:
            src, tgt, T = st.source, st.target, st.T
        pts = np.vstack([tgt.points, apply(T, src.points)])
        rgb = np.vstack([np.tile(TARGET_RGB, (len(tgt.points), 1)), np.tile(SOURCE_RGB, (len(src.points), 1))])
        self._download(f"{tgt.name}+{src.name}_registered.ply", ply_bytes(pts, None, rgb.astype(np.uint8)))

    def slice(self) -> None:
        st = self.state
        with st.lock:
            if st.slice is None:
                raise InputError("compute a slice first")
            *args, run_minima = picture(st)
            units = st.target.units
        self._download("slice.png", slice_png_bytes(*args, units=units, run_minima=run_minima))

    def model(self) -> None:
        model = self.state.model
        if model is None:
            raise InputError("fuse a model first (Model tab: Fuse this pair, or Merge scans)")
        self._download("model.ply", ply_bytes(model.vertices, model.faces))

    def recording(self) -> None:
        """The last run as a self-contained HTML recording (app/recording.py); made on a worker thread."""
        import threading

        from rangereg.app.recording import RunToRecord, recording_html

        st = self.state
        st.require_scans()
        st.require_idle()
        kind = self.tab.run_panel.settings().frustum
        with st.lock:
            if not st.events:
                raise InputError("no run yet: nothing to record")
            run = RunToRecord(st.source, st.target, st.display, st.frusta[kind], st.run_start, list(st.events),
                              st.slice, st.target.units, E0=st.E0, threshold=st.threshold)
        self.h.recording.disabled = True

        def work() -> None:
            try:
                self._download(f"{run.source.name}_to_{run.target.name}_run.html", recording_html(run))
            except Exception as exc:  # said on the page; the tab lives on
                self.tab.notify("Recording failed", str(exc))
            finally:
                self.h.recording.disabled = False

        threading.Thread(target=work, daemon=True, name="rangereg-recording").start()
