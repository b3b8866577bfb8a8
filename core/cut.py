"""Which source points the error uses: the overlap cut under the guess, widened when it is too small.

The paper cuts the overlap by frustum segmentation under the initial guess (section 2.1). Under a
poor guess that cut can be empty (the source lands beside the target's view) although the guess's
stated uncertainty allows overlap. Then, rather than refuse, the cut widens step by step: the frustum
opened by half the rotation uncertainty, by all of it, and finally the whole scan. The first cut
holding enough points is used, and its name is reported.

The same steps hold for every kind of scan through its view (core.frustum.View): a panorama's visibility
in its spherical image, an unstructured scan's closeness to its points. The names stay the frustum's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .frustum import Overlap, frustum_of
from .rows import norms
from .scan import Scan
from .surface import Surface
from .transforms import apply

MIN_SHARE = 0.02  # a cut is enough when it holds this share of the source's points (and >= 3)
CUTS = ("frustum", "frustum+half-uncertainty", "frustum+uncertainty", "whole scan")


@dataclass(frozen=True, eq=False)
class Cut:
    """used: (Ns,) bool source points in the cut; name: which of CUTS; overlap: the frustum masks both
    ways (the paper's overlap, for drawing; ``source_mask``, ``target_mask``)."""

    used: np.ndarray
    name: str
    overlap: Overlap

    @property
    def source_mask(self) -> np.ndarray:
        return self.overlap.source_mask

    @property
    def target_mask(self) -> np.ndarray:
        return self.overlap.target_mask


def overlap_cut(source: Scan, target: Scan, surface: Surface, T_target_source: np.ndarray, kind: str,
                visibility: bool, rotation_uncertainty: float, translation_uncertainty: float) -> Cut | None:
    """The first cut of CUTS with enough points, or None when even the frustum opened by the whole
    rotation uncertainty holds fewer than 3 (the guess's uncertainty allows no overlap)."""
    # the source's view now, though only drawing reads it (Overlap.target_mask): making it refuses a source no
    # view can be made of (points beside or behind its stated viewpoint); made on first use, such a pair
    # registered instead of being refused (the view: 0.06 s on a 250k-point Kinect frame)
    f_src, f_tgt = frustum_of(source, kind), frustum_of(target, kind)
    moved = apply(T_target_source, source.points)
    enough = max(3, int(MIN_SHARE * len(source.points)))
    src_mask = f_tgt.contains(moved)
    overlap = Overlap(src_mask, f_src, target.points, np.array(T_target_source, dtype=np.float64))
    used = src_mask.copy()
    if visibility and used.any():
        radius = float(norms(source.points[used] - source.points[used].mean(0)).max())
        used = f_tgt.guessed(surface, moved, used, translation_uncertainty + rotation_uncertainty * radius)
    if used.sum() >= enough:
        return Cut(used, CUTS[0], overlap)
    widest = used
    for name, angle, shift in ((CUTS[1], rotation_uncertainty / 2, translation_uncertainty / 2),
                               (CUTS[2], rotation_uncertainty, translation_uncertainty)):
        widest = f_tgt.widened(moved, angle, shift)
        if widest.sum() >= enough:
            return Cut(widest, name, overlap)
    if widest.sum() < 3:
        return None
    return Cut(np.ones(len(source.points), dtype=bool), CUTS[3], overlap)
