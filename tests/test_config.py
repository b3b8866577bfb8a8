"""Each config checks its own knobs (core.config); the search constants are set through them."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from rangereg.core import prepare
from rangereg.core.config import Config, IcpConfig, SearchConfig, ThresholdConfig
from rangereg.core.errors import InputError
from rangereg.core.search import SearchState


def test_the_defaults_are_the_measured_constants():
    s, t = SearchConfig(), ThresholdConfig()
    assert (s.bound, s.min_gain, s.resegment_rotation_deg, s.resegment_translation) == (2.0, 0.01, 2.0, 0.02)
    assert (s.coarse_widenings, s.coarse_threshold, s.same_cut, s.confirm_hops) == ((100.0, 10.0, 1.0), 3.0, 0.9, 15)
    assert t.factor == 6.0
    Config().validate()


@pytest.mark.parametrize("field, bad, message", [
    ("bound", 0.0, "search bound"), ("bound", float("inf"), "search bound"),
    ("min_gain", -0.1, "minimum gain"), ("min_gain", 1.0, "minimum gain"),
    ("resegment_rotation_deg", 0.0, "converged rotation"), ("resegment_rotation_deg", 181.0, "converged rotation"),
    ("resegment_translation", 0.0, "converged translation"),
    ("coarse_widenings", (), "widenings"), ("coarse_widenings", (100.0, 10.0), "widenings"),
    ("coarse_widenings", (0.5, 1.0), "widenings"),
    ("coarse_threshold", 0.5, "coarse threshold"),
    ("same_cut", 0.0, "same-cut"), ("same_cut", 1.5, "same-cut"),
    ("confirm_hops", -1, "confirming hops"),
])
def test_search_config_refuses_nonsense(field, bad, message):
    with pytest.raises(InputError, match=message):
        replace(SearchConfig(), **{field: bad}).validate()
    with pytest.raises(InputError, match=message):  # and through the run's config
        Config(search=replace(SearchConfig(), **{field: bad})).validate()


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_threshold_config_refuses_nonsense(bad):
    with pytest.raises(InputError, match="threshold factor"):
        Config(threshold_estimate=ThresholdConfig(factor=bad)).validate()


@pytest.mark.parametrize("bad, message", [(dict(refine_metric="planar"), "refinement's ICP metric"),
                                          (dict(refine=0), "refine >= 1"), (dict(sample=5), "at least 10"),
                                          (dict(normal_neighbours=2), "at least 3 neighbours"),
                                          (dict(kiss_grids=(4.0, float("inf"))), "grids must be positive"),
                                          (dict(kiss_grids=(-1.0,)), "grids must be positive"),
                                          (dict(settle_share=1.0), "settle_share"),
                                          (dict(settle_share=-0.1), "settle_share"),
                                          (dict(settle_share=float("nan")), "settle_share")])
def test_candidate_config_refuses_nonsense(bad, message):
    from rangereg.core.candidates import CandidateConfig

    with pytest.raises(InputError, match=message):
        Config(candidates=CandidateConfig(**bad)).validate()
    assert CandidateConfig().refine_metric == "plane" and IcpConfig().metric == "point"  # the paper's ICP stays Horn's


@pytest.mark.parametrize("bad, message", [(dict(sample=5), "at least 10 points"), (dict(legs=0), "at least 1 leg"),
                                          (dict(legs=2.5), "whole number of at least 1 leg"),
                                          (dict(settled_deg=0.0), "settled_deg must be > 0"),
                                          (dict(step_spacings=float("nan")), "step_spacings must be > 0")])
def test_the_whole_scans_legs_refuse_nonsense(bad, message):
    from rangereg.core.candidates import CandidateConfig, WholeLegs

    with pytest.raises(InputError, match=message):
        Config(candidates=CandidateConfig(whole=WholeLegs(**bad))).validate()
    Config(candidates=CandidateConfig(whole=WholeLegs(sample=10, legs=1))).validate()


@pytest.mark.parametrize("bad", [dict(seed=-1), dict(simplex_scale=0.0), dict(restarts=0)])
def test_run_config_refuses_nonsense(bad):
    with pytest.raises(InputError):
        Config(**bad).validate()


def test_the_search_bound_sets_the_region(scene):
    a, b = scene("corner")
    p = prepare(b, a)
    shift = np.eye(4)
    shift[0, 3] = 1.5 * p.translation_uncertainty  # 1.5 x the guess's translation uncertainty away
    assert SearchState(p, Config(), None).inside(shift)  # default: 2 x
    assert not SearchState(p, Config(search=SearchConfig(bound=1.0)), None).inside(shift)
