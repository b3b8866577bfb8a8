"""Pictures for people (matplotlib, headless): the error-surface slice with a run's path on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from core.landscape import Slice

LEG_COLOURS = {"icp": "#1f77b4", "sa": "#d62728"}


def slice_png(sl: Slice, path: str | Path, path_xy: np.ndarray | None = None, phases: list[str] | None = None,
              current: np.ndarray | None = None, title: str = "") -> None:
    """Write the contour picture of ``sl``; ``path_xy`` (K, 2) with ``phases`` (K,) draws the run."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5.5), dpi=110)
    B, A = np.meshgrid(sl.axis_b, sl.axis_a)
    cs = ax.contourf(A, B, sl.values, levels=30, cmap="viridis")
    fig.colorbar(cs, ax=ax, label="robust error E")
    if path_xy is not None and len(path_xy):
        phases = phases or ["icp"] * len(path_xy)
        start = 0
        for k in range(1, len(path_xy) + 1):
            if k == len(path_xy) or phases[k] != phases[start]:
                seg = path_xy[max(start - 1, 0):k]
                ax.plot(seg[:, 0], seg[:, 1], "-", lw=1.2, color=LEG_COLOURS.get(phases[start], "k"))
                start = k
        ax.plot(*path_xy[0], "o", color="white", mec="k", ms=8, label="start")
        ax.plot(*path_xy[-1], "*", color="yellow", mec="k", ms=13, label="end")
        ax.plot([], [], color=LEG_COLOURS["icp"], label="ICP")
        ax.plot([], [], color=LEG_COLOURS["sa"], label="SA")
        ax.legend(loc="upper right", fontsize=8)
    if current is not None:
        ax.plot(*current, "x", color="white", ms=10, mew=2)
    unit = lambda n: "deg" if n.startswith("r") else "units"  # noqa: E731
    ax.set_xlabel(f"{sl.params[0]} ({unit(sl.params[0])})")
    ax.set_ylabel(f"{sl.params[1]} ({unit(sl.params[1])})")
    ax.set_title(title or "error surface slice")
    fig.tight_layout()
    fig.savefig(str(path))
    plt.close(fig)
