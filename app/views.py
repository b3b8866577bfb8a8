"""What the page draws, computed from core objects: display coordinates, path arrays, figures.

The page shows the target's frame, shifted to the target's centroid and divided by its size, so
every scene (metres or millimetres) opens at the same comfortable scale. The moving scan is one
scene node placed at its own centroid; moving it is a change of that node's pose only.
"""

from __future__ import annotations

import numpy as np
from rangereg.app.figures import (
    MINIMUM_RGB,
    PHASE_LABEL,
    PHASE_NAMES,
    PHASE_RGB,
    PHASE_TABLE,
    axis_label,
    log_values,
    phase_code,
    squared_unit,
)
from rangereg.core.events import Event
from rangereg.core.landscape import Slice
from rangereg.core.scan import Scan
from scipy.spatial.transform import Rotation

MAX_PATH_POINTS = 300  # the drawn path is thinned to at most this many points, plus its phase ends and minima
# (the trace keeps them all). Each segment is a fat line of 6 triangles: in software WebGL (headless Chromium,
# SwiftShader) a frame of the bunny SA run cost the GPU process 125-155 ms of CPU with 1500 segments, 85-90 ms
# with 300, ~90 ms with the path hidden (load 4-6 on 2 cores); its thickness and its updates cost nothing seen
MAX_PLOT_POINTS = 2000


def thin(n: int, most: int, keep: np.ndarray | None = None) -> np.ndarray:
    """Sorted indices of at most ``most`` (+ the last) of ``n`` path points, every ``2**k``-th one, and every index
    where ``keep`` (n,) bool is set (a phase's ends, local minima).

    The stride is a power of two that doubles as the path grows, so the points kept stay the same from one push
    to the next (a live path does not shimmer), and the first and the last point are always kept.
    """
    if n <= 0:
        return np.zeros(0, int)
    stride = 1 << max(0, int(np.ceil(np.log2(n / most)))) if n > most else 1
    idx = np.r_[np.arange(0, n, stride), n - 1]
    if keep is not None and keep.any():
        idx = np.r_[idx, np.flatnonzero(keep)]
    return np.unique(idx)


def phase_ends(phase: np.ndarray) -> np.ndarray:
    """(K,) bool: the first and last point of each run of one phase in ``phase`` (K,), so a thinned path keeps
    every leg, however short, in its own colour."""
    change = np.zeros(len(phase), bool)
    if len(phase) > 1:
        d = phase[1:] != phase[:-1]
        change[1:] |= d
        change[:-1] |= d
    return change


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


class Trail:
    """A run's events as arrays for drawing, extended incrementally (each event is converted once).

    pos: (K, 3) float32 node positions on the page; sa, minimum: (K,) bool; phase: (K,) rows of
    app.figures.PHASE_TABLE (the path's colours); iteration, error: (K,); temperature: (K,) annealing's
    temperature (E's units), NaN where there is none yet (ICP, and a leg's first simplex, measured before the
    temperature is set from it).
    """

    def __init__(self, display: Display, events: list[Event]):
        self.display, self.events, self.n = display, events, 0
        self.pos = np.zeros((0, 3), np.float32)
        self.sa = np.zeros(0, bool)
        self.phase = np.zeros(0, np.int8)
        self.minimum = np.zeros(0, bool)
        self.iteration = np.zeros(0)
        self.error = np.zeros(0)
        self.temperature = np.zeros(0)

    def update(self) -> int:
        """Take in the events that arrived since the last call; returns how many there are now."""
        n = len(self.events)
        new = self.events[self.n:n]
        if new:
            Ts = np.stack([e.T for e in new])
            ref = np.einsum("kij,j->ki", Ts[:, :3, :3], self.display.source_centre) + Ts[:, :3, 3]
            self.pos = np.concatenate([self.pos, self.display.points(ref)])
            self.sa = np.r_[self.sa, [e.phase == "sa" for e in new]].astype(bool)
            self.phase = np.r_[self.phase, [phase_code(e.phase) for e in new]].astype(np.int8)
            self.minimum = np.r_[self.minimum, [e.local_minimum for e in new]].astype(bool)
            self.iteration = np.r_[self.iteration, [e.iteration for e in new]]
            self.error = np.r_[self.error, [e.error for e in new]]
            self.temperature = np.r_[self.temperature, [temperature_of(e) for e in new]]
            self.n = n
        return n

    @property
    def counts(self) -> tuple[int, int, int]:
        """(ICP iterations, SA moves, local minima) so far (candidates apart: :attr:`candidates`)."""
        n_min = int(self.minimum.sum())
        return int((self.phase == phase_code("icp")).sum()) - n_min, int(self.sa.sum()), n_min

    @property
    def candidates(self) -> int:
        """Candidate poses scored so far (the global pipeline's own phase)."""
        return int((self.phase == phase_code("candidates")).sum())

    def minima(self) -> np.ndarray:
        """(M, 3) float32 page positions of the local minima ICP stopped in (drawn as red markers)."""
        return self.pos[self.minimum] if self.minimum.any() else np.zeros((0, 3), np.float32)

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """Line segments (S, 2, 3) and colours (S, 2, 3) for the path, thinned (:func:`thin`, MAX_PATH_POINTS)."""
        pos = self.pos
        if len(pos) < 2:
            return np.zeros((0, 2, 3), np.float32), np.zeros((0, 2, 3), np.uint8)
        keep = thin(len(pos), MAX_PATH_POINTS, phase_ends(self.phase) | self.minimum)
        seg = np.stack([pos[keep][:-1], pos[keep][1:]], axis=1)
        rgb = PHASE_TABLE[self.phase[keep][1:]]  # each segment in the phase of its end
        return seg, np.repeat(rgb[:, None, :], 2, axis=1)

    def plot(self, E0: float) -> tuple[np.ndarray, ...]:
        """(iteration, then log10 E during each phase of PHASE_NAMES: ICP, SA, candidates) for the uPlot chart;
        the other phases are NaN (a gap).

        log10 E on a linear axis, not E on uPlot's log axis: that one put a tick on every 1-9 of each decade and
        printed values below 0.01 as '0', a column of overlapping labels; a linear axis spaces its ticks (a
        zero E, which has no log, is drawn at the smallest positive one). Every series starts at iteration 0
        with E at the initial pose (``E0``), the start all share; a series of NaN only would leave the chart blank.
        """
        keep = np.unique(np.linspace(0, self.n - 1, min(self.n, MAX_PLOT_POINTS)).astype(int)) if self.n else []
        it = np.r_[0.0, self.iteration[keep]]
        # an ICP "local minimum" mark repeats the last iteration: nudge it so x stays increasing
        it = np.maximum.accumulate(it + np.arange(len(it)) * 1e-6)
        err = np.r_[E0, self.error[keep]].astype(float)
        positive = err[err > 0]
        log_err = np.log10(np.maximum(err, positive.min() if len(positive) else 1.0))
        phase = np.r_[-1, self.phase[keep]]  # -1: the shared start
        return it, *(np.where((phase == c) | (phase == -1), log_err, np.nan) for c in range(len(PHASE_NAMES)))

    def chart(self, E0: float, threshold: float | None) -> tuple[np.ndarray, ...]:
        """:meth:`plot`'s series, then log10 of the threshold (a line over every iteration; NaN when not known) and
        of annealing's temperature (NaN where there is none), all in E's units: the data of app.tab.run's chart."""
        it, *phases = self.plot(E0)
        keep = np.unique(np.linspace(0, self.n - 1, min(self.n, MAX_PLOT_POINTS)).astype(int)) if self.n else []
        temp = np.r_[np.nan, self.temperature[keep]]
        with np.errstate(divide="ignore", invalid="ignore"):
            log_temp = np.where(temp > 0, np.log10(temp), np.nan)
        line = np.full(len(it), np.log10(threshold) if threshold is not None and threshold > 0 else np.nan)
        # every series starts at the shared start's value: a series whose first value is NaN left uPlot's scale without
        # a range, and the whole chart blank (a lone first point draws no line: it shows nothing of its own)
        log_temp[0] = phases[0][0]
        if np.isnan(line[0]):
            line[0] = phases[0][0]
        return it, *phases, line, log_temp


def temperature_of(e: Event) -> float:
    """An event's annealing temperature (E's units), NaN when it has none: ICP, or the first simplex of a leg,
    whose moves are measured before the temperature is set from their spread (core.anneal reports 0 there)."""
    return float(e.temperature) if e.temperature is not None and e.temperature > 0 else float("nan")


def slice_figure(sl: Slice, path_xy: np.ndarray | None, phases: list[str] | None, current: np.ndarray | None,
                 title: str, units: str = "", minima: np.ndarray | None = None, run_minima: np.ndarray | None = None):
    """A Plotly contour map of log10 E with the run's path, the current pose and the slice's local minima on it.

    path_xy: (K, 2) the run's poses in the slice's axes, phases: (K,) "icp"/"sa"; current: (2,); units:
    the scans' length unit (axis labels); minima: (M, 2) the slice's local minima (default: ``sl.minima()``),
    white rings; run_minima: (R, 2) where the run's ICP stopped in a local minimum, red (the page's red).
    """
    import plotly.graph_objects as go

    minima = sl.minima() if minima is None else minima
    fig = go.Figure(go.Contour(x=sl.axis_a, y=sl.axis_b, z=log_values(sl).T, colorscale="Viridis", ncontours=25,
                               colorbar=dict(title=dict(text=f"log10 E ({squared_unit(units)})", side="right"),
                                             thickness=12)))  # its title along the bar: the contour keeps the width
    if len(minima):
        fig.add_trace(go.Scatter(x=minima[:, 0], y=minima[:, 1], mode="markers", name="minima of the slice",
                                 marker=dict(symbol="circle-open", color="white", size=9, line=dict(width=2))))
    if path_xy is not None and len(path_xy):
        phases = phases or ["icp"] * len(path_xy)
        for phase, name in PHASE_LABEL.items():
            mask = np.array([p == phase for p in phases])
            if not mask.any():
                continue
            xy = np.where(mask[:, None], path_xy, np.nan)
            # a white casing under the leg: ICP's green would melt into Viridis's greens (the lesson's "green path")
            fig.add_trace(go.Scatter(x=xy[:, 0], y=xy[:, 1], mode="lines", showlegend=False, hoverinfo="skip",
                                     line=dict(color="white", width=4.5)))
            fig.add_trace(go.Scatter(x=xy[:, 0], y=xy[:, 1], mode="lines", name=name,
                                     line=dict(color=f"rgb{PHASE_RGB[phase]}", width=2)))
        fig.add_trace(go.Scatter(x=path_xy[:1, 0], y=path_xy[:1, 1], mode="markers", name="start",
                                 marker=dict(color="white", size=10, line=dict(color="black", width=1))))
    if current is not None:
        fig.add_trace(go.Scatter(x=[current[0]], y=[current[1]], mode="markers", name="shown pose",
                                 marker=dict(symbol="x", color="white", size=12, line=dict(color="black", width=1))))
    if run_minima is not None and len(run_minima):
        fig.add_trace(go.Scatter(x=run_minima[:, 0], y=run_minima[:, 1], mode="markers", name="ICP's local minimum",
                                 marker=dict(symbol="diamond", color=f"rgb{MINIMUM_RGB}", size=11,
                                             line=dict(color="black", width=1))))
    fig.update_layout(title=dict(text=title, font=dict(size=12)), margin=dict(l=40, r=10, t=30, b=35),
                      xaxis_title=axis_label(sl.params[0], units), yaxis_title=axis_label(sl.params[1], units),
                      legend=dict(orientation="h", y=-0.25, bgcolor="#d8d8d8"), height=380)
    return fig


def ply_bytes(points: np.ndarray, faces: np.ndarray | None = None, colors: np.ndarray | None = None) -> bytes:
    """A binary PLY in memory (for downloads)."""
    import tempfile
    from pathlib import Path

    from rangereg.core.ply import write_ply

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "out.ply"
        write_ply(path, points, faces, colors)
        return path.read_bytes()


def png_bytes(sl: Slice, path_xy, phases, current, title, units: str = "") -> bytes:
    """The slice as a PNG in memory, drawn like the page's figure (same colours and labels)."""
    import tempfile
    from pathlib import Path

    from rangereg.app.plots import slice_png

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "slice.png"
        slice_png(sl, out, path_xy, phases, current, title, units)
        return out.read_bytes()

