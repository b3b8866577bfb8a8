"""Where the global method's candidates come from, stage by stage, cheapest first (core.candidates,
core.kiss_matcher_candidates, Open3D's FPFH + RANSAC)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from ..candidates import fpfh_candidates, pair_spacing, rotation_candidates
from ..kiss_matcher_candidates import kiss_available, kiss_candidates
from .setup import Setup


@dataclass(frozen=True, eq=False)
class Hypotheses:
    """A stage's poses (each (4, 4) T_target_source), or why it has none (``why_none``)."""

    poses: list
    why_none: str = ""

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
    return Hypotheses(list(setup.basis.shift_to_fit(np.stack(poses))) if poses else [])


def matched(setup: Setup, method: str, voxels: tuple[float, ...] | None = None) -> Hypotheses:
    """Feature-matching hypotheses of ``method`` ("fpfh-ransac" at ``voxels`` spacings, or "kiss-matcher"),
    wherever they lie (the region orders them, it drops none)."""
    cc, source, target = setup.config.candidates, setup.source, setup.target
    spacing = pair_spacing(source, target)
    if method == "fpfh-ransac":
        return Hypotheses(fpfh_candidates(source, target, spacing, voxels or cc.fpfh_voxels, cc.fpfh_seeds,
                                          setup.config.seed))
    if not kiss_available():
        return Hypotheses([], "not installed (pip kiss-matcher; wheels for Python 3.11/3.12)")
    if setup.ahead is not None:
        return Hypotheses(setup.ahead.result())
    return Hypotheses(kiss_candidates(source, target, spacing, max(cc.fpfh_voxels)))


@dataclass(frozen=True)
class Stage:
    """name; make: the stage's hypotheses; refine: how many of them (the best by score) ICP refines;
    features: hypotheses from feature matching, start-free (a pose they give beyond the region they give
    from any guess: once one such is trusted, a later feature stage has nothing new to say)."""

    name: str
    make: Callable[[], Hypotheses]
    refine: int
    features: bool = False


def stages(setup: Setup) -> Iterator[Stage]:
    """The stages, cheapest first. A rotation stated within ``guess_first_deg``: the guess alone, then
    KISS-Matcher's one hypothesis (computed ahead, in its own process), then the rotation samples. A wider
    one: the guess and KISS-Matcher's hypothesis scored together (the lower refined first), then the
    samples. FPFH + RANSAC last: it costs about what the whole Open3D pipeline does."""
    cc = setup.config.candidates
    kiss = cc.enabled and cc.kiss_matcher
    guess = Hypotheses([setup.T_guess])
    if setup.region.stated_rotation_deg > cc.guess_first_deg and kiss:
        yield Stage("guess, kiss-matcher", lambda: Hypotheses(guess.poses + matched(setup, "kiss-matcher").poses), 2, True)
    else:
        yield Stage("guess", lambda: guess, 1)
        if kiss:
            yield Stage("kiss-matcher", lambda: matched(setup, "kiss-matcher"), 1, True)
    if not cc.enabled:
        return
    yield Stage("rotation samples", lambda: sampled(setup), cc.refine)
    for v in sorted(cc.fpfh_voxels, reverse=True):  # coarse first: 5 spacings costs ~1/5 of 2 spacings
        yield Stage(f"fpfh-ransac {v:g} spacings", lambda v=v: matched(setup, "fpfh-ransac", (v,)), cc.fpfh_seeds, True)


