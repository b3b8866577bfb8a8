"""Held-out small views for the benchmarks: seeded crops of a scan's range grid.

A crop is a rectangular window of the scanner's range image that holds a seeded share of the scan's
points; it keeps the scan's viewpoint, units and ground-truth pose, so it is a smaller view taken by the
same sensor from the same place. Crops are data made by the benchmarks (the sweep, the campaign
benchmark); nothing in core knows about them.

The rule, fixed before any result was looked at:

    share   uniform in [SHARE_LOW, SHARE_HIGH] of the scan's points
    aspect  rows / cols of the window, log-uniform in [1 / ASPECT, ASPECT]
    centre  a uniformly drawn occupied cell
    size    the smallest window of that aspect, centred there and clipped to the grid, that holds at
            least the share (bisection on its scale: the count never falls as the window grows)

One generator per (scan name, crop index), so crop k of a scan is the same whatever else is drawn.
"""

from __future__ import annotations

import zlib
from dataclasses import replace

import numpy as np
from rangereg.core.errors import InputError
from rangereg.core.scan import RangeGrid, Scan

SHARE_LOW, SHARE_HIGH = 0.25, 0.60
ASPECT = 2.0


def crop_rng(name: str, k: int) -> np.random.Generator:
    """The generator of crop ``k`` of the scan called ``name`` (stable across runs and processes)."""
    return np.random.default_rng([zlib.crc32(name.encode()), k])


def crop(scan: Scan, k: int) -> Scan:
    """Crop ``k`` of ``scan`` (which must carry a range grid): the module's seeded rule."""
    if scan.grid is None:
        raise InputError(f"{scan.name}: a crop needs the scan's range grid, and this scan has none")
    rng = crop_rng(scan.name, k)
    share = rng.uniform(SHARE_LOW, SHARE_HIGH)
    aspect = float(np.exp(rng.uniform(-np.log(ASPECT), np.log(ASPECT))))
    index = scan.grid.index
    rows, cols = np.nonzero(index >= 0)
    pick = int(rng.integers(len(rows)))
    r0, c0 = rows[pick], cols[pick]
    R, C = index.shape
    half = np.array([np.sqrt(aspect) * R, C / np.sqrt(aspect)]) / 2  # at scale 1 the window spans the grid

    def inside(s: float) -> np.ndarray:
        hr, hc = s * half
        return (np.abs(rows - r0) <= hr) & (np.abs(cols - c0) <= hc)

    need = int(np.ceil(share * len(rows)))
    lo, hi = 0.0, 2.0 * max(1.0, 1.0 / np.sqrt(aspect), np.sqrt(aspect))  # hi covers the whole grid from any cell
    for _ in range(40):
        mid = (lo + hi) / 2
        lo, hi = (lo, mid) if inside(mid).sum() >= need else (mid, hi)
    return window(scan, inside(hi), rows, cols, f"{scan.name}-crop{k}")


def window(scan: Scan, keep_cells: np.ndarray, rows: np.ndarray, cols: np.ndarray, name: str) -> Scan:
    """``scan`` restricted to the occupied cells (``rows``, ``cols``) where ``keep_cells`` holds, its grid
    cut to their bounding box and re-indexed."""
    r, c = rows[keep_cells], cols[keep_cells]
    old = scan.grid.index[r, c]
    order = np.argsort(old)  # keep the points in the scan's own order
    old, r, c = old[order], r[order], c[order]
    grid = np.full((r.max() - r.min() + 1, c.max() - c.min() + 1), -1, dtype=np.int64)
    grid[r - r.min(), c - c.min()] = np.arange(len(old))
    intensity = None if scan.intensity is None else scan.intensity[old]  # cut with the points
    return replace(scan, points=scan.points[old], grid=RangeGrid(grid), faces=None, name=name, intensity=intensity,
                   source=f"{scan.source}#{name}" if scan.source else name)
