"""Overlap by frustum segmentation (paper section 2.1).

The frustum of a scan is the pyramid from the sensor origin through the outline of the scan's
points as seen from the sensor. The paper's frustum is convex (the outline is the convex hull of
the projected points); the non-convex variant it left as future work follows the scan's real
footprint: an occupancy mask of the projected points, closed over the sampling gaps.

Given a guess ``T_a_b`` (B into A's frame), the points of B inside A's frustum and the points of A
inside B's are the overlap that registration uses; points outside are culled before they can
become outliers.

The frustum is the single-view case of a scan's view (:class:`View`, by the scan's kind): a panorama's is
visibility in its spherical image (core.panorama), an unstructured scan's closeness to its points
(core.unstructured). Every overlap cut, score and drawing asks :func:`frustum_of` and uses the view's
methods, whatever the kind.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError, cKDTree

from .errors import InputError
from .rows import norms
from .scan import Scan, ScanKind
from .threads import cached_property
from .transforms import apply, invert

KINDS = ("convex", "nonconvex")


class View(Protocol):
    """Where a scan saw, in its own frame: the overlap tests of one kind (a :class:`Frustum`,
    core.panorama.PanoramaView, core.unstructured.CloudView). ``apex``: (3,) the sensor, for drawing."""

    apex: np.ndarray

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which (N, 3) points (this scan's frame) lie where the scan saw."""
        ...

    def visible(self, surface, points: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: which of (N, 3) points the sensor could have seen, not hidden behind (or seen through)
        ``surface`` by more than ``margin`` (units)."""
        ...

    def guessed(self, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: the cut under a guess off by ``margin`` (units, at the points) of (N, 3) points of which
        ``inside`` (N,) are in :meth:`contains`: those inside and :meth:`visible` (a frustum, a panorama), or
        those within reach of the guess (a cloud)."""
        ...

    def widened(self, points: np.ndarray, angle: float, translation: float = 0.0) -> np.ndarray:
        """(N,) bool: :meth:`contains` opened by ``angle`` radians (and ``translation`` units where the view
        measures distance)."""
        ...

    def wireframe(self) -> np.ndarray:
        """(S, 2, 3) line segments to draw ((0, 2, 3) when the view has no outline)."""
        ...


@dataclass(frozen=True, eq=False)
class Frustum:
    """The viewing pyramid of one scan, in that scan's frame.

    apex: (3,) sensor origin; basis: (3, 3) rows u, v, viewing axis; outline: (K, 2) convex outline
    on the image plane (gnomonic coordinates, one unit in front of the sensor); far: depth (units)
    used for drawing. ``mask`` (with ``mask_origin``, ``cell``) makes it non-convex.
    """

    apex: np.ndarray
    basis: np.ndarray
    outline: np.ndarray
    equations: np.ndarray
    far: float
    mask: np.ndarray | None = None
    mask_origin: np.ndarray | None = None
    cell: float = 0.0

    @property
    def convex(self) -> bool:
        return self.mask is None

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        local = (points - self.apex) @ self.basis.T
        depth = local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = local[:, :2] / depth[:, None]
        return uv, depth

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: which (N, 3) points (this scan's frame) lie inside the frustum.

        Memory and time linear in N: each point is tested against the outline edge of its angular
        wedge (found by binary search) and that edge's two neighbours, with the hull's own facet
        equations, so the answer is the all-facets test's.
        """
        return self._contains_local((np.asarray(points, dtype=np.float64) - self.apex) @ self.basis.T)

    def _contains_local(self, local: np.ndarray) -> np.ndarray:
        depth = local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = local[:, :2] / depth[:, None]
        del local
        inside = np.zeros(len(uv), dtype=bool)
        front = np.flatnonzero(depth > 0)
        if not len(front):
            return inside
        q = uv[front]
        del uv, depth
        hull_ok = _inside_convex(q, self._wedges)
        if self.mask is not None:
            ij = np.floor((q - self.mask_origin) / self.cell).astype(np.int64)
            in_box = np.all((ij >= 0) & (ij < self.mask.shape), axis=1)
            ok = np.zeros(len(q), dtype=bool)
            ok[in_box] = self.mask[ij[in_box, 0], ij[in_box, 1]]
            hull_ok &= ok
        inside[front] = hull_ok
        return inside

    def visible(self, surface, points: np.ndarray, margin: float) -> np.ndarray:
        """:func:`visible_from` this frustum's apex on ``surface`` (the scan's own, in its frame)."""
        return visible_from(surface, self.apex, points, margin)

    def guessed(self, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
        """(N,) bool: the points ``inside`` (N,) that are also :meth:`visible` (the frustum cut's visibility)."""
        return visible_cut(self, surface, points, inside, margin)

    def widened(self, points: np.ndarray, angle: float, translation: float = 0.0, chunk: int = 65536) -> np.ndarray:
        """(N,) bool: points inside the frustum opened by ``angle`` radians on every side: each point's ray from
        the apex within ``angle`` of every side plane (through the apex and an edge of the convex outline).
        ``translation`` does not open a frustum (its sides are directions)."""
        if angle <= 0:
            return self.contains(points)
        if angle >= np.pi / 2:
            return np.ones(len(points), dtype=bool)
        # an edge a u + b v + c = 0 on the image plane (z = 1) is the side plane a x + b y + c z = 0
        sides = self.equations / np.linalg.norm(self.equations, axis=1, keepdims=True)
        out = np.zeros(len(points), dtype=bool)
        for start in range(0, len(points), chunk):  # (chunk, K) at a time: a 2M-point scan in bounded memory
            local = (np.asarray(points[start:start + chunk], dtype=np.float64) - self.apex) @ self.basis.T
            with np.errstate(divide="ignore", invalid="ignore"):
                rays = local / np.linalg.norm(local, axis=1, keepdims=True)  # a point at the apex: NaN, outside
            out[start:start + chunk] = np.all(rays @ sides.T <= np.sin(angle), axis=1)
        return out

    @cached_property
    def _wedges(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return _wedge_table(self.outline, self.equations)

    def wireframe(self) -> np.ndarray:
        """(S, 2, 3) line segments for drawing: apex to each outline corner, and the far outline."""
        far = self.outline_points(self.far)
        spokes = np.stack([np.broadcast_to(self.apex, far.shape), far], axis=1)
        ring = np.stack([far, np.roll(far, -1, axis=0)], axis=1)
        return np.concatenate([spokes, ring])

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """The frustum's side faces as a mesh: vertices (K + 1, 3), faces (K, 3)."""
        far = self.outline_points(self.far)
        k = len(far)
        verts = np.vstack([self.apex, far])
        faces = np.array([[0, 1 + i, 1 + (i + 1) % k] for i in range(k)])
        return verts, faces

    def outline_points(self, depth: float) -> np.ndarray:
        o = self.outline
        return self.apex + depth * (o[:, :1] * self.basis[0] + o[:, 1:] * self.basis[1] + self.basis[2])


def _wedge_table(outline: np.ndarray, equations: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centre (2,), vertex angles (K,) rising from 0, and the equations (K, 3) of the edge that
    leaves each outline vertex, for the wedge search of :meth:`Frustum.contains`.

    ``outline`` is the hull's vertices in order (either turn); ``equations`` its facets in any order.
    """
    centre = outline.mean(0)
    ang = np.arctan2(outline[:, 1] - centre[1], outline[:, 0] - centre[0])
    if len(outline) > 2 and np.sum(np.diff(np.unwrap(ang))) < 0:  # clockwise: walk it the other way
        outline, ang = outline[::-1], ang[::-1]
    start = ang[0]
    ang = np.mod(ang - start, 2 * np.pi)
    # The facet of edge (k, k+1) is the one both ends lie on: the largest (closest to 0) mean offset.
    mid = 0.5 * (outline + np.roll(outline, -1, axis=0))
    offsets = mid @ equations[:, :2].T + equations[:, 2]  # (K, K), K = outline corners: small
    edge_eq = equations[np.argmax(offsets, axis=1)]
    return np.r_[centre, start], ang, edge_eq


def _inside_convex(q: np.ndarray, table, tol: float = 1e-12) -> np.ndarray:
    """(N,) bool: (N, 2) points on the inner side (within ``tol``) of every outline edge.

    O(N log K): a point lies in the wedge between two outline corners seen from the centre; inside
    the polygon means inside that wedge's edge. The edges either side are tested too, so a point
    that rounding puts in the next wedge gets the same answer as testing every edge.
    """
    head, ang, eq = table
    k = len(ang)
    theta = np.mod(np.arctan2(q[:, 1] - head[1], q[:, 0] - head[0]) - head[2], 2 * np.pi)
    j = np.clip(np.searchsorted(ang, theta, side="right") - 1, 0, k - 1)
    ok = np.ones(len(q), dtype=bool)
    for shift in (-1, 0, 1):
        e = eq[(j + shift) % k]
        ok &= q[:, 0] * e[:, 0] + q[:, 1] * e[:, 1] + e[:, 2] <= tol
    return ok


# A scan's frustum, kept while the scan lives: a scan is immutable, and each overlap cut (prepare,
# every re-cut) would otherwise project and hull all its points again (two 2M-point scans: 1.3 s
# of CPU per cut).
_FRUSTA: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def frustum_of(scan: Scan, kind: str = "convex") -> View:
    """The view of ``scan`` by its kind: a single-view scan's frustum (``kind``: 'convex' as in the paper,
    or 'nonconvex'), a panorama's spherical visibility, an unstructured scan's closeness (``kind`` does not
    apply to those two)."""
    if kind not in KINDS:
        raise InputError(f"unknown frustum kind {kind!r}; use one of {', '.join(KINDS)}")
    cache = _FRUSTA.setdefault(scan, {})
    key = kind if scan.kind is ScanKind.SINGLE_VIEW else scan.kind
    if key not in cache:
        cache[key] = _build_view(scan, kind)
    return cache[key]


def _build_view(scan: Scan, kind: str) -> View:
    if scan.kind is ScanKind.PANORAMA:
        from .panorama import panorama_view

        return panorama_view(scan)
    if scan.kind is ScanKind.UNSTRUCTURED:
        from .unstructured import cloud_view

        return cloud_view(scan)
    return _build_frustum(scan, kind)


def _build_frustum(scan: Scan, kind: str) -> Frustum:
    from .surface import view_projection

    try:
        uv, basis = view_projection(scan.points, scan.viewpoint)
    except InputError as exc:
        raise InputError(f"{scan.name}: {exc}") from None
    try:
        hull = ConvexHull(uv)
    except (QhullError, ValueError):
        raise InputError(f"{scan.name}: the scan is seen edge-on from its viewpoint; no frustum") from None
    depth = (scan.points - scan.viewpoint) @ basis[2]
    outline = uv[hull.vertices]
    mask = origin = None
    cell = 0.0
    if kind == "nonconvex":
        mask, origin, cell = _occupancy(uv)
    return Frustum(apex=scan.viewpoint.copy(), basis=basis, outline=outline, equations=hull.equations,
                   far=float(depth.max() * 1.05), mask=mask, mask_origin=origin, cell=cell)


def _occupancy(uv: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """A closed occupancy mask of projected points: cells 2 x the median projected spacing."""
    sub = uv[:: max(1, len(uv) // 5000)]
    d, _ = cKDTree(uv).query(sub, k=2)
    cell = 2.0 * float(np.median(d[:, 1])) or 1e-9
    origin = uv.min(0) - 2 * cell
    ij = np.floor((uv - origin) / cell).astype(np.int64)
    shape = ij.max(0) + 3
    mask = np.zeros(shape, dtype=bool)
    mask[ij[:, 0], ij[:, 1]] = True
    mask = ndimage.binary_closing(mask, iterations=2)
    mask = ndimage.binary_fill_holes(mask)
    return mask, origin, cell


@dataclass(frozen=True, eq=False)
class Overlap:
    """source_mask: (Ns,) source points inside the target's frustum under ``T_target_source``;
    target_mask: (Nt,) the reverse, the ``target_points`` (target frame) inside ``source_frustum``, made
    when first asked for (only drawing asks: a registration's every cut would pay a test of the whole
    target for it)."""

    source_mask: np.ndarray
    source_frustum: View = field(repr=False)
    target_points: np.ndarray = field(repr=False)
    T_target_source: np.ndarray = field(repr=False)

    @cached_property
    def target_mask(self) -> np.ndarray:
        return self.source_frustum.contains(apply(invert(self.T_target_source), self.target_points))

    @property
    def source_fraction(self) -> float:
        return float(self.source_mask.mean())

    @property
    def target_fraction(self) -> float:
        return float(self.target_mask.mean())

    def __repr__(self) -> str:
        return (f"Overlap(source {self.source_mask.sum()}/{len(self.source_mask)} = {self.source_fraction:.0%}, "
                f"target {self.target_mask.sum()}/{len(self.target_mask)} = {self.target_fraction:.0%})")


def segment_overlap(source: Scan, target: Scan, T_target_source: np.ndarray, kind: str = "convex",
                    frusta: tuple[View, View] | None = None) -> Overlap:
    """Segment the overlap both ways under the guess ``T_target_source``."""
    f_src, f_tgt = frusta if frusta is not None else (frustum_of(source, kind), frustum_of(target, kind))
    T = np.array(T_target_source, dtype=np.float64)
    return Overlap(f_tgt.contains(apply(T, source.points)), f_src, target.points, T)


def visible_cut(view: View, surface, points: np.ndarray, inside: np.ndarray, margin: float) -> np.ndarray:
    """(N,) bool: the points ``inside`` (N,) of (N, 3) points that ``view`` finds visible with ``margin``."""
    out = inside.copy()
    out[np.flatnonzero(inside)] = view.visible(surface, points[inside], margin)
    return out


def visible_from(target_surface, viewpoint: np.ndarray, points: np.ndarray, margin: float) -> np.ndarray:
    """(N,) bool: points (target frame) that the target's sensor could have seen.

    Beyond the paper: a point inside the frustum but more than ``margin`` behind the target's
    surface along the sensor ray is hidden from that sensor, so it has no partner there. Rays
    that hit nothing passed through a hole in the target. ``margin`` (units) should cover the
    uncertainty of the guess, so that a wrong guess does not cut true overlap.
    """
    rays = points - viewpoint
    dist = norms(rays)
    hit = target_surface.first_hit(np.broadcast_to(viewpoint, points.shape), rays / dist[:, None])
    return np.isfinite(hit) & (dist <= hit + margin)
