"""A run as a recording that plays in a browser with no rangereg process and no network.

One self-contained HTML file: viser's own built client (shipped in the viser wheel as a single
``client/build/index.html``) with the scene recording embedded as base64 (the client plays
``window.__VISER_EMBED_DATA__``, the format of viser's ``.viser`` files). The recording holds the
scans, their frustums, the moving scan over time, the path growing as it moves (ICP green, SA
magenta) and, when a slice was computed, the landscape as a 3-D height field with the path on it; a line of text
follows the run (event k of n, its iteration, phase, E and temperature), beside a legend of the colours.

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
from rangereg.app.figures import LEGEND, MINIMUM_RGB, PHASE_LABEL, PHASE_TABLE, SOURCE_RGB, TARGET_RGB, fmt, squared_unit
from rangereg.app.tab.scene3d import set_lights
from rangereg.app.views import Display, Trail, temperature_of
from rangereg.core.errors import InputError

MAX_POINTS = 20000  # per scan in the recording: the file stays a few MB
FRAMES = 150  # poses the recording steps through (evenly over the run's events)
SECONDS = 10.0  # how long the recording plays
HOLD = 1.0  # seconds the start pose is held before the scan moves
CAMERA_AT, CAMERA_LOOK_AT = (0.7, 1.3, 2.6), (0.7, 0.0, 0.0)  # both the scans and the terrain in view
LEGEND_AT = (-0.95, 0.75, 0.0)  # page units: the legend's first entry, above and left of the scans; the next below
LEGEND_STEP = 0.075
INFO_AT = (-0.95, 0.95, 0.0)  # the line that follows the run, above the legend
RECORDED_LEGEND = ("source", "target", "ICP", "annealing (SA)", "local minimum")


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


def client_html() -> str:
    """viser's built single-file client, from the installed wheel."""
    import viser

    path = Path(viser.__file__).parent / "client" / "build" / "index.html"
    if not path.is_file():
        raise InputError(f"this viser install ships no built client ({path}): cannot write a recording")
    return path.read_text(encoding="utf-8")


def embed(recording: bytes) -> bytes:
    """The HTML page playing ``recording`` (a .viser byte string) with no server."""
    page = client_html()
    data = base64.b64encode(recording).decode("ascii")
    script = f'<script>window.__VISER_EMBED_DATA__ = "{data}";</script>\n'
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
    for which, f, to_page, rgb in (("source", run.frustums[0], d.source_local, SOURCE_RGB),
                                   ("target", run.frustums[1], d.points, TARGET_RGB)):
        scene.add_line_segments(f"/{which}/frustum", to_page(f.wireframe().reshape(-1, 3)).reshape(-1, 2, 3), rgb,
                                thickness=1.5, thickness_units="screen")
    return frame, size


def _legend(scene) -> None:
    """The colours of what the recording draws, each a swatch and its name (app.figures.LEGEND)."""
    x, y, z = LEGEND_AT
    for k, (name, rgb) in enumerate(e for e in LEGEND if e[0] in RECORDED_LEGEND):
        at = (x, y - k * LEGEND_STEP, z)
        scene.add_icosphere(f"/legend/{k}/swatch", radius=0.018, color=rgb, position=at)
        scene.add_label(f"/legend/{k}/name", name, position=(x + 0.035, at[1], z), anchor="center-left")


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
        recorder = server.get_scene_serializer()
        # recorded after the snapshot: the camera messages are then part of the file
        server.initial_camera.look_at = CAMERA_LOOK_AT if terrain is not None else (0.0, 0.0, 0.0)
        server.initial_camera.position = CAMERA_AT if terrain is not None else (0.0, 0.4, 1.8)
        recorder.insert_sleep(hold)
        steps = np.unique(np.linspace(0, len(pos) - 1, min(frames, len(pos))).astype(int))
        last = 0
        for i, k in enumerate(steps):
            T = run.T_start if k == 0 else run.events[k - 1].T
            frame.wxyz, frame.position = run.display.node_pose(T)
            info.text = event_line(run, int(k))
            keep = np.unique(np.r_[np.linspace(last, k, min(k - last + 1, 40)).astype(int), k])
            _part(scene, f"/path/part{i}", pos[keep], phase[keep])
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
