"""The result (core.result): why the search stopped, as an enum and as text; below the threshold."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
from rangereg.core.intrusion import MAX_INTRUSION
from rangereg.core.result import GlobalDetails, Iterations, Result, Stop, StopReason, Verdict
from rangereg.core.threshold import pair_threshold


def _result(error=0.5, threshold=1.0, stop=Stop(StopReason.BELOW_THRESHOLD)):
    return Result(np.eye(4), error, Iterations(12, 30), 1, 80, 0.25, "hybrid", threshold, stop)


def test_the_stop_reason_is_an_enum_member_and_its_text_names_the_counts():
    r = _result(error=3.0, stop=Stop(StopReason.RESTARTS_SPENT, "restart budget (40 ICP runs) spent"))
    assert r.stop_reason is StopReason.RESTARTS_SPENT
    assert r.stop_text == "restart budget (40 ICP runs) spent"
    assert _result().stop_text == "error below threshold"  # no text: the reason's own words
    assert "stopped: restart budget (40 ICP runs) spent" in repr(r)


def test_below_threshold_says_whether_to_trust_the_pose():
    assert _result(error=0.5, threshold=1.0).below_threshold
    assert not _result(error=1.0, threshold=1.0).below_threshold
    assert not _result(error=0.5, threshold=0.0).below_threshold  # threshold 0: searched until SA gave up


def test_json_keeps_its_keys_with_readable_text_and_adds_below_threshold():
    out = json.loads(json.dumps(_result().to_json()))
    assert set(out) == {"transform", "error", "iterations", "local_minima", "evaluations", "seconds", "method",
                        "threshold", "stop_reason", "below_threshold", "cut"}
    assert out["stop_reason"] == "error below threshold" and out["below_threshold"] is True
    assert out["iterations"] == {"icp": 12, "sa": 30}


def test_the_trust_text_says_why_in_the_terms_of_the_test_that_decided(scene):
    assert _result(error=0.5, threshold=1.0).trust_text == "E is below the threshold (1)"
    source, target = scene("corner")
    from rangereg.core.guess import Guess

    region = Guess.identity().region(source, target)

    def global_(trusted, misfit, beyond=""):
        verdict = Verdict(pair_threshold(1.0, 2.0, 0.1), misfit, holds=trusted)
        details = GlobalDetails(region, not beyond, beyond, 0.1, 4, {"guess": 1})
        return Result(np.eye(4), 0.5, Iterations(3, 0, 4), 0, 9, 0.1, "global", 20.0, Stop(StopReason.TRUSTED),
                      trusted=trusted, verdict=verdict, details=details)

    assert "agree at the noise level in distance and normals (misfit 2.1 < 4.5)" in global_(True, 2.1).trust_text
    assert "(misfit 7.3, trusted below 4.5)" in global_(False, 7.3).trust_text
    assert "too little" in global_(False, None).trust_text  # no misfit: fewer than 3 points matched
    assert "E is" not in global_(True, 2.1).trust_text  # E on the cut is not what the pair threshold bounds
    beyond = global_(True, 1.3, "found 41 deg / 0.12 m beyond the stated uncertainty (15 deg, ...)")
    assert beyond.within_region is False and beyond.trust_text.endswith("beyond the stated uncertainty (15 deg, ...)")
    out = beyond.to_json()
    assert out["trusted"] is True and out["within_region"] is False and out["beyond"].startswith("found 41 deg")
    assert out["iterations"] == {"icp": 3, "sa": 0, "candidates": 4} and out["region"]["rotation_deg"] == 15.0


def test_a_pose_whose_scans_cut_through_each_others_rooms_is_doubted_in_those_words(scene):
    from rangereg.core.guess import Guess

    source, target = scene("corner")
    region = Guess.identity().region(source, target)
    verdict = Verdict(pair_threshold(1.0, 2.0, 0.1), 1.7, None, 0.24)
    r = Result(np.eye(4), 0.5, Iterations(3, 0, 4), 0, 9, 0.1, "global", 20.0, Stop(StopReason.TRUSTED),
               trusted=False, verdict=verdict, details=GlobalDetails(region, True, "", 0.1, 4, {"guess": 1}, "guess"))
    assert "24.0 % of one scan's points lie where the other's sensor looked through" in r.trust_text
    assert f"trusted below {100 * MAX_INTRUSION:g} %" in r.trust_text and r.to_json()["intrusion"] == 0.24
    assert verdict.looked_through  # what a campaign reads: a twin, never corroborated (core.merge_graph)
    assert not replace(verdict, intrusion=0.5 * MAX_INTRUSION).looked_through
    assert not replace(verdict, intrusion=None).looked_through


def test_a_weakly_pinned_pose_whose_walls_pass_where_the_other_saw_them_end_is_doubted_in_those_words(scene):
    # a slide along a room's free motion (sim-fragments-0's guess slid 0.75 m ended 1.16 m off, trusted, at a free-space
    # share of 0.066, under a fused cloud's 0.072): where the rise is asked, the bound between known sensors holds
    from types import SimpleNamespace

    from rangereg.core.guess import Guess
    from rangereg.core.intrusion import MAX_LOOKED_THROUGH

    source, target = scene("corner")
    region = Guess.identity().region(source, target)
    weak = SimpleNamespace(rise=1.23, stable_rise=None, ratio=0.008, matched=900, stably_pinned=False,
                           free_motion="a translation along (-0.81, +0.18, -0.56)", pins=lambda bound: True)
    verdict = Verdict(pair_threshold(1.0, 2.0, 0.1), 0.95, weak, 0.066)
    r = Result(np.eye(4), 0.5, Iterations(3, 0, 4), 0, 9, 0.1, "global", 20.0, Stop(StopReason.TRUSTED),
               trusted=False, verdict=verdict, details=GlobalDetails(region, True, "", 0.1, 4, {"guess": 1}, "guess"))
    assert verdict.threshold.slide_bound == MAX_LOOKED_THROUGH < 0.066 < MAX_INTRUSION
    assert verdict.slid_through and not verdict.looked_through  # a slide, not a twin: the campaign's rules stand
    assert "pins the pose weakly (it may slide by a translation along (-0.81" in r.trust_text
    assert "6.6 % of one scan's points" in r.trust_text and f"trusted below {100 * MAX_LOOKED_THROUGH:g} %" in r.trust_text
    assert not replace(verdict, constraint=_with_rise(weak, None)).slid_through  # pinned well: the fused bound
    assert not replace(verdict, intrusion=0.5 * MAX_LOOKED_THROUGH).slid_through
    doubted = _with_rise(weak, 1.05)  # the rise falls short: "pins weakly ... only 1.05 x", as before
    doubted.pins = lambda bound: False
    assert "scores only 1.05 x as high" in replace(r, verdict=replace(verdict, constraint=doubted)).trust_text


def _with_rise(c, rise):
    from types import SimpleNamespace

    return SimpleNamespace(**{**vars(c), "rise": rise})
