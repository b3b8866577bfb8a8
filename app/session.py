"""One browser tab of the workbench: its scans, its GUI, its runs. Tabs never share mutable state.

Everything the page does calls core: loading (core.io), the overlap (core.problem), the runs
(core.register through app.runner), the slice (core.landscape), the model (core.fuse). Work runs
on threads of its own; a refresher thread pushes the run's progress to the page at ~15 Hz inside
``client.atomic()``, moving the scan by its node's pose, never by re-sending its points.
"""

from __future__ import annotations

import json
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import viser
import viser.uplot as uplot

from app.runner import Run
from app.views import (
    MINIMUM_RGB,
    SOURCE_OVERLAP_RGB,
    SOURCE_RGB,
    TARGET_OVERLAP_RGB,
    TARGET_RGB,
    Display,
    Trail,
    ply_bytes,
    png_bytes,
    slice_figure,
)
from core.anneal import AnnealConfig
from core.errors import InputError
from core.frustum import KINDS, frustum_of
from core.icp import IcpConfig
from core.io import load_scan
from core.landscape import compute_slice, default_span, project
from core.problem import ProblemConfig, prepare, relative_guess
from core.register import Config, estimate_threshold, register
from core.scan import Scan
from core.surface import Surface
from core.transforms import PARAM_NAMES, apply, check_rigid, from_params, invert, to_params
from core.viewpoint import check_viewpoint

REFRESH = 0.07  # seconds between pushes of a run's progress: ~14 Hz, >= 10 Hz and no faster than a
# software-rendered page draws, so pushes never queue up in the browser (Pause shows at once)
RUN_POINTS = 6000  # while a run moves the scan, each cloud is drawn with at most this many points
SLICE_REFRESH = 1.0  # seconds between redraws of the path on the slice during a run
RUN_BUTTONS = {"Run hybrid": "hybrid", "Run ICP": "icp", "Run SA": "sa", "ICP restarts": "icp-restarts",
               "Basin hopping": "basin-hopping"}


class Session:
    def __init__(self, workbench, client: viser.ClientHandle):
        self.wb, self.client = workbench, client
        self.gui = client.gui
        self.scene = _Kept(client.scene, self)  # every node added is remembered by name, to show/hide/remove
        self.lock = threading.RLock()
        self.closed = False
        self.source: Scan | None = None
        self.target: Scan | None = None
        self.T_file = self.T_init = self.T = np.eye(4)
        self.T_truth: np.ndarray | None = None
        self.problem = None
        self.lod: dict[str, np.ndarray] = {}  # scan node -> indices of the points drawn during a run
        self.run_drawing = False
        self.threshold: float | None = None
        self.run: Run | None = None
        self.run_method = ""
        self.events: list = []
        self.pushed = 0
        self.slice = None
        self.slice_busy = False
        self.slice_drawn_at = 0.0
        self.model = None
        self.finished_text = ""
        self.h = SimpleNamespace()  # every GUI handle of this tab, together
        self.nodes: dict = {}  # every scene node of this tab, by name
        self._build_gui()
        self.refresher = threading.Thread(target=self._refresh_loop, daemon=True, name="rangereg-refresh")
        self.refresher.start()

    # ---- GUI -------------------------------------------------------------------------------
    def _build_gui(self) -> None:
        gui, h = self.gui, self.h
        h.status = gui.add_markdown("Loading...")
        with gui.add_folder("Run"):
            h.run = {label: gui.add_button(label) for label in RUN_BUTTONS}
            h.step = gui.add_button("Step", hint="one ICP iteration or one annealing move, then pause")
            h.next_phase = gui.add_button("Next phase", hint="run to the end of this ICP or SA leg, then pause")
            h.pause = gui.add_button("Pause", disabled=True)
            h.resume = gui.add_button("Resume", disabled=True)
            h.cancel = gui.add_button("Cancel", disabled=True)
            h.reset = gui.add_button("Reset", hint="back to the initial pose; clear the path")
        h.plot = gui.add_uplot(
            data=(np.zeros(1), np.ones(1), np.ones(1)),
            # points, not lines: each phase leaves gaps where the other ran
            series=(uplot.Series(label="iteration"),
                    uplot.Series(label="E (ICP)", stroke="#1eaa46", width=0,
                                 points=uplot.Series_Points(show=True, size=5, fill="#1eaa46", stroke="#1eaa46")),
                    uplot.Series(label="E (SA)", stroke="#d232c8", width=0,
                                 points=uplot.Series_Points(show=True, size=3, fill="#d232c8", stroke="#d232c8"))),
            scales={"x": uplot.Scale(time=False, auto=True), "y": uplot.Scale(distr=3)},
            axes=(uplot.Axis(), uplot.Axis(size=70)), title="E against iteration", aspect=1.6)
        with gui.add_folder("Initial pose"):
            h.e_init = gui.add_markdown("")
            h.params = [gui.add_number(n + (" (deg)" if n.startswith("r") else ""), 0.0, step=1e-4) for n in PARAM_NAMES]
            h.apply_pose = gui.add_button("Apply pose")
            h.reset_file = gui.add_button("Reset to file pose")
            h.reset_truth = gui.add_button("Reset to ground truth")
        with gui.add_folder("Scans"):
            h.scene = gui.add_dropdown("Scene", self.wb.scene_names, initial_value=self.wb.options.scene)
            h.open_scene = gui.add_button("Open scene")
            files = self.wb.data_files()
            if files:
                h.file_source = gui.add_dropdown("Source file", files, initial_value=files[min(1, len(files) - 1)])
                h.file_target = gui.add_dropdown("Target file", files, initial_value=files[0])
                h.open_files = gui.add_button("Open files")
                h.open_files.on_click(lambda e: self._guarded(self._open_data_files))
            h.upload_source = gui.add_upload_button("Upload source", hint=f"up to {self.wb.upload_cap_mb:g} MB")
            h.upload_target = gui.add_upload_button("Upload target", hint=f"up to {self.wb.upload_cap_mb:g} MB")
            h.vp_source = gui.add_vector3("Source viewpoint", (0.0, 0.0, 0.0), step=1e-4)
            h.vp_target = gui.add_vector3("Target viewpoint", (0.0, 0.0, 0.0), step=1e-4)
            h.apply_vp = gui.add_button("Apply viewpoints")
        with gui.add_folder("Show"):
            h.show_frustums = gui.add_checkbox("Frustums", True)
            h.show_overlap = gui.add_checkbox("Overlap points", True)
            h.show_surfaces = gui.add_checkbox("Surfaces", False)
            h.show_path = gui.add_checkbox("Path", True)
        with gui.add_folder("Settings", expand_by_default=False):
            h.threshold = gui.add_text("Threshold", "auto", hint="stop below this E; auto: from the scans' noise; "
                                       "0: search until annealing gives up")
            h.t_start = gui.add_text("Start temperature", "auto", hint="auto: from the spread of E over the first simplex")
            h.t_min = gui.add_number("Minimum temperature ratio", 0.01, min=1e-9, max=0.999, step=1e-3)
            h.cooling = gui.add_number("Cooling", 0.9, min=0.01, max=0.999, step=0.01)
            h.seed = gui.add_number("Seed", 0, min=0, step=1)
            h.icp_max = gui.add_number("ICP iteration cap", 100, min=1, step=1)
            h.sa_max = gui.add_number("SA evaluation cap", 20000, min=7, step=100)
            h.frustum = gui.add_dropdown("Frustum", KINDS, initial_value="convex")
            h.max_points = gui.add_number("Overlap sample size", 300, min=3, step=1)
            h.c2f = gui.add_checkbox("Coarse to fine", False)
            h.polish = gui.add_checkbox("Unweighted polish", False)
        with gui.add_folder("Error slice"):
            h.slice_a = gui.add_dropdown("Parameter A", PARAM_NAMES, initial_value="tx")
            h.slice_b = gui.add_dropdown("Parameter B", PARAM_NAMES, initial_value="ry")
            h.span_a = gui.add_number("Span A (0: auto)", 0.0, min=0.0, step=1e-3)
            h.span_b = gui.add_number("Span B (0: auto)", 0.0, min=0.0, step=1e-3)
            h.steps = gui.add_number("Steps", 41, min=2, max=201, step=1)
            h.compute_slice = gui.add_button("Compute slice")
            h.slice_progress = gui.add_progress_bar(0.0, visible=False)
            h.slice_plot = None
        with gui.add_folder("Model"):
            h.merge = gui.add_button("Merge", hint="fuse the two scans at the current pose into one mesh")
            h.show_model = gui.add_checkbox("Show model", False, disabled=True)
        with gui.add_folder("Export", expand_by_default=False):
            h.export_transform = gui.add_button("Transform (JSON)")
            h.export_trace = gui.add_button("Trace (JSON lines)")
            h.export_scans = gui.add_button("Registered scans (PLY)")
            h.export_slice = gui.add_button("Slice (PNG)")
            h.export_model = gui.add_button("Model (PLY)")

        for label, method in RUN_BUTTONS.items():
            h.run[label].on_click(lambda e, m=method: self._guarded(self.start_run, m))
        h.step.on_click(lambda e: self._guarded(self.step))
        h.next_phase.on_click(lambda e: self._guarded(self.next_phase))
        h.pause.on_click(lambda e: self._control("pause"))
        h.resume.on_click(lambda e: self._control("resume"))
        h.cancel.on_click(lambda e: self._control("cancel"))
        h.reset.on_click(lambda e: self._guarded(self.reset))
        h.apply_pose.on_click(lambda e: self._guarded(self._apply_typed_pose))
        h.reset_file.on_click(lambda e: self._guarded(self.set_initial, self.T_file))
        h.reset_truth.on_click(lambda e: self._guarded(self._reset_truth))
        h.open_scene.on_click(lambda e: self._guarded(self.open_scene, h.scene.value))
        h.upload_source.on_upload(lambda e: self._guarded(self._uploaded, "source", e.target.value))
        h.upload_target.on_upload(lambda e: self._guarded(self._uploaded, "target", e.target.value))
        h.apply_vp.on_click(lambda e: self._guarded(self._apply_viewpoints))
        for box in (h.show_frustums, h.show_surfaces, h.show_path, h.show_model):
            box.on_update(lambda e: self._guarded(self._apply_visibility))
        h.show_overlap.on_update(lambda e: self._guarded(self._draw_overlap))
        h.frustum.on_update(lambda e: self._guarded(self._reprepare))
        h.max_points.on_update(lambda e: self._guarded(self._reprepare))
        h.compute_slice.on_click(lambda e: self._guarded(self.start_slice))
        h.merge.on_click(lambda e: self._guarded(self.start_merge))
        h.export_transform.on_click(lambda e: self._guarded(self._export_transform))
        h.export_trace.on_click(lambda e: self._guarded(self._export_trace))
        h.export_scans.on_click(lambda e: self._guarded(self._export_scans))
        h.export_slice.on_click(lambda e: self._guarded(self._export_slice))
        h.export_model.on_click(lambda e: self._guarded(self._export_model))

    def notify(self, title: str, body: str, error: bool = True) -> None:
        self.client.add_notification(title, body, color="red" if error else "green", auto_close_seconds=8.0)

    def _guarded(self, fn, *args) -> None:
        """Run a GUI action; bad input becomes a notification and leaves the session as it was."""
        try:
            fn(*args)
        except InputError as exc:
            self.notify("Not done", str(exc))
        except Exception as exc:  # never a dead page: say what happened, keep the session
            self.notify("Something went wrong", f"{type(exc).__name__}: {exc}")

    # ---- loading -----------------------------------------------------------------------------
    def open_scene(self, name: str) -> None:
        self.load_pair(*self.wb.scene_pair(name))

    def _open_data_files(self) -> None:
        self.load_pair(self.wb.load_data_file(self.h.file_source.value), self.wb.load_data_file(self.h.file_target.value))

    def _uploaded(self, which: str, upload) -> None:
        if len(upload.content) > self.wb.upload_cap:
            raise InputError(f"{upload.name}: {len(upload.content) / 1e6:.0f} MB is over the upload cap "
                             f"({self.wb.upload_cap_mb:g} MB)")
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / Path(upload.name).name
            path.write_bytes(upload.content)
            try:
                scan = load_scan(path)
            except InputError as exc:
                raise InputError(str(exc).replace(str(path), upload.name)) from None
        scan = replace(scan, source=f"upload:{upload.name}")
        if which == "source":
            self.load_pair(scan, self.target)
        else:
            self.load_pair(self.source, scan)
        self.notify("Loaded", f"{upload.name}: {len(scan.points)} points", error=False)

    def _apply_viewpoints(self) -> None:
        src = self._with_viewpoint(self.source, self.h.vp_source.value)
        tgt = self._with_viewpoint(self.target, self.h.vp_target.value)
        self.load_pair(src, tgt, keep_pose=True)

    @staticmethod
    def _with_viewpoint(scan: Scan, value) -> Scan:
        v = np.asarray(value, dtype=np.float64)
        if np.allclose(v, scan.viewpoint):
            return scan
        moved = scan.with_viewpoint(v)
        check_viewpoint(moved.points, moved.viewpoint, moved.grid, moved.faces, moved.name)
        return moved

    def load_pair(self, source: Scan, target: Scan, keep_pose: bool = False) -> None:
        """Show a new pair; everything is checked before anything of the old pair is dropped."""
        self._require_idle()
        T_file = relative_guess(source, target)
        T_init = self.T_init if keep_pose else T_file
        surfaces = Surface.from_scan(source), Surface.from_scan(target)
        frusta = {k: (frustum_of(source, k), frustum_of(target, k)) for k in KINDS}
        problem = prepare(source, target, T_init, self._problem_config(), surface=surfaces[1], seed=int(self.h.seed.value))
        threshold = self._threshold_setting()
        if threshold is None:
            threshold = estimate_threshold(problem, int(self.h.seed.value))
        with self.lock:
            self.source, self.target, self.surfaces, self.frusta = source, target, surfaces, frusta
            self.T_file, self.T_init, self.T = T_file, T_init, T_init
            self.T_truth = invert(target.pose) @ source.pose if source.pose is not None and target.pose is not None else None
            self.problem, self.threshold = problem, threshold
            self.display = Display(target, source)
            self.events, self.pushed, self.slice, self.model, self.finished_text = [], 0, None, None, ""
        self.h.vp_source.value = tuple(float(v) for v in source.viewpoint)
        self.h.vp_target.value = tuple(float(v) for v in target.viewpoint)
        self.h.reset_truth.disabled = self.T_truth is None
        self.h.show_model.value, self.h.show_model.disabled = False, True
        self._draw_scans()
        self._clear_run_views()
        self._show_pose_fields(T_init)
        self._update_status()

    def _problem_config(self) -> ProblemConfig:
        return ProblemConfig(max_points=int(self.h.max_points.value), frustum=self.h.frustum.value)

    def _threshold_setting(self) -> float | None:
        text = str(self.h.threshold.value).strip().lower()
        if text in ("", "auto"):
            return None
        try:
            v = float(text)
        except ValueError:
            raise InputError(f"threshold must be a number >= 0 or 'auto', got {text!r}") from None
        if not (np.isfinite(v) and v >= 0):
            raise InputError(f"threshold must be a number >= 0 or 'auto', got {text!r}")
        return v

    def _reprepare(self) -> None:
        if self.source is None or self.running:
            return
        problem = prepare(self.source, self.target, self.T_init, self._problem_config(), surface=self.surfaces[1],
                          seed=int(self.h.seed.value))
        with self.lock:
            self.problem = problem
        self._draw_overlap()
        self._update_status()

    # ---- the 3-D scene -------------------------------------------------------------------------
    def _draw_scans(self) -> None:
        d, sc, src, tgt = self.display, self.scene, self.source, self.target
        size = 0.8 * min(src.spacing, tgt.spacing) / d.size
        self.client.scene.set_up_direction("+y")
        with self.client.atomic():
            for node in self.nodes.values():
                try:
                    node.remove()
                except Exception:  # already gone with its parent
                    pass
            self.nodes.clear()
            wxyz, pos = d.node_pose(self.T)
            self.n_source = sc.add_frame("/source", show_axes=False, wxyz=wxyz, position=pos)
            # Every cloud twice: all points, and a fixed subset drawn while a run moves the scan (the
            # page redraws on every pose push; software WebGL draws ~1.3 M points/s on 2 cores).
            self.lod = {}
            for name, pts in (("/target", d.points(tgt.points)), ("/source", d.source_local(src.points))):
                sc.add_point_cloud(f"{name}/points", pts, self._colours(name), point_size=size, precision="float32")
                if len(pts) > RUN_POINTS:
                    keep = np.sort(np.random.default_rng(0).choice(len(pts), RUN_POINTS, replace=False))
                    self.lod[name] = keep
                    sc.add_point_cloud(f"{name}/points_run", pts[keep], self._colours(name)[keep], point_size=size,
                                       precision="float32", point_shading="flat", visible=False)
            self.n_gizmo = sc.add_transform_controls("/gizmo", scale=0.3, wxyz=wxyz, position=pos, depth_test=False,
                                                     translation_limits=((-1e6, 1e6),) * 3)
            self.n_gizmo.on_update(lambda e: self._dragged())
            sc.add_icosphere("/target/viewpoint", radius=0.015, color=TARGET_RGB, position=d.points(tgt.viewpoint))
            sc.add_icosphere("/source/viewpoint", radius=0.015, color=SOURCE_RGB,
                             position=d.source_local(src.viewpoint))
            self.n_path = sc.add_line_segments("/path", np.zeros((0, 2, 3), np.float32), (0, 0, 0),
                                               thickness=3.0, thickness_units="screen")
            self.n_minima = sc.add_point_cloud("/minima", np.zeros((0, 3), np.float32), MINIMUM_RGB,
                                               point_size=4 * size, precision="float32")
            # look from behind the target's sensor, so both scans and their frustums are in view
            eye = d.points(tgt.viewpoint).astype(np.float64)
            eye = 1.5 * eye / max(np.linalg.norm(eye), 1e-9) + np.array([0.0, 0.3, 0.0])
            self.client.camera.up_direction = (0.0, 1.0, 0.0)
            self.client.camera.position = tuple(eye)
            self.client.camera.look_at = (0.0, 0.0, 0.0)
        self._draw_frustums()
        self._draw_overlap()
        self._draw_surfaces()
        self._apply_visibility()

    def _draw_frustums(self) -> None:
        d = self.display
        f_src, f_tgt = self.frusta[self.h.frustum.value]
        self.scene.add_line_segments("/target/frustum", d.points(f_tgt.wireframe().reshape(-1, 3)).reshape(-1, 2, 3),
                                     TARGET_RGB, thickness=1.5, thickness_units="screen")
        self.scene.add_line_segments("/source/frustum",
                                     d.source_local(f_src.wireframe().reshape(-1, 3)).reshape(-1, 2, 3),
                                     SOURCE_RGB, thickness=1.5, thickness_units="screen")

    def _colours(self, name: str) -> np.ndarray:
        """(N, 3) uint8 per-point colours of a scan: the overlap points highlighted when shown."""
        src = name == "/source"
        scan = self.source if src else self.target
        rgb = np.empty((len(scan.points), 3), np.uint8)
        rgb[:] = SOURCE_RGB if src else TARGET_RGB
        p = self.problem
        if p is not None and self.h.show_overlap.value and (p.source is self.source and p.target is self.target):
            rgb[p.used if src else p.overlap.target_mask] = (
                SOURCE_OVERLAP_RGB if src else TARGET_OVERLAP_RGB)
        return rgb

    def _draw_overlap(self) -> None:
        """Recolour the clouds (colours only: the points stay where they are on the page)."""
        with self.client.atomic():
            for name in ("/target", "/source"):
                rgb = self._colours(name)
                if f"{name}/points" in self.nodes:
                    self.nodes[f"{name}/points"].colors = rgb
                if name in self.lod:
                    self.nodes[f"{name}/points_run"].colors = rgb[self.lod[name]]

    def _draw_surfaces(self) -> None:
        d = self.display
        self.n_surf_t = self.scene.add_mesh_simple("/target/surface", d.points(self.target.points), self.surfaces[1].faces,
                                                   color=TARGET_RGB, opacity=0.6, side="double", visible=False)
        self.n_surf_s = self.scene.add_mesh_simple("/source/surface", d.source_local(self.source.points),
                                                   self.surfaces[0].faces, color=SOURCE_RGB, opacity=0.6,
                                                   side="double", visible=False)

    def _apply_visibility(self) -> None:
        h = self.h
        show_model = bool(h.show_model.value and self.model is not None)
        with self.client.atomic():
            # Frustum wireframes cost a software-rendered page half its frame rate: off while a run draws.
            self._set_visible(("/target/frustum", "/source/frustum"),
                              h.show_frustums.value and not show_model and not self.run_drawing)
            self._set_visible(("/target/surface", "/source/surface"), h.show_surfaces.value and not show_model)
            self._set_visible(("/path", "/minima"), h.show_path.value)
            for name in ("/target", "/source"):
                light = self.run_drawing and name in self.lod
                self._set_visible((f"{name}/points",), not show_model and not light)
                self._set_visible((f"{name}/points_run",), not show_model and light)
            self._set_visible(("/model",), show_model)

    def _set_visible(self, names, visible: bool) -> None:
        for name in names:
            node = self.nodes.get(name)
            if node is not None:
                node.visible = bool(visible)

    def _move_source(self, T: np.ndarray, gizmo: bool = True) -> None:
        wxyz, pos = self.display.node_pose(T)
        self.n_source.wxyz, self.n_source.position = wxyz, pos
        if gizmo:
            self.n_gizmo.wxyz, self.n_gizmo.position = wxyz, pos

    # ---- the initial pose ------------------------------------------------------------------------
    def _dragged(self) -> None:
        if self.running or self.source is None:
            return
        T = self.display.pose_from_node(self.n_gizmo.wxyz, self.n_gizmo.position)
        with self.lock:
            self.T_init = self.T = T
            self.events, self.pushed, self.finished_text = [], 0, ""
        self._move_source(T, gizmo=False)
        self._clear_run_views()
        self._show_pose_fields(T)
        self._update_status()

    def _apply_typed_pose(self) -> None:
        p = np.array([float(h.value) for h in self.h.params])
        if not np.all(np.isfinite(p)):
            raise InputError("the six pose parameters must be finite numbers")
        self.set_initial(from_params(np.r_[p[:3], np.radians(p[3:])]))

    def _reset_truth(self) -> None:
        if self.T_truth is None:
            raise InputError("these scans carry no ground-truth pose")
        self.set_initial(self.T_truth)

    def set_initial(self, T: np.ndarray) -> None:
        self._require_idle()
        T = check_rigid(np.asarray(T, dtype=np.float64), "initial pose")
        with self.lock:
            self.T_init = self.T = T
            self.events, self.pushed, self.finished_text = [], 0, ""
        self._reprepare()
        self._move_source(T)
        self._clear_run_views()
        self._show_pose_fields(T)

    def _clear_run_views(self) -> None:
        with self.client.atomic():
            self.n_path.points = np.zeros((0, 2, 3), np.float32)
            self.n_minima.points = np.zeros((0, 3), np.float32)
            self.h.plot.data = Trail(self.display, []).plot(self.E0)

    def _show_pose_fields(self, T: np.ndarray) -> None:
        p = to_params(T)
        for h, v in zip(self.h.params, np.r_[p[:3], np.degrees(p[3:])]):
            h.value = float(v)

    # ---- runs ------------------------------------------------------------------------------------------
    @property
    def running(self) -> bool:
        return self.run is not None and self.run.running

    def _require_idle(self) -> None:
        if self.running:
            raise InputError("a run holds the scans: pause is not enough, Cancel it first")

    def _config(self, method: str) -> Config:
        t_start_text = str(self.h.t_start.value).strip().lower()
        try:
            t_start = None if t_start_text in ("", "auto") else float(t_start_text)
        except ValueError:
            raise InputError(f"start temperature must be a number or 'auto', got {t_start_text!r}") from None
        anneal = AnnealConfig(t_start=t_start, t_min_ratio=float(self.h.t_min.value), cooling=float(self.h.cooling.value),
                              max_evaluations=int(self.h.sa_max.value))
        seed = int(self.h.seed.value)
        cfg = Config(method=method, threshold=self._threshold_setting(), seed=seed, problem=self._problem_config(),
                     icp=IcpConfig(max_iterations=int(self.h.icp_max.value)), anneal=anneal,
                     sa_alone=replace(Config().sa_alone, t_start=t_start, cooling=float(self.h.cooling.value),
                                      max_evaluations=max(int(self.h.sa_max.value), 7)),
                     coarse_to_fine=bool(self.h.c2f.value), polish=bool(self.h.polish.value))
        if seed < 0:
            raise InputError(f"seed must be >= 0, got {seed}")
        cfg.validate()
        return cfg

    def start_run(self, method: str, mode: str = "run") -> None:
        if self.source is None:
            raise InputError("open two scans first")
        self._require_idle()
        cfg = self._config(method)
        source, target, T_init = self.source, self.target, self.T_init
        problem = self.problem

        def work(listener):
            return register(source, target, T_init, cfg, listener, problem=prepare(
                source, target, T_init, cfg.problem, surface=problem.surface, seed=cfg.seed))

        with self.lock:
            self.T = T_init
            self.events, self.pushed, self.finished_text, self.run_method = [], 0, "", method
            self.run = Run(work, mode=mode, on_done=self._finished)
            self.events = self.run.events
        self.n_gizmo.visible = False
        self._set_controls(running=True)
        self.run.start()

    def _control(self, action: str) -> None:
        """Pause, resume or cancel the run, and say so on the page at once (not at the next push)."""
        if self.run is None:
            return
        getattr(self.run, action)()
        if self.running:
            self._update_status()

    def step(self) -> None:
        if self.running:
            self.run.step()
        else:
            self.start_run("hybrid", mode="step")

    def next_phase(self) -> None:
        if self.running:
            self.run.next_phase()
        else:
            self.start_run("hybrid", mode="phase")

    def reset(self) -> None:
        if self.run is not None:
            self.run.cancel()
            self.run.join(2.0)
        self.set_initial(self.T_init)
        self._update_status()

    def _finished(self, run: Run) -> None:
        if run.failure is not None:
            self.notify("The run failed", str(run.failure))
            self.finished_text = f"**Finished**: the run failed: {run.failure}"
        else:
            r = run.result
            with self.lock:
                self.T = r.transform
                self.threshold = r.threshold
            below = "below" if r.error < r.threshold else "above"
            self.finished_text = (f"**Finished**: E = {r.error:.6g} ({below} the threshold {r.threshold:.4g}); "
                                  f"stopped: {r.stop_text}; {r.seconds:.2f} s")
        self.result = run.result

    def _set_controls(self, running: bool) -> None:
        h = self.h
        self.run_drawing = running
        self._apply_visibility()
        for b in [*h.run.values(), h.apply_pose, h.reset_file, h.reset_truth, h.open_scene, h.upload_source,
                  h.upload_target, h.apply_vp, h.merge, h.frustum, h.max_points]:
            b.disabled = running
        if running:
            h.reset_truth.disabled = True
        else:
            h.reset_truth.disabled = self.T_truth is None
        h.pause.disabled = h.resume.disabled = h.cancel.disabled = not running
        if hasattr(h, "open_files"):
            h.open_files.disabled = running

    # ---- the refresher: progress to the page at >= 10 Hz ---------------------------------------------------
    def _refresh_loop(self) -> None:
        was_running = False
        while not self.closed:
            time.sleep(REFRESH)
            try:
                running = self.running
                # the light view only while the scan moves: a paused run shows every point again
                light = running and not self.run.paused
                if light != self.run_drawing and self.source is not None:
                    self.run_drawing = light
                    self._apply_visibility()
                if self.source is not None and (running or was_running or self.pushed != len(self.events)):
                    self._push(running)
                    if was_running and not running:
                        self._set_controls(running=False)
                        self.n_gizmo.visible = True
                        self._move_source(self.T)
                        self._update_status()
                        if self.slice is not None:
                            self._draw_slice()
                was_running = running
            except Exception:  # a closed tab ends its refresher quietly
                if self.closed:
                    return
                time.sleep(0.5)

    @property
    def trail(self) -> Trail:
        """The drawing arrays of the current run's events (a new run, a new trail)."""
        if getattr(self, "_trail", None) is None or self._trail.events is not self.events:
            self._trail = Trail(self.display, self.events)
        return self._trail

    def _push(self, running: bool) -> None:
        trail = self.trail
        before = trail.n
        n = trail.update()
        if n == before and running:
            self._update_status()
            return
        self.pushed = n
        if n and running:
            self.T = self.events[n - 1].T
        seg, rgb = trail.segments()
        with self.client.atomic():
            self._move_source(self.T, gizmo=False)
            self.n_path.points, self.n_path.colors = seg, rgb
            self.n_minima.points = trail.pos[trail.minimum] if trail.minimum.any() else np.zeros((0, 3), np.float32)
            self.h.plot.data = trail.plot(self.E0)
            self._update_status()
        if self.slice is not None and time.monotonic() - self.slice_drawn_at > SLICE_REFRESH:
            self._draw_slice()

    @property
    def E0(self) -> float:
        """E at the initial pose (the error of the overlap cut under it)."""
        return float(self.problem.error(self.T_init)) if self.problem is not None else float("nan")

    def _update_status(self) -> None:
        trail = self.trail
        last = self.events[trail.n - 1] if trail.n else None
        n_icp, n_sa, n_min = trail.counts
        state = "running" if self.running and not self.run.paused else ("paused" if self.running else "idle")
        E0 = self.E0
        thr = f"{self.threshold:.4g}" if self.threshold is not None else "auto"
        units = self.target.units if self.target is not None else ""
        lines = [f"**{self.source.name if self.source else '-'} → {self.target.name if self.target else '-'}** "
                 f"({units}) · overlap {self.problem.used.sum() if self.problem else 0} points",
                 f"Method **{self.run_method or '-'}** · {state} · phase **{(last.phase.upper() if last else '-')}**",
                 f"Iterations: ICP {n_icp}, SA {n_sa} · local minima {n_min}",
                 f"E = {last.error:.6g}" if last else f"E = {E0:.6g} (initial)",
                 f"Temperature {last.temperature:.4g}" if last is not None and last.temperature is not None else "Temperature -",
                 f"Threshold {thr}"]
        if self.finished_text and not self.running:
            lines.append(self.finished_text)
        self.h.status.content = "  \n".join(lines)
        self.h.e_init.content = f"Initial E = {E0:.6g}"

    # ---- the slice ---------------------------------------------------------------------------------------
    def start_slice(self) -> None:
        if self.source is None:
            raise InputError("open two scans first")
        if self.slice_busy:
            raise InputError("a slice is already being computed")
        params = (self.h.slice_a.value, self.h.slice_b.value)
        if params[0] == params[1]:
            raise InputError("choose two different parameters for the slice")
        steps = int(self.h.steps.value)
        if not 2 <= steps <= 201:
            raise InputError(f"steps must be between 2 and 201, got {steps}")
        problem = self.problem
        spans = tuple(float(s.value) or default_span(problem, n) for s, n in zip((self.h.span_a, self.h.span_b), params))
        if not all(np.isfinite(s) and s > 0 for s in spans):
            raise InputError(f"spans must be positive numbers, got {spans}")
        center = self.T if not self.running else self.T_init
        bar = self.h.slice_progress
        bar.value, bar.visible = 0.0, True
        self.slice_busy = True
        self.h.compute_slice.disabled = True

        def work():
            try:
                sl = compute_slice(problem, center, params, spans, steps,
                                   progress=lambda f: setattr(bar, "value", 100.0 * f))
                with self.lock:
                    self.slice = (sl, problem)
                self._draw_slice()
            except Exception as exc:
                self.notify("Slice failed", str(exc))
            finally:
                self.slice_busy = False
                bar.visible = False
                self.h.compute_slice.disabled = False

        threading.Thread(target=work, daemon=True, name="rangereg-slice").start()

    def _slice_picture_data(self):
        sl, problem = self.slice
        events = self.events[: len(self.events)]
        poses = [self.T_init] + [e.T for e in events]
        xy = project(problem, sl.T_center, sl.params, poses) if events else None
        phases = ["icp"] + [e.phase for e in events] if events else None
        current = project(problem, sl.T_center, sl.params, [self.T])[0]
        title = f"{self.source.name} → {self.target.name}: log10 E({sl.params[0]}, {sl.params[1]})"
        return sl, xy, phases, current, title

    def _draw_slice(self) -> None:
        self.slice_drawn_at = time.monotonic()
        fig = slice_figure(*self._slice_picture_data())
        if self.h.slice_plot is None:
            with self.gui.add_folder("Error slice plot"):
                self.h.slice_plot = self.gui.add_plotly(fig, aspect=1.2)
        else:
            self.h.slice_plot.figure = fig

    # ---- the model -------------------------------------------------------------------------------------------
    def start_merge(self) -> None:
        if self.source is None:
            raise InputError("open two scans first")
        self._require_idle()
        from core.fuse import fuse

        source, target, T = self.source, self.target, self.T
        self.h.merge.disabled = True

        def work():
            try:
                model = fuse([target, source], [np.eye(4), T], [self.surfaces[1], self.surfaces[0]])
                with self.lock:
                    self.model = model
                self.scene.add_mesh_simple("/model", self.display.points(model.vertices), model.faces,
                                           color=(200, 200, 190), side="double")
                self.h.show_model.disabled = False
                self.h.show_model.value = True
                self._apply_visibility()
                self.notify("Model", f"{len(model.vertices)} vertices, {len(model.faces)} triangles", error=False)
            except Exception as exc:
                self.notify("Merge failed", str(exc))
            finally:
                self.h.merge.disabled = False

        threading.Thread(target=work, daemon=True, name="rangereg-merge").start()

    # ---- exports ---------------------------------------------------------------------------------------------
    def _download(self, name: str, data: bytes) -> None:
        self.client.send_file_download(name, data, save_immediately=True)

    def _export_transform(self) -> None:
        r = getattr(self, "result", None)
        extra = {"error": float(self.problem.error(self.T)), "source": self.source.name, "target": self.target.name,
                 "convention": "maps SOURCE coordinates into TARGET's frame (T_target_source)"}
        if r is not None:
            extra.update(method=r.method, threshold=r.threshold, stop_reason=r.stop_text)
        self._download(f"{self.source.name}_to_{self.target.name}.json",
                       (json.dumps({"transform": self.T.tolist(), **extra}, indent=1) + "\n").encode())

    def _export_trace(self) -> None:
        if not self.events:
            raise InputError("no run yet: nothing to export")
        text = "".join(json.dumps(e.to_json()) + "\n" for e in list(self.events))
        self._download("trace.jsonl", text.encode())

    def _export_scans(self) -> None:
        pts = np.vstack([self.target.points, apply(self.T, self.source.points)])
        rgb = np.vstack([np.tile(TARGET_RGB, (len(self.target.points), 1)), np.tile(SOURCE_RGB, (len(self.source.points), 1))])
        self._download(f"{self.target.name}+{self.source.name}_registered.ply", ply_bytes(pts, None, rgb.astype(np.uint8)))

    def _export_slice(self) -> None:
        if self.slice is None:
            raise InputError("compute a slice first")
        self._download("slice.png", png_bytes(*self._slice_picture_data()))

    def _export_model(self) -> None:
        if self.model is None:
            raise InputError("press Merge first")
        self._download("model.ply", ply_bytes(self.model.vertices, self.model.faces))

    def close(self) -> None:
        self.closed = True
        if self.run is not None:
            self.run.cancel()



class _Kept:
    """client.scene, remembering each node it adds in ``session.nodes`` (a re-added name replaces it)."""

    def __init__(self, scene, session: Session):
        self._scene, self._session = scene, session

    def __getattr__(self, name):
        fn = getattr(self._scene, name)
        if not name.startswith("add_"):
            return fn

        def add(*args, **kwargs):
            handle = fn(*args, **kwargs)
            self._session.nodes[handle.name] = handle
            return handle

        return add
