"""Residuals (Model tab): the source coloured by its distance to the target surface, and the histogram
of those distances with the robust cap marked, the operator's evidence that a registration is right.

The cap is the error's own: a point is within it when d^2 < t = 2 median(d^2) over the overlap
sample at the shown pose (paper eq. 2, core.robust_error.robust_weights); the colours run from 0 to 2 sqrt(t).
Points beyond the cap are expected on a right pose wherever the scans do not overlap (the part of the source
the target never saw): the summary says how many of them lie outside the overlap cut, so a right result with
40 % beyond the cap does not read as a broken one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.figures import fmt, legend_html, residual_legend, unit_label
from rangereg.core.transforms import apply

BINS = 40
COLOUR_SPAN = 2.0  # the colour scale ends at this many caps (sqrt t): every outlier is the last colour
HISTOGRAM_SPAN = 4.0  # the histogram shows distances up to this many caps; its last bar holds all beyond


@dataclass(frozen=True, eq=False)
class Residuals:
    """distances: (N,) every source point to the target surface at pose T (scan units); cap: sqrt(t), same units."""

    distances: np.ndarray
    cap: float
    T: np.ndarray
    overlap: np.ndarray | None = None  # (N,) bool: the points in the error's overlap cut (None: not known)

    @property
    def inliers(self) -> np.ndarray:
        return self.distances < self.cap

    def __repr__(self) -> str:
        return (f"Residuals({len(self.distances)} points, median {np.median(self.distances):.4g}, cap {self.cap:.4g}, "
                f"{self.inliers.mean():.0%} inliers)")


def residuals(problem, source_points: np.ndarray, T: np.ndarray) -> Residuals:
    """Distances of all source points (N, 3) under T_target_source to the problem's target surface (and which of them
    are in the problem's overlap cut, when they are the problem's source points)."""
    _, d2 = problem.surface.closest(apply(T, source_points))
    t = problem.error.terms(T).t
    used = np.asarray(problem.used, bool)
    return Residuals(np.sqrt(d2), float(np.sqrt(t)), T, used if len(used) == len(source_points) else None)


def summary_text(r: Residuals, unit: str) -> str:
    """The panel's words on ``r``: the median and the cap, the share within it, and the share beyond it said for
    what it is (the part of the source with no partner surface, and the noise's tail), not as a failure rate."""
    beyond = ~r.inliers
    text = (f"Median distance {fmt(np.median(r.distances))} {unit}; cap √t {fmt(r.cap)} {unit} (t = 2 × median d²). "
            f"Within the cap: {r.inliers.mean():.0%} of the source's points. Beyond it: {beyond.mean():.0%}")
    if r.overlap is not None and beyond.any():
        outside = float((beyond & ~r.overlap).sum() / beyond.sum())
        text += f", {outside:.0%} of them outside the overlap cut, where the target has no surface to match"
    # Gaussian noise at a cap of twice the median d^2: P(chi2_1 > 2 x 0.455) = 0.34 for distances along the normal,
    # P(chi2_3 > 2 x 2.366) = 0.19 in three dimensions: a fifth to a third of matching points lie beyond it
    return text + (" (on a right pose too: where the scans do not overlap, and the noise's tail, a fifth to a third "
                   "of matching points at a cap of twice the median). The robust error caps their weight; the run's "
                   "trust line says whether the pose is right.")


def colour_map(values: np.ndarray, top: float) -> np.ndarray:
    """(N, 3) uint8 viridis colours for values in [0, top] (clipped)."""
    import matplotlib

    rgba = matplotlib.colormaps["viridis"](np.clip(values / max(top, 1e-300), 0.0, 1.0))
    return (rgba[:, :3] * 255).astype(np.uint8)


def histogram_figure(r: Residuals, units: str):
    """Plotly histogram of distances coloured like the points (its colour bar in units), the cap marked."""
    import plotly.graph_objects as go

    unit = unit_label("t", units)
    top = COLOUR_SPAN * r.cap
    # points outside the overlap lie far off: they go in the last bar, so the cap's neighbourhood stays readable
    edges = np.linspace(0.0, HISTOGRAM_SPAN * r.cap, BINS + 1)
    counts, _ = np.histogram(np.minimum(r.distances, edges[-1]), edges)
    centre, width = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    fig = go.Figure()
    # each bar's colour as an rgb() string: numbers mapped through a colour scale made Plotly's legend log an
    # "Invalid color specifier" per bar on every draw; the colour bar is a trace of its own, with no points
    rgb = colour_map(centre, top)
    for name, mask, opacity in ((f"within the cap (d < √t): {r.inliers.sum()}", centre < r.cap, 1.0),
                                (f"beyond the cap (d ≥ √t): {(~r.inliers).sum()}", centre >= r.cap, 0.45)):
        fig.add_trace(go.Bar(x=centre[mask].tolist(), y=counts[mask].tolist(), width=width[mask].tolist(), name=name,
                             opacity=opacity, marker=dict(color=[f"rgb({a},{b},{c})" for a, b, c in rgb[mask]])))
    fig.add_trace(go.Scatter(x=[None], y=[None], mode="markers", showlegend=False, hoverinfo="skip",
                             marker=dict(colorscale="Viridis", cmin=0.0, cmax=top, color="rgba(0,0,0,0)",
                                         showscale=True, colorbar=dict(title=f"d ({unit})", thickness=12))))
    fig.add_vline(x=r.cap, line=dict(color="red", dash="dash"), annotation_text=f"cap √t = {fmt(r.cap, 3)} {unit}",
                  annotation_position="top right")
    # no title in the figure (the panel's line above it names it): a title shared the top edge with Plotly's toolbar
    # and the legend; the legend goes under the axis, where nothing else is
    fig.update_layout(xaxis_title=f"distance to the target surface ({unit}); last bar: ≥ {fmt(edges[-1], 3)}",
                      yaxis_title="source points", bargap=0.0, height=340, margin=dict(l=45, r=10, t=30, b=40),
                      showlegend=True, legend=dict(orientation="h", x=0.0, y=-0.22, yanchor="top"))
    return fig


def legend_for(tab, unit: str | None) -> None:
    """The page's legend: the residual scale while the source is coloured by distance (``unit``), else the scans'."""
    content = legend_html() if unit is None else legend_html(residual_legend(unit))
    if tab.legend.content != content:
        tab.legend.content = content


class ResidualsPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        with gui.add_folder("Residuals") as self.folder:
            self.show = gui.add_checkbox("Colour by residual", False,
                                         hint="colour the source by its distance to the target surface at the shown pose")
            self.summary = gui.add_markdown("")
        self.plot: viser.GuiPlotlyHandle | None = None
        self.current: Residuals | None = None
        self.show.on_update(lambda e: tab.guarded(self.refresh))

    def refresh(self) -> None:
        """Recompute at the shown pose when asked for (and no run moves the scan), else drop the colours."""
        st = self.state
        if st.source is None or st.problem is None:
            return
        if not self.show.value or st.running:
            if st.residual_rgb is not None:
                with st.lock:
                    st.residual_rgb = None
                self.tab.recolour()
            legend_for(self.tab, None)
            if self.plot is not None:
                self.plot.visible = bool(self.show.value) and self.current is not None
            return
        with st.lock:
            problem, points, T, units = st.problem, st.source.points, st.T.copy(), st.target.units
        r = residuals(problem, points, T)
        with st.lock:
            st.residual_rgb = colour_map(r.distances, COLOUR_SPAN * r.cap)
        self.current = r
        self.tab.recolour()
        fig = histogram_figure(r, units)
        unit = unit_label("t", units)
        legend_for(self.tab, unit)
        self.summary.content = summary_text(r, unit) + "  \n**Source points by distance to the target surface**"
        if self.plot is None:
            with self.folder:
                self.plot = self.tab.gui.add_plotly(fig, aspect=1.3)
        else:
            self.plot.figure = fig
            self.plot.visible = True
