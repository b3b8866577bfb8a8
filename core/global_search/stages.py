"""Where the global method's candidates come from, stage by stage, cheapest first (core.candidates,
core.kiss_matcher_candidates, Open3D's FPFH + RANSAC)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ..candidates import FPFH_FINER_BELOW, feature_spacing, fpfh_candidates, rotation_candidates, voxel_cells
from ..kiss_matcher_candidates import kiss_available, kiss_candidates
from ..scan import ScanKind
from .setup import Setup


@dataclass(frozen=True, eq=False)
class Hypotheses:
    """A stage's poses (each (4, 4) T_target_source), or why it has none (``why_none``); labels: where each
    pose came from ("guess", "kiss-matcher", ...), beside ``poses``."""

    poses: list
    why_none: str = ""
    labels: tuple = ()

    def label(self, k: int) -> str:
        return self.labels[k]

    def __add__(self, other: Hypotheses) -> Hypotheses:
        return Hypotheses(self.poses + other.poses, self.why_none or other.why_none, self.labels + other.labels)

    @property
    def source_note(self) -> int | str:
        """For the result's candidate sources: how many, or why none."""
        return self.why_none or len(self.poses)


def sampled(setup: Setup) -> Hypotheses:
    """The rotation samples within the region (core.candidates.rotation_candidates), shifted to fit."""
    cc, region = setup.config.candidates, setup.region
    if not cc.enabled:
        return Hypotheses([], "candidates off")
    poses = rotation_candidates(setup.source, setup.target, setup.T_guess, region.rotation + region.slack_rotation,
                                region.translation, cc.rotation_samples)
    poses = list(setup.basis.shift_to_fit(np.stack(poses))) if poses else []
    return Hypotheses(poses, labels=("rotation samples",) * len(poses))


def matched(setup: Setup, method: str, voxels: tuple[float, ...] | None = None) -> Hypotheses:
    """Feature-matching hypotheses of ``method`` ("fpfh-ransac" at ``voxels`` spacings, or "kiss-matcher"),
    wherever they lie (the region orders them, it drops none)."""
    cc, source, target = setup.config.candidates, setup.source, setup.target
    spacing = feature_spacing(source, target)
    if method == "fpfh-ransac":
        voxels = voxels or cc.fpfh_voxels
        poses = fpfh_candidates(source, target, spacing, voxels, cc.fpfh_seeds, setup.config.seed)
        return Hypotheses(poses, labels=(f"fpfh-ransac {max(voxels):g} spacings",) * len(poses))
    if not kiss_available():
        return Hypotheses([], "not installed (pip kiss-matcher; wheels for Python 3.11/3.12)")
    poses = setup.ahead.result() if setup.ahead is not None else kiss_candidates(source, target, spacing,
                                                                                   max(cc.fpfh_voxels))
    return Hypotheses(poses, labels=("kiss-matcher",) * len(poses))


@dataclass(frozen=True)
class Stage:
    """name; make: the stage's hypotheses; refine: how many of them (the best by score) ICP refines;
    costly: skipped once a pose beyond the region is trusted (FPFH + RANSAC, about the cost of the whole
    Open3D pipeline: start-free, it would give that pose again rather than a twin inside)."""

    name: str
    make: Callable[[], Hypotheses]
    refine: int
    costly: bool = False


def stages(setup: Setup) -> Iterator[Stage]:
    """The stages, cheapest first. A rotation stated within ``guess_first_deg``: the guess alone, then
    KISS-Matcher's one hypothesis (computed ahead, in its own process), then the rotation samples. A wider
    one: the guess and KISS-Matcher's hypothesis scored together (the lower refined first), then the
    samples. FPFH + RANSAC last: it costs about what the whole Open3D pipeline does. But with no guess, where either
    scan is a fused cloud, FPFH + RANSAC instead of the rotation samples: the samples place each turn by the
    centroids, which partly overlapping fragments of a room do not share. Measured (benchmarks/written_files.py, 24
    fused pairs from no guess; the sensor sweep's fragments family): no right pose came from them, but twins of a
    room's corner did (tsdf-13, whose truth FPFH found after them in 6.1-6.4 s, and without them in 3.3-3.7 s); the
    pairs nothing registers end 2-3 s sooner (tsdf-14 7.8-9.1 -> 5.4-6.2 s, walk15-1 7.0-7.4 -> 4.2-4.8 s), at the
    same poses; the sensor sweep's fragments family is bitwise as before."""
    cc = setup.config.candidates
    kiss = cc.enabled and cc.kiss_matcher
    guess = Hypotheses([setup.T_guess], labels=("guess",))
    if setup.region.stated_rotation_deg > cc.guess_first_deg and kiss:
        yield Stage("guess, kiss-matcher", lambda: guess + matched(setup, "kiss-matcher"), 2)
    else:
        yield Stage("guess", lambda: guess, 1)
        if kiss:
            yield Stage("kiss-matcher", lambda: matched(setup, "kiss-matcher"), 1)
    if not cc.enabled:
        return
    if setup.guess.is_none and ScanKind.UNSTRUCTURED in (setup.source.kind, setup.target.kind):
        yield from fpfh_stages(setup)
        yield Stage("rotation samples", lambda: Hypotheses([], UNPLACED), 0)
        return
    yield Stage("rotation samples", lambda: sampled(setup), cc.refine)
    yield from fpfh_stages(setup)


# why a fused cloud with no guess gets no rotation samples (stages' notes)
UNPLACED = ("not run: with no guess a fused cloud's samples are placed by the centroids, which partly overlapping "
            "fragments do not share")


def fpfh_stages(setup: Setup) -> Iterator[Stage]:
    """FPFH + RANSAC, the coarse grid first; a finer one only where the coarser left too few cells."""
    cc = setup.config.candidates
    coarser = None
    for v in sorted(cc.fpfh_voxels, reverse=True):  # coarse first: 5 spacings costs ~1/5 of 2 spacings
        if coarser is not None and not too_few_cells(setup, coarser):
            break  # the coarser grid held enough of both scans: a finer one adds cost, not poses
        yield Stage(f"fpfh-ransac {v:g} spacings", lambda v=v: matched(setup, "fpfh-ransac", (v,)), cc.fpfh_seeds,
                    costly=True)
        coarser = v


def too_few_cells(setup: Setup, voxel: float) -> bool:
    """Whether a grid of ``voxel`` point spacings leaves either scan fewer than FPFH_FINER_BELOW cells."""
    size = voxel * feature_spacing(setup.source, setup.target)
    return min(voxel_cells(setup.source, size), voxel_cells(setup.target, size)) < FPFH_FINER_BELOW


