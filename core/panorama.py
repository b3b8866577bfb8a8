"""The spherical range image of a panorama (a spinning LiDAR, a terrestrial scanner), its mesh and its view.

A panorama's points lie all around the sensor, so no plane in front of it can hold them (the single-view
frustum and 2.5-D triangulation do not apply). Seen from the sensor each point has an azimuth and an
elevation: the image's rows are elevations, its columns azimuths, each cell holds the nearest point seen in
that direction. Rows are the scanner's rings where the elevations fall in a few tight groups (a spinning
LiDAR's lasers), else equal elevation bins; columns are equal azimuth bins at the scan's own step, phased so
that a scanner's firings sit at cell centres. The image is then a range grid that wraps round in azimuth:

- its mesh joins neighbouring cells as a range grid's does, a triangle kept only when every edge is at most
  ``EDGE_FACTOR`` (core.surface) times the smaller local spacing of its endpoints along that edge's image
  axes: an edge along a ring against the spacing along the rings, one across rings against the spacing
  across them, a diagonal against both (Pythagoras). Per axis, because a ring scanner's spacing along a ring
  and across rings differ tenfold and more (the ground at grazing incidence: 3 cm and 1.2 m at 10 m), so one
  spacing for both either cuts every ring from the next or lets an edge along a ring bridge a depth jump of
  metres (a curtain at every occlusion, which moves with the sensor and holds a registration at the guess).
  A cell's spacing along an axis is the distance to the nearer of its two neighbours on it, so that one
  depth jump beside a cell does not make its own spacing large;
- its view (:class:`PanoramaView`) is the single-view frustum's counterpart: a direction is inside when the
  sensor saw something there (an occupied cell, or one beside it), and a point is visible when its range lies
  within a margin of the range seen in its cell (farther: hidden behind that surface; nearer: the sensor
  looked through it).
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from .errors import InputError
from .rows import norms
from .scan import Scan
from .threads import cached_property

# Rings: the sorted elevations split at gaps at least RING_GAP_RATIO times every gap inside a group (the
# shared HDL-32E frames: 32 groups 1.33 deg apart, no gap inside a group above 1e-6 deg; the ratio asks only that
# the rings stand out by an order of magnitude), into at most MAX_RINGS groups of at least MIN_RING_POINTS points
# each (a ring seen by so few points is no ring), each narrower than half the smallest gap between them.
RING_GAP_RATIO = 10.0
MAX_RINGS = 1024
MIN_RING_POINTS = 8
SAMPLE = 20_000  # points the azimuth phase is measured on (a mean: a sample says as much as all)
REACH_SLACK = 1.05  # a panorama's reach: the farthest range seen and 5 % (core.frustum draws a frustum as deep)


def spherical(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(N,) azimuth (radians, -pi..pi, about +z from +x), elevation (radians, -pi/2..pi/2) and range of
    (N, 3) rays from the sensor."""
    r = norms(rays)
    with np.errstate(invalid="ignore", divide="ignore"):
        el = np.arcsin(np.clip(rays[:, 2] / r, -1.0, 1.0))
    return np.arctan2(rays[:, 1], rays[:, 0]), el, r


@dataclass(frozen=True, eq=False)
class SphericalImage:
    """A panorama's range image about ``viewpoint`` (3,): ``index`` (R, C) int64 the point held by each cell
    (-1 empty), ``ranges`` (R, C) its range (inf empty); rows at elevations ``row_elevation`` (R,) rising
    (radians), split at ``row_edges`` (R + 1,); column c spans azimuths ``az0 + c * az_step`` to the next
    (radians, ``C * az_step`` = 2 pi); ``rings``: the rows are the scanner's rings."""

    viewpoint: np.ndarray
    index: np.ndarray
    ranges: np.ndarray
    row_elevation: np.ndarray
    row_edges: np.ndarray
    az0: float
    az_step: float
    rings: bool

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.row_elevation), self.cols

    @property
    def cols(self) -> int:
        return int(round(2 * np.pi / self.az_step))

    def cells(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(N,) row, column and range of (N, 3) points (the image's frame) and (N,) bool: the point lies
        inside the image's rows (the scanner's vertical field of view) and not at the sensor."""
        return self._cells_of(*spherical(np.asarray(points, dtype=np.float64) - self.viewpoint))

    def _cells_of(self, az: np.ndarray, el: np.ndarray, r: np.ndarray):
        """:meth:`cells` of points at azimuths, elevations and ranges (N,) about the viewpoint."""
        ok = (r > 0) & (el >= self.row_edges[0]) & (el < self.row_edges[-1])
        row = np.clip(np.searchsorted(self.row_edges, np.where(ok, el, self.row_edges[0]), side="right") - 1,
                      0, len(self.row_elevation) - 1)
        col = np.floor((az - self.az0) / self.az_step).astype(np.int64) % self.cols
        return row, col, r, ok

    def directions(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(N, 3) unit rays through the centres of cells (rows, cols) (N,)."""
        el = self.row_elevation[rows]
        az = self.az0 + (np.asarray(cols) + 0.5) * self.az_step
        return np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]

    @cached_property
    def occupied(self) -> np.ndarray:
        """(R, C) bool: the sensor saw something in the cell or in one of its eight neighbours (azimuth wraps)."""
        seen = self.index >= 0
        wrapped = np.hstack([seen[:, -1:], seen, seen[:, :1]])
        return ndimage.binary_dilation(wrapped, np.ones((3, 3), dtype=bool))[:, 1:-1]

    def range_bounds(self, rows: np.ndarray, cols: np.ndarray, grow: tuple[int, int] = (1, 1)
                     ) -> tuple[np.ndarray, np.ndarray]:
        """(N,) the nearest and the farthest range seen in cells (rows, cols) and their neighbours ``grow``
        (rows, columns) cells away (inf, -inf where none): the surface a point in that direction is judged
        against."""
        near, far = self._bounds(grow)
        return near[rows, cols], far[rows, cols]

    def _bounds(self, grow: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        cache = self.__dict__.setdefault("_bounds_cache", {})
        if grow not in cache:
            gr, gc = grow
            C = self.cols
            pad = min(gc, C)
            size = (2 * gr + 1, 2 * pad + 1)
            near = np.hstack([self.ranges[:, C - pad:], self.ranges, self.ranges[:, :pad]])
            far = np.where(np.isfinite(near), near, -np.inf)
            near = ndimage.minimum_filter(near, size=size, mode="constant", cval=np.inf)[:, pad:pad + C]
            far = ndimage.maximum_filter(far, size=size, mode="constant", cval=-np.inf)[:, pad:pad + C]
            cache[grow] = (near, far)
        return cache[grow]

    def faces(self, points: np.ndarray, edge_factor: float) -> tuple[np.ndarray, np.ndarray]:
        """(M, 3) int64 faces over (N, 3) ``points`` (the scan's, which the image indexes) joining neighbouring
        cells, azimuth wrapping round, each edge at most ``edge_factor`` times the spacing of its endpoints
        along its own image axes (module notes); and (M, 3) their edge lengths."""
        from .surface import _grid_faces, edge_lengths

        idx = np.hstack([self.index, self.index[:, :1]])  # the last column joins the first
        faces = _grid_faces(idx)
        if not len(faces):
            return faces, np.zeros((0, 3))
        along, across = self.spacing(points)
        row = np.zeros(len(points), dtype=np.int64)
        held = self.index >= 0
        row[self.index[held]] = np.nonzero(held)[0]
        lengths = edge_lengths(points, faces)
        kept = np.ones(len(faces), dtype=bool)
        for k in range(3):
            a, b = faces[:, k], faces[:, (k + 1) % 3]
            # a grid edge runs along a ring, across rings, or both (a diagonal): its bound likewise
            steps_row = row[a] != row[b]
            steps_col = np.ones(len(faces), dtype=bool)
            steps_col[steps_row] = self._same_column(a[steps_row], b[steps_row])
            steps_col = ~steps_col | ~steps_row
            bound = np.sqrt(np.where(steps_col, np.minimum(along[a], along[b]) ** 2, 0.0)
                            + np.where(steps_row, np.minimum(across[a], across[b]) ** 2, 0.0))
            kept &= lengths[:, k] <= edge_factor * bound
        return faces[kept], lengths[kept]

    def _same_column(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """(K,) bool: the points a and b (K,) sit in one column of the image."""
        col = self.__dict__.get("_column")
        if col is None:
            held = self.index >= 0
            col = np.zeros(int(self.index.max()) + 1, dtype=np.int64)
            col[self.index[held]] = np.nonzero(held)[1]
            self.__dict__["_column"] = col
        return col[a] == col[b]

    def spacing(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) and (N,) per point: its cell's spacing along its ring (the distance to the nearer of its two
        neighbours in the row, azimuth wrapping) and across the rings (to the nearer in the column); inf for a
        point in no cell or with no neighbour that way. The nearer: one depth jump beside a cell does not make
        its own spacing large."""
        idx = self.index
        R, C = idx.shape
        d = np.full((4, R, C), np.nan)
        held = idx >= 0
        p = np.where(held[..., None], points[np.maximum(idx, 0)], np.nan)
        for k, (dr, dc) in enumerate(((0, 1), (0, -1), (1, 0), (-1, 0))):
            q = np.roll(p, (-dr, -dc), axis=(0, 1))
            if dr:  # rows do not wrap
                q[(R - 1 if dr > 0 else 0)] = np.nan
            d[k] = norms(q - p)
        out = []
        for cell in (np.fmin(d[0], d[1]), np.fmin(d[2], d[3])):  # NaN only where both neighbours are missing
            o = np.full(len(points), np.inf)
            o[idx[held]] = np.where(np.isnan(cell[held]), np.inf, cell[held])
            out.append(o)
        return out[0], out[1]


def _rings(s: np.ndarray) -> np.ndarray | None:
    """(R + 1,) elevation edges of the scanner's rings (midway between neighbouring rings, half a gap beyond
    the outer ones) from sorted elevations ``s`` (N,), or None when they do not fall in rings (module notes:
    RING_GAP_RATIO)."""
    gaps = np.diff(s)
    if len(gaps) < 2 * MIN_RING_POINTS:
        return None
    # the MAX_RINGS largest gaps, largest first (which of equal gaps comes first does not matter: the split
    # below takes a set of them only where a gap RING_GAP_RATIO times smaller follows)
    order = np.argpartition(gaps, len(gaps) - MAX_RINGS)[-MAX_RINGS:] if len(gaps) > MAX_RINGS else np.arange(len(gaps))
    order = order[np.argsort(gaps[order])[::-1]]
    top = gaps[order]
    # the split: the largest drop from one gap to the next smaller (the ring gaps, then the spread inside)
    top = np.maximum(top, 1e-9)  # differences of rounding (float32 files) are no gaps: ratios among them 1
    ratio = top[:-1] / top[1:]
    k = int(np.argmax(ratio)) + 1  # k gaps split the elevations into k + 1 rings
    if ratio[k - 1] < RING_GAP_RATIO:
        return None
    cuts = np.sort(order[:k])
    sizes = np.diff(np.r_[0, cuts + 1, len(s)])
    if sizes.min() < MIN_RING_POINTS:
        return None
    # and each ring narrower than half the smallest gap between rings (else: bands, not rings)
    starts, ends = np.r_[0, cuts + 1], np.r_[cuts, len(s) - 1]
    if np.max(s[ends] - s[starts]) > 0.5 * gaps[cuts].min():
        return None
    mids = 0.5 * (s[cuts] + s[cuts + 1])
    lo, hi = s[0] - 0.5 * (s[cuts[0] + 1] - s[cuts[0]]), s[-1] + 0.5 * (s[cuts[-1] + 1] - s[cuts[-1]])
    return np.r_[lo, mids, hi]


def _step(values: np.ndarray) -> float:
    """The median step between neighbouring distinct values of sorted (N,) ``values``, ignoring repeats."""
    d = np.diff(values)
    d = d[d > 1e-9]
    return float(np.median(d)) if len(d) else 0.0


def build_image(points: np.ndarray, viewpoint: np.ndarray, name: str = "scan") -> SphericalImage:
    """The spherical range image of (N, 3) ``points`` about ``viewpoint`` (3,) (module notes)."""
    viewpoint = np.asarray(viewpoint, dtype=np.float64)
    az, el, r = spherical(np.asarray(points, dtype=np.float64) - viewpoint)
    valid = r > 0
    if valid.sum() < 3:
        raise InputError(f"{name}: fewer than 3 points away from the viewpoint; no spherical image")
    s = np.sort(el[valid])
    edges = _rings(s)
    rings = edges is not None
    if rings:
        # each ring's median elevation, read off the sorted elevations (np.median's values, without its copies)
        start = np.r_[0, np.searchsorted(s, edges[1:-1])]
        n = np.diff(np.r_[start, len(s)])
        mid = start + n // 2
        centre = np.where(n % 2 == 1, s[mid], (s[mid - 1] + s[mid]) / 2)
        # along a ring: the step between its firings (each ring's azimuths sorted, repeats aside)
        ring = np.clip(np.searchsorted(edges, el[valid], side="right") - 1, 0, len(centre) - 1)
        by_ring = np.split(az[valid][np.argsort(ring.astype(np.uint16), kind="stable")],
                           np.cumsum(np.bincount(ring, minlength=len(centre)))[:-1])
        d = np.concatenate([np.diff(np.sort(a)) for a in by_ring])
        d = d[d > 1e-9]
        az_step = float(np.median(d)) if len(d) else 0.0
    else:
        # no rings: square cells at the sampling's own angular step (nearest neighbours in azimuth x elevation)
        ae = np.c_[az[valid], el[valid]]
        sub = ae[:: max(1, len(ae) // SAMPLE)]
        d, _ = cKDTree(ae).query(sub, k=2)
        az_step = float(np.median(d[:, 1]))
        lo, hi = float(el[valid].min()), float(el[valid].max())
        n_rows = max(1, int(np.ceil((hi - lo) / max(az_step, 1e-9))) + 1)
        edges = lo - 0.5 * az_step + az_step * np.arange(n_rows + 1)
        centre = 0.5 * (edges[:-1] + edges[1:])
    if not az_step > 0:
        raise InputError(f"{name}: the points' directions show no azimuth step; no spherical image")
    cols = max(3, int(round(2 * np.pi / az_step)))
    az_step = 2 * np.pi / cols
    # phase the columns so that the firings sit at cell centres (the circular mean of the azimuths' phase)
    sub = az[valid][:: max(1, int(valid.sum()) // SAMPLE)]
    phase = np.angle(np.mean(np.exp(1j * (sub / az_step) * 2 * np.pi)))
    az0 = float(phase / (2 * np.pi) * az_step - 0.5 * az_step)
    image = SphericalImage(viewpoint, np.empty((0, 0), dtype=np.int64), np.empty((0, 0)), centre, edges,
                           az0, az_step, True)
    row, col, rr, ok = image._cells_of(az, el, r)
    keep = np.flatnonzero(ok)
    R = len(centre)
    index = np.full(R * cols, -1, dtype=np.int64)
    cell = row[keep] * cols + col[keep]
    order = np.lexsort((rr[keep], cell))  # by cell, the nearest first
    first = np.unique(cell[order], return_index=True)[1]
    held = keep[order][first]
    index[cell[order][first]] = held
    # a firing that fell in its neighbour's cell (the spin's speed varies: the HDL-32E frames' steps are 0.14-0.17
    # deg about the median) moves to the empty cell beside it, on the side its azimuth leans to, then the other
    left = np.setdiff1d(keep, held, assume_unique=True)
    lean = np.where(((az[left] - az0) / az_step) % 1.0 >= 0.5, 1, -1)
    for sign in (1, -1):
        if not len(left):
            break
        target = row[left] * cols + (col[left] + sign * lean) % cols
        free = index[target] < 0
        target, moved = target[free], left[free]
        order = np.lexsort((rr[moved], target))
        first = np.unique(target[order], return_index=True)[1]
        index[target[order][first]] = moved[order][first]
        placed = np.zeros(len(left), dtype=bool)
        placed[np.flatnonzero(free)[order][first]] = True
        left, lean = left[~placed], lean[~placed]
    index = index.reshape(R, cols)
    ranges = np.full(index.shape, np.inf)
    ranges[index >= 0] = rr[index[index >= 0]]
    return SphericalImage(viewpoint, index, ranges, centre, edges, az0, az_step, rings)


# A scan's image, kept while the scan lives (a scan is immutable; the surface and every overlap cut use it)
_IMAGES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def image_of(scan: Scan) -> SphericalImage:
    """The spherical image of ``scan`` about its viewpoint, built once."""
    if scan not in _IMAGES:
        _IMAGES[scan] = build_image(scan.points, scan.viewpoint, scan.name)
    return _IMAGES[scan]


@dataclass(frozen=True, eq=False)
class PanoramaView:
    """The overlap test of a panorama, in its scan's frame (module notes): the frustum's counterpart.

    apex: (3,) the sensor; image: its :class:`SphericalImage`."""

    apex: np.ndarray
    image: SphericalImage

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: (N, 3) points (this scan's frame) in a direction the sensor saw something, within its
        reach (:attr:`far`): the frustum's counterpart, free space and what lies behind the surface included
        (:meth:`visible` tells those apart)."""
        row, col, r, ok = self.image.cells(points)
        return ok & self.image.occupied[row, col] & (r <= self.far)

    def visible(self, surface, points: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: points whose range lies within ``margin`` (units) of the ranges seen about their cell:
        farther, they hide behind that surface; nearer, the sensor looked through them. (``surface`` is not
        needed: the image holds the ranges.)"""
        row, col, r, ok = self.image.cells(points)
        near, far = self.image.range_bounds(row, col)
        return ok & (r >= near - margin) & (r <= far + margin)

    def guessed(self, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: the points ``inside`` (N,) that are also :meth:`visible` with ``margin``."""
        out = inside.copy()
        out[np.flatnonzero(inside)] = self.visible(surface, points[inside], margin)
        return out

    def widened(self, points: np.ndarray, angle: float, translation: float = 0.0) -> np.ndarray:
        """(N,) bool: points within ``angle`` radians of a direction the sensor saw something and within its
        reach moved by the rotation and ``translation`` (units): :meth:`contains` opened (every point from a
        quarter turn, as the frustum opened that far holds every direction ahead)."""
        if angle <= 0:
            return self.contains(points)
        if angle >= np.pi / 2:
            return np.ones(len(points), dtype=bool)
        img = self.image
        grow = (int(np.ceil(angle / max(float(np.diff(img.row_edges).min()), 1e-12))),
                int(np.ceil(angle / img.az_step)))
        az, el, r = spherical(np.asarray(points, dtype=np.float64) - self.apex)
        inside_rows = (r > 0) & (el >= img.row_edges[0] - angle) & (el < img.row_edges[-1] + angle)
        row = np.clip(np.searchsorted(img.row_edges, el, side="right") - 1, 0, len(img.row_elevation) - 1)
        col = np.floor((az - img.az0) / img.az_step).astype(np.int64) % img.cols
        seen = np.isfinite(img.range_bounds(row, col, grow)[0])
        return inside_rows & seen & (r <= self.far + translation + 2 * self.far * np.sin(angle / 2))

    def wireframe(self) -> np.ndarray:
        """(0, 2, 3): a panorama has no pyramid to draw (the page shows a sensor marker at ``apex``)."""
        return np.zeros((0, 2, 3))

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """No side faces (see :meth:`wireframe`): vertices (1, 3) the apex, faces (0, 3)."""
        return self.apex[None].copy(), np.zeros((0, 3), dtype=np.int64)

    @cached_property
    def far(self) -> float:
        """The sensor's reach (units): REACH_SLACK x the farthest range seen (as a frustum is drawn)."""
        return REACH_SLACK * float(np.max(self.image.ranges[np.isfinite(self.image.ranges)], initial=0.0))


def panorama_view(scan: Scan) -> PanoramaView:
    return PanoramaView(np.array(scan.viewpoint, dtype=np.float64), image_of(scan))


def _faces(scan: Scan) -> tuple[np.ndarray, np.ndarray]:
    from .surface import EDGE_FACTOR

    return image_of(scan).faces(scan.points, EDGE_FACTOR)


def _register() -> None:
    from .surface import PANORAMA_FACES

    PANORAMA_FACES[:] = [_faces]  # a panorama's triangulation (core.surface's table of kinds)


_register()
