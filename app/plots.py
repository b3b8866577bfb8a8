"""Pictures for people (matplotlib, headless): the error-surface slice with a run's path on it.

Drawn in the page's colours (app/figures.py): ICP legs green, annealing legs magenta.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from app.figures import PHASE_LABEL, PHASE_RGB, axis_label, squared_unit, unit_fraction
from core.landscape import Slice


def slice_axes(sl: Slice, path_xy: np.ndarray | None = None, phases: list[str] | None = None,
               current: np.ndarray | None = None, title: str = "", units: str = ""):
    """A matplotlib figure of ``sl``: contours of E, the run (``path_xy`` (K, 2), ``phases`` (K,)), the pose."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5.5), dpi=110)
    B, A = np.meshgrid(sl.axis_b, sl.axis_a)
    cs = ax.contourf(A, B, sl.values, levels=30, cmap="viridis")
    fig.colorbar(cs, ax=ax, label=f"robust error E ({squared_unit(units)})")
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
        ax.legend(loc="upper right", fontsize=8)
    if current is not None:
        ax.plot(*current, "x", color="white", ms=10, mew=2, label="_current")
    ax.set_xlabel(axis_label(sl.params[0], units))
    ax.set_ylabel(axis_label(sl.params[1], units))
    ax.set_title(title or "error surface slice")
    fig.tight_layout()
    return fig


def slice_png(sl: Slice, path: str | Path, path_xy: np.ndarray | None = None, phases: list[str] | None = None,
              current: np.ndarray | None = None, title: str = "", units: str = "") -> None:
    """Write the contour picture of ``sl`` to ``path`` (see :func:`slice_axes`)."""
    import matplotlib.pyplot as plt

    fig = slice_axes(sl, path_xy, phases, current, title, units)
    fig.savefig(str(path))
    plt.close(fig)
