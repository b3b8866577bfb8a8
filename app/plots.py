"""Pictures for people (matplotlib, headless): the error-surface slice with a run's path on it.

Drawn as the page draws it: log10 E in viridis (app/figures.log_values), ICP legs green, annealing legs magenta
(app/figures.py), the slice's local minima as white rings, the run's own local minima (where ICP stopped) as red
diamonds; every mark has its legend entry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rangereg.app.figures import MINIMUM_RGB, PHASE_LABEL, PHASE_RGB, axis_label, log_values, squared_unit, unit_fraction
from rangereg.core.landscape import Slice


def slice_axes(sl: Slice, path_xy: np.ndarray | None = None, phases: list[str] | None = None,
               current: np.ndarray | None = None, title: str = "", units: str = "",
               run_minima: np.ndarray | None = None):
    """A matplotlib figure of ``sl``: contours of E, the run (``path_xy`` (K, 2), ``phases`` (K,)), where it stopped
    in a local minimum (``run_minima`` (R, 2)), the pose."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt


    fig, ax = plt.subplots(figsize=(7, 5.5), dpi=110)
    B, A = np.meshgrid(sl.axis_b, sl.axis_a)
    cs = ax.contourf(A, B, log_values(sl), levels=25, cmap="viridis")
    fig.colorbar(cs, ax=ax, label=f"log10 E ({squared_unit(units)})")
    minima = sl.minima()
    if len(minima):
        ax.plot(minima[:, 0], minima[:, 1], "o", mfc="none", mec="white", mew=1.8, ms=8, label="minima of the slice")
    if path_xy is not None and len(path_xy):
        phases = phases or ["icp"] * len(path_xy)
        start = 0
        for k in range(1, len(path_xy) + 1):
            if k == len(path_xy) or phases[k] != phases[start]:
                seg = path_xy[max(start - 1, 0):k]
                ax.plot(seg[:, 0], seg[:, 1], "-", lw=1.2, color=unit_fraction(PHASE_RGB.get(phases[start], (0, 0, 0))))
                start = k
        ax.plot(*path_xy[0], "o", color="white", mec="k", ms=8, label="start")
        ax.plot(*path_xy[-1], "*", color="yellow", mec="k", ms=13, label="end")
        for phase, name in PHASE_LABEL.items():
            if phase in phases:
                ax.plot([], [], color=unit_fraction(PHASE_RGB[phase]), label=name)
    if run_minima is not None and len(run_minima):
        ax.plot(run_minima[:, 0], run_minima[:, 1], "D", color=unit_fraction(MINIMUM_RGB), mec="k", ms=8,
                label="ICP's local minimum")
    if current is not None:
        ax.plot(*current, "x", color="white", ms=10, mew=2, label="shown pose")
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=8, framealpha=0.85)
    ax.set_xlabel(axis_label(sl.params[0], units))
    ax.set_ylabel(axis_label(sl.params[1], units))
    ax.set_title(title or "error surface slice")
    fig.tight_layout()
    return fig


def slice_png(sl: Slice, path: str | Path, path_xy: np.ndarray | None = None, phases: list[str] | None = None,
              current: np.ndarray | None = None, title: str = "", units: str = "",
              run_minima: np.ndarray | None = None) -> None:
    """Write the contour picture of ``sl`` to ``path`` (see :func:`slice_axes`)."""
    import matplotlib.pyplot as plt

    fig = slice_axes(sl, path_xy, phases, current, title, units, run_minima)
    fig.savefig(str(path))
    plt.close(fig)


def slice_png_bytes(sl: Slice, path_xy=None, phases=None, current=None, title: str = "", units: str = "",
                    run_minima: np.ndarray | None = None) -> bytes:
    """The PNG of :func:`slice_png` in memory (the page's download)."""
    import io

    import matplotlib.pyplot as plt

    fig = slice_axes(sl, path_xy, phases, current, title, units, run_minima)
    out = io.BytesIO()
    fig.savefig(out, format="png")
    plt.close(fig)
    return out.getvalue()
