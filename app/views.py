"""What the page draws, computed from core objects: display coordinates, path arrays, figures.

The page shows the target's frame, shifted to the target's centroid and divided by its size, so
every scene (metres or millimetres) opens at the same comfortable scale. The moving scan is one
scene node placed at its own centroid; moving it is a change of that node's pose only.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from core.events import Event
from core.landscape import Slice
from core.scan import Scan

TARGET_RGB = (60, 120, 220)
SOURCE_RGB = (240, 140, 30)
TARGET_OVERLAP_RGB = (120, 230, 255)
SOURCE_OVERLAP_RGB = (255, 225, 60)
PHASE_RGB = {"icp": (30, 170, 70), "sa": (210, 50, 200)}
MINIMUM_RGB = (230, 30, 30)
MAX_PATH_POINTS = 3000  # the drawn path is thinned to this many points (the trace keeps them all)
MAX_PLOT_POINTS = 2000


class Display:
    """Maps the target's frame to the page: x -> (x - centre) / size."""

    def __init__(self, target: Scan, source: Scan):
        self.centre = target.centroid
        self.size = max(target.size, 1e-12)
        self.source_centre = source.centroid

    def points(self, p: np.ndarray) -> np.ndarray:
        return ((np.asarray(p) - self.centre) / self.size).astype(np.float32)

    def source_local(self, p: np.ndarray) -> np.ndarray:
        """Source-frame points as children of the moving node (float32)."""
        return ((np.asarray(p) - self.source_centre) / self.size).astype(np.float32)

    def node_pose(self, T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(wxyz, position) of the moving node for T_target_source."""
        q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x y z w
        pos = (T[:3, :3] @ self.source_centre + T[:3, 3] - self.centre) / self.size
        return np.r_[q[3], q[:3]], pos

    def pose_from_node(self, wxyz, position) -> np.ndarray:
        """T_target_source from the moving node's (wxyz, position): inverse of :meth:`node_pose`."""
        w, x, y, z = wxyz
        R = Rotation.from_quat([x, y, z, w]).as_matrix()
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = np.asarray(position) * self.size + self.centre - R @ self.source_centre
        return T


def path_arrays(display: Display, events: list[Event]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node positions (K, 3), phases (K,) and local-minimum flags (K,) along a run's events."""
    if not events:
        return np.zeros((0, 3), np.float32), np.zeros(0, "<U3"), np.zeros(0, bool)
    Ts = np.stack([e.T for e in events])
    ref = np.einsum("kij,j->ki", Ts[:, :3, :3], display.source_centre) + Ts[:, :3, 3]
    return (display.points(ref), np.array([e.phase for e in events]), np.array([e.local_minimum for e in events]))


def path_segments(pos: np.ndarray, phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Line segments (S, 2, 3) and colours (S, 2, 3) for a path, thinned to MAX_PATH_POINTS."""
    if len(pos) < 2:
        return np.zeros((0, 2, 3), np.float32), np.zeros((0, 2, 3), np.uint8)
    keep = np.unique(np.r_[np.linspace(0, len(pos) - 1, min(len(pos), MAX_PATH_POINTS)).astype(int), len(pos) - 1])
    pos, phases = pos[keep], phases[keep]
    seg = np.stack([pos[:-1], pos[1:]], axis=1)
    rgb = np.array([PHASE_RGB.get(p, (128, 128, 128)) for p in phases[1:]], np.uint8)
    return seg, np.repeat(rgb[:, None, :], 2, axis=1)


def plot_series(events: list[Event], E0: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(iteration, E during ICP, E during SA) for the uPlot chart; the other phase is NaN (a gap).

    Both series start at iteration 0 with E at the initial pose (``E0``), the start both share; a
    series of NaN only would leave the chart blank.
    """
    keep = np.unique(np.linspace(0, len(events) - 1, min(len(events), MAX_PLOT_POINTS)).astype(int)) if events else []
    it = np.r_[0.0, [events[k].iteration for k in keep]]
    # an ICP "local minimum" mark repeats the last iteration: nudge it so x stays increasing
    it = np.maximum.accumulate(it + np.arange(len(it)) * 1e-6)
    err = np.r_[E0, [events[k].error for k in keep]]
    is_icp = np.array([True] + [events[k].phase == "icp" for k in keep], bool)
    is_sa = np.r_[True, ~is_icp[1:]]
    return it, np.where(is_icp, err, np.nan), np.where(is_sa, err, np.nan)


def slice_figure(sl: Slice, path_xy: np.ndarray | None, phases: list[str] | None, current: np.ndarray | None,
                 title: str):
    """A Plotly contour map of log10 E with the run's path and the current pose on it."""
    import plotly.graph_objects as go

    z = np.log10(np.maximum(sl.values, np.nanmin(sl.values[sl.values > 0]) if np.any(sl.values > 0) else 1e-300))
    fig = go.Figure(go.Contour(x=sl.axis_a, y=sl.axis_b, z=z.T, colorscale="Viridis", ncontours=25,
                               colorbar=dict(title="log10 E", thickness=12)))
    if path_xy is not None and len(path_xy):
        phases = phases or ["icp"] * len(path_xy)
        for phase, name in (("icp", "ICP"), ("sa", "SA")):
            mask = np.array([p == phase for p in phases])
            xy = np.where(mask[:, None], path_xy, np.nan)
            fig.add_trace(go.Scatter(x=xy[:, 0], y=xy[:, 1], mode="lines", name=name,
                                     line=dict(color=f"rgb{PHASE_RGB[phase]}", width=2)))
        fig.add_trace(go.Scatter(x=path_xy[:1, 0], y=path_xy[:1, 1], mode="markers", name="start",
                                 marker=dict(color="white", size=10, line=dict(color="black", width=1))))
    if current is not None:
        fig.add_trace(go.Scatter(x=[current[0]], y=[current[1]], mode="markers", name="current",
                                 marker=dict(symbol="x", color="red", size=12)))
    unit = lambda n: "deg" if n.startswith("r") else "units"  # noqa: E731
    fig.update_layout(title=dict(text=title, font=dict(size=12)), margin=dict(l=40, r=10, t=30, b=35),
                      xaxis_title=f"{sl.params[0]} ({unit(sl.params[0])})",
                      yaxis_title=f"{sl.params[1]} ({unit(sl.params[1])})",
                      legend=dict(orientation="h", y=-0.25), height=360)
    return fig


def ply_bytes(points: np.ndarray, faces: np.ndarray | None = None, colors: np.ndarray | None = None) -> bytes:
    """A binary PLY in memory (for downloads)."""
    import tempfile
    from pathlib import Path

    from core.ply import write_ply

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "out.ply"
        write_ply(path, points, faces, colors)
        return path.read_bytes()


def png_bytes(sl: Slice, path_xy, phases, current, title) -> bytes:
    import tempfile
    from pathlib import Path

    from app.plots import slice_png

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "slice.png"
        slice_png(sl, out, path_xy, phases, current, title)
        return out.read_bytes()

