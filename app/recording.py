"""A run as a recording that plays in a browser with no rangereg process and no network.

One self-contained HTML file: viser's own built client (shipped in the viser wheel as a single
``client/build/index.html``) with the scene recording embedded as base64 (the client plays
``window.__VISER_EMBED_DATA__``, the format of viser's ``.viser`` files). The recording holds the
scans, their frustums (over the scans' depths, :func:`frustum_segments`), the moving scan over time, the path
growing as it moves (ICP green, SA magenta) and, when a slice was computed, the landscape as a 3-D height field with
the path on it; a line of text follows the run (event k of n, its iteration, phase, E and temperature), beside a
legend of the colours, and the chart of log10 E against iteration grows beside the scans as the run plays.

The page's E chart is a viser GUI element (uPlot), and a recording holds scene messages only: viser marks every
GUI message ``include_in_scene_serialization=False`` (``_CreateGuiComponentMessage`` in viser/_messages.py, the
filter ``ViserServer.get_scene_serializer`` applies). So the recording draws the same series (app.views.Trail.chart:
ICP, SA and candidates by phase, the threshold) as line segments in a plane of the scene facing the opening camera,
with its axis values as labels. The opening camera frames the scans and the chart from outside both frustums
(app.tab.scene3d.default_view, the page's own).

viser records a scene through a server, so a throwaway one is started on a free loopback port for
the few seconds it takes (it serves nobody: no browser is pointed at it).
"""

from __future__ import annotations

import base64
import contextlib
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rangereg.app.access import free_port
from rangereg.app.figures import (
    LEGEND,
    MINIMUM_RGB,
    PHASE_LABEL,
    PHASE_TABLE,
    SOURCE_RGB,
    TARGET_RGB,
    faded,
    fmt,
    squared_unit,
)
from rangereg.app.tab.scene3d import DEFAULT_FOV, FRUSTUM_THICKNESS, default_view, set_lights
from rangereg.app.views import Display, Trail, temperature_of
from rangereg.core.errors import InputError
from rangereg.core.frustum import Frustum

DEPTH_PAD = 0.05  # a frustum is drawn over its scan's depths, this share of their range beyond (frustum_segments)
MAX_POINTS = 20000  # per scan in the recording: the file stays a few MB
FRAMES = 150  # poses the recording steps through (evenly over the run's events)
SECONDS = 10.0  # how long the recording plays
HOLD = 1.0  # seconds the start pose is held before the scan moves
CHART_SIZE = (0.8, 0.45)  # page units (the target's size is 1): the chart's width and height
CHART_GAP = 0.15  # page units between the scans' box and the chart, on the camera's right
CHART_AXES_RGB = (110, 110, 110)
THRESHOLD_RGB = (200, 0, 0)
LEGEND_AT = (-0.95, 0.75, 0.0)  # page units: the legend's first entry, above and left of the scans; the next below
LEGEND_STEP = 0.075
INFO_AT = (-0.95, 0.95, 0.0)  # the line that follows the run, above the legend
RECORDING_ASPECT = 1.6  # the opening view's canvas, width over height: the recording fills the browser's window (no
# panel beside it), 1.6-1.8 on a laptop or a monitor; framed as the page's docked canvas (1.1), the bunny's scans and
# chart took under half of a 1280 x 720 window. A window narrower than 1.45 (1.6 less Fit view's margin) cuts the sides
RECORDED_LEGEND = ("source", "target", "ICP", "annealing (SA)", "candidates", "local minimum")


@dataclass(frozen=True, eq=False)
class RunToRecord:
    """What a recording shows: the pair at its display, frustums (source, target), the run's start and events."""

    source: object  # core.scan.Scan
    target: object
    display: Display
    frustums: tuple
    T_start: np.ndarray
    events: list
    slice_view: object | None = None  # app.tab.state.SliceView
    units: str = ""
    E0: float = float("nan")  # E at the start (the chart's first point; NaN: the first event's)
    threshold: float | None = None  # the run's threshold (the chart's red line; None: not drawn)


def client_html() -> str:
    """viser's built single-file client, from the installed wheel."""
    import viser

    path = Path(viser.__file__).parent / "client" / "build" / "index.html"
    if not path.is_file():
        raise InputError(f"this viser install ships no built client ({path}): cannot write a recording")
    return path.read_text(encoding="utf-8")


# viser's client says in a notice at the window's top-left when WebGL runs in software (or is missing, or the browser
# is old), where the recording's line and legend are (a 1000 x 700 window: the line and "source" under it): the
# notices are moved to the bottom-left, under the legend and beside the scans, their text unchanged
NOTICES_CSS = ".mantine-Notifications-root{top:auto!important;bottom:1em!important}"


def embed(recording: bytes) -> bytes:
    """The HTML page playing ``recording`` (a .viser byte string) with no server."""
    page = client_html()
    data = base64.b64encode(recording).decode("ascii")
    script = f'<style>{NOTICES_CSS}</style>\n<script>window.__VISER_EMBED_DATA__ = "{data}";</script>\n'
    head = page.index("<script")
    return (page[:head] + script + page[head:]).encode("utf-8")


def _thin(points: np.ndarray, cap: int = MAX_POINTS) -> np.ndarray:
    if len(points) <= cap:
        return points
    return points[np.sort(np.random.default_rng(0).choice(len(points), cap, replace=False))]


def _draw_pair(scene, run: RunToRecord):
    d = run.display
    size = 0.8 * min(run.source.spacing, run.target.spacing) / d.size
    scene.set_up_direction("+y")
    set_lights(scene)
    scene.add_point_cloud("/target/points", _thin(d.points(run.target.points)), TARGET_RGB, point_size=size,
                          precision="float32")
    wxyz, pos = d.node_pose(run.T_start)
    frame = scene.add_frame("/source", show_axes=False, wxyz=wxyz, position=pos)
    scene.add_point_cloud("/source/points", _thin(d.source_local(run.source.points)), SOURCE_RGB, point_size=size,
                          precision="float32")
    for which, f, scan, to_page, rgb in (("source", run.frustums[0], run.source, d.source_local, SOURCE_RGB),
                                         ("target", run.frustums[1], run.target, d.points, TARGET_RGB)):
        segments = frustum_segments(f, scan.points)
        scene.add_line_segments(f"/{which}/frustum", to_page(segments.reshape(-1, 3)).reshape(-1, 2, 3),
                                faded(rgb), thickness=FRUSTUM_THICKNESS, thickness_units="screen")
    return frame, size


def frustum_segments(view, points: np.ndarray) -> np.ndarray:
    """(S, 2, 3) line segments drawing ``view`` (core.frustum's, of the scan with (N, 3) ``points``, in its frame) in
    the recording: a frustum over its scan's depths (padded by DEPTH_PAD of their range), the part of the pyramid the
    scan fills, its spokes pointing the sensor's way. Drawn from the sensor to its far outline (1.05 x the farthest
    depth), the bunny's spokes (1.2 m long, to scans 0.15 m across) were most of what the opening view showed.
    Other views: their own wireframe."""
    if not isinstance(view, Frustum):
        return view.wireframe()
    _, depth = view.project(points)
    ahead = depth[depth > 0]
    if not len(ahead):
        return view.wireframe()
    pad = DEPTH_PAD * float(np.ptp(ahead))
    front, back = view.outline_points(max(float(ahead.min()) - pad, 0.0)), view.outline_points(float(ahead.max()) + pad)
    rings = [np.stack([o, np.roll(o, -1, axis=0)], axis=1) for o in (front, back)]
    return np.concatenate([np.stack([front, back], axis=1), *rings])


def _legend(scene) -> None:
    """The colours of what the recording draws, each a swatch and its name (app.figures.LEGEND)."""
    x, y, z = LEGEND_AT
    for k, (name, rgb) in enumerate(e for e in LEGEND if e[0] in RECORDED_LEGEND):
        at = (x, y - k * LEGEND_STEP, z)
        scene.add_icosphere(f"/legend/{k}/swatch", radius=0.018, color=rgb, position=at)
        scene.add_label(f"/legend/{k}/name", name, position=(x + 0.035, at[1], z), anchor="center-left")


def _label_anchors() -> np.ndarray:
    """(2, 3) page points: where the line that follows the run and the legend's last entry are anchored (their text
    runs right from there), for the opening view to take in."""
    n = sum(1 for e in LEGEND if e[0] in RECORDED_LEGEND)
    x, y, z = LEGEND_AT
    return np.array([INFO_AT, (x, y - (n - 1) * LEGEND_STEP, z)], np.float64)


def event_line(run: RunToRecord, k: int) -> str:
    """What the recording says at its k-th event (0: the start)."""
    n = len(run.events)
    if k == 0:
        return f"event 0 of {n}: the start"
    e = run.events[k - 1]
    u = squared_unit(run.units)
    temp = temperature_of(e)
    return (f"event {k} of {n} · iteration {e.iteration} · {PHASE_LABEL.get(e.phase, e.phase)} · E = {fmt(e.error)} {u}"
            + (f" · temperature {fmt(temp)} {u}" if np.isfinite(temp) else ""))


def _part(scene, name: str, points: np.ndarray, phase: np.ndarray) -> None:
    """Line segments through ``points`` (K, 3), each coloured by the phase of its end (``phase`` (K,): rows of
    PHASE_TABLE)."""
    if len(points) < 2:
        return
    rgb = PHASE_TABLE[phase[1:]]
    scene.add_line_segments(name, np.stack([points[:-1], points[1:]], axis=1), np.repeat(rgb[:, None], 2, axis=1),
                            thickness=3.0, thickness_units="screen")


@dataclass(frozen=True, eq=False)
class Chart:
    """The E chart in the scene: ``xy`` (K, 2) chart coordinates in [0, 1]^2 of the start and each event (iteration,
    log10 E), ``phase`` (K,) rows of PHASE_TABLE, the threshold's height (None: none), the plane it is drawn in
    (``origin`` (3,) its lower-left corner, ``right``, ``up`` (3,) unit axes, page units) and its axis values."""

    xy: np.ndarray
    phase: np.ndarray
    threshold_y: float | None
    origin: np.ndarray
    right: np.ndarray
    up: np.ndarray
    iterations: float
    log_range: tuple[float, float]

    def at(self, xy: np.ndarray) -> np.ndarray:
        """(K, 3) page points of chart coordinates (K, 2)."""
        w, h = CHART_SIZE
        return (self.origin + xy[:, :1] * w * self.right + xy[:, 1:] * h * self.up).astype(np.float32)

    def corners(self) -> np.ndarray:
        return self.at(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))


def chart_of(run: RunToRecord, trail: Trail, eye: np.ndarray, look_at: np.ndarray, extent: np.ndarray) -> Chart:
    """The chart of ``trail`` (its events taken in), placed on the camera's right of the scans' page ``extent``
    (K, 3), in the plane facing the camera at ``eye`` looking at ``look_at``."""
    E0 = run.E0 if np.isfinite(run.E0) else float(trail.error[0])
    it = np.maximum.accumulate(np.r_[0.0, trail.iteration])
    err = np.r_[E0, trail.error].astype(float)
    positive = err[err > 0]
    floor = positive.min() if len(positive) else 1.0
    logs = np.log10(np.maximum(err, floor))
    thr = np.log10(run.threshold) if run.threshold is not None and run.threshold > 0 else None
    lo, hi = min(logs.min(), thr if thr is not None else np.inf), max(logs.max(), thr if thr is not None else -np.inf)
    if hi - lo < 1e-9:
        lo, hi = lo - 0.5, hi + 0.5
    xy = np.c_[it / max(it[-1], 1.0), (logs - lo) / (hi - lo)]
    way = np.asarray(eye, float) - np.asarray(look_at, float)
    way /= np.linalg.norm(way)
    right = np.cross([0.0, 1.0, 0.0], way)
    right /= np.linalg.norm(right)
    up = np.cross(way, right)
    rel = extent - np.asarray(look_at, float)
    origin = np.asarray(look_at, float) + ((rel @ right).max() + CHART_GAP) * right - 0.5 * CHART_SIZE[1] * up
    return Chart(xy, np.r_[0, trail.phase].astype(np.int8), None if thr is None else (thr - lo) / (hi - lo), origin,
                 right, up, float(it[-1]), (float(lo), float(hi)))


def _draw_chart_frame(scene, chart: Chart, units: str) -> None:
    """The chart's axes, its threshold line and its axis values (the series grows in :func:`record`)."""
    box = chart.at(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])).reshape(2, 2, 3)
    scene.add_line_segments("/chart/axes", box, CHART_AXES_RGB, thickness=1.0, thickness_units="screen")
    if chart.threshold_y is not None:
        dashes = np.linspace(0.0, 1.0, 41)
        ends = np.c_[dashes[:-1:2], dashes[1::2]]
        pts = chart.at(np.c_[ends.reshape(-1), np.full(ends.size, chart.threshold_y)]).reshape(-1, 2, 3)
        scene.add_line_segments("/chart/threshold", pts, THRESHOLD_RGB, thickness=1.5, thickness_units="screen")
    lo, hi = chart.log_range
    for name, xy, text, anchor in (
            ("title", (0.0, 1.08), f"log10 E ({squared_unit(units)}) against iteration", "bottom-left"),
            ("y_hi", (-0.02, 1.0), f"{hi:.2g}", "center-right"), ("y_lo", (-0.02, 0.0), f"{lo:.2g}", "center-right"),
            ("x_lo", (0.0, -0.04), "0", "top-center"), ("x_hi", (1.0, -0.04), f"{chart.iterations:.0f}", "top-center")):
        scene.add_label(f"/chart/{name}", text, position=tuple(chart.at(np.array([xy]))[0]), anchor=anchor)
    if chart.threshold_y is not None:
        scene.add_label("/chart/threshold_name", "threshold", position=tuple(chart.at(np.array([[1.0, chart.threshold_y]]))[0]),
                        anchor="center-left")


def opening_view(run: RunToRecord, trail: Trail, terrain_box: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, Chart]:
    """(eye, look_at, chart): the recording's opening camera and its chart. The scans (and the terrain's (K, 3) page
    points ``terrain_box``) framed from outside both frustums, the chart placed on that view's right, then the view
    widened to take the chart in too (still from outside the frustums: app.tab.scene3d.default_view)."""
    from rangereg.app.tab.scene3d import pair_extent

    d = run.display
    extent = pair_extent(d, run.target, run.source, run.T_start)
    eye, look_at = default_view(d, run.target, run.source, run.T_start, run.frustums, terrain_box, RECORDING_ASPECT)
    chart = chart_of(run, trail, eye, look_at, extent if terrain_box is None else np.r_[extent, terrain_box])
    framed = np.r_[chart.corners(), _label_anchors()] if terrain_box is None else \
        np.r_[terrain_box, chart.corners(), _label_anchors()]
    eye, look_at = default_view(d, run.target, run.source, run.T_start, run.frustums, framed, RECORDING_ASPECT)
    return eye, look_at, chart


def record(run: RunToRecord, frames: int = FRAMES, seconds: float = SECONDS, hold: float = HOLD) -> bytes:
    """The recording (.viser bytes): the pair, then the scan moving along the run with its path growing."""
    import viser
    from rangereg.app.access import Guard, guarded_viser
    from rangereg.app.tab.terrain import PathOnSlice, Terrain, on_surface

    if not run.events:
        raise InputError("no run yet: nothing to record")
    trail = Trail(run.display, run.events)
    trail.update()
    start = run.display.points((run.T_start[:3, :3] @ run.display.source_centre + run.T_start[:3, 3])[None])
    pos, phase = np.r_[start, trail.pos], np.r_[0, trail.phase].astype(np.int8)
    minimum = np.r_[False, trail.minimum]
    with guarded_viser(Guard("127.0.0.1")), contextlib.redirect_stdout(io.StringIO()):  # no banner on the console
        server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        scene = server.scene
        frame, size = _draw_pair(scene, run)
        terrain = on_terrain = None
        if run.slice_view is not None:
            terrain = Terrain(scene, run.slice_view, run.units, run.T_start, [])
            path = PathOnSlice(run.slice_view.problem, run.slice_view.slice, run.T_start, run.events)
            path.update()
            on_terrain = on_surface(run.slice_view.slice, path.xy)
        _legend(scene)
        info = scene.add_label("/info", event_line(run, 0), position=INFO_AT, anchor="center-left")
        eye, look_at, chart = opening_view(run, trail, terrain.extent() if terrain is not None else None)
        _draw_chart_frame(scene, chart, run.units)
        recorder = server.get_scene_serializer()
        # recorded after the snapshot: the camera messages are then part of the file
        server.initial_camera.up = (0.0, 1.0, 0.0)
        server.initial_camera.fov = float(DEFAULT_FOV)  # the field of view the opening view was framed for
        server.initial_camera.position = tuple(eye)
        server.initial_camera.look_at = tuple(look_at)
        recorder.insert_sleep(hold)
        steps = np.unique(np.linspace(0, len(pos) - 1, min(frames, len(pos))).astype(int))
        last = 0
        for i, k in enumerate(steps):
            T = run.T_start if k == 0 else run.events[k - 1].T
            frame.wxyz, frame.position = run.display.node_pose(T)
            info.text = event_line(run, int(k))
            keep = np.unique(np.r_[np.linspace(last, k, min(k - last + 1, 40)).astype(int), k])
            _part(scene, f"/path/part{i}", pos[keep], phase[keep])
            _part(scene, f"/chart/series/part{i}", chart.at(chart.xy[keep]), phase[keep])
            mins = np.flatnonzero(minimum[last + 1:k + 1]) + last + 1
            if len(mins):
                scene.add_point_cloud(f"/minima/part{i}", pos[mins], MINIMUM_RGB, point_size=4 * size,
                                      precision="float32")
            if terrain is not None:
                _part(scene, f"/terrain/path/part{i}", on_terrain[keep], phase[keep])
                terrain.current.position = tuple(on_terrain[k])
            last = k
            recorder.insert_sleep(seconds / len(steps))
        return recorder.serialize()
    finally:
        server.stop()


def recording_html(run: RunToRecord, frames: int = FRAMES, seconds: float = SECONDS, hold: float = HOLD) -> bytes:
    """One HTML file that plays the run in a browser from disk (see the module's docstring)."""
    return embed(record(run, frames, seconds, hold))
