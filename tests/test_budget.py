"""The search's bound counts work (core.search.budget): the same answer on a fast machine and a slow one."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from rangereg.core.candidates import CandidateConfig
from rangereg.core.guess import Guess
from rangereg.core.register import Config, register
from rangereg.core.result import StopReason
from rangereg.core.search.budget import Budget, BudgetSpent


def test_a_budget_grants_what_it_has_and_stops_with_its_reason():
    b = Budget(steps=5, candidates=10)
    assert b.take("steps", 3) is None and b.left("steps") == 2
    stop = b.take("steps", 3)  # more than is left: refused, nothing recorded
    assert stop.reason is StopReason.WORK_BOUND and "its steps are spent (5 steps" in str(stop)
    assert b.used["steps"] == 3
    assert b.grant("candidates", 25) == 10 and b.left("candidates") == 0
    share = b.share(1, "the hybrid")
    share.take_or_stop("steps")
    assert b.used["steps"] == 4 and share.left("steps") == 0  # charged to both
    with pytest.raises(BudgetSpent) as e:
        share.take_or_stop("steps")
    assert "1 steps for the hybrid, 5 steps" in str(e.value.stop)
    assert Budget().spent() is None and Budget().left("steps") is None  # no limit


def test_seconds_are_read_only_when_asked_for():
    ticks = iter(range(0, 1000, 10))
    b = Budget(steps=None, seconds=15, clock=lambda: float(next(ticks)))  # t0 = 0
    assert b.take("steps") is None  # 10 s
    assert b.take("steps").reason is StopReason.TIME_BOUND  # 20 s > 15
    never = Budget(steps=3, clock=lambda: pytest.fail("the clock was read"))
    assert never.take("steps", 3) is None and never.spent().reason is StopReason.WORK_BOUND


def _unregistrable(scene):
    corner, _ = scene("corner")
    _, bowl = scene("bowl")  # two different objects: nothing is trusted, the search runs to its bound
    return corner, bowl


def test_a_slow_clock_gives_the_same_pose_the_bound_counts_work(scene, monkeypatch):
    import rangereg.core.search.budget as budget

    corner, bowl = _unregistrable(scene)
    cfg = Config(method="global", candidates=replace(CandidateConfig(), fallback_steps=40, kiss_matcher=False))
    fast = register(corner, bowl, Guess.none(), cfg)
    t = {"now": 0.0}

    def slow():  # a machine 1000 x slower: every reading of the clock 10 s later
        t["now"] += 10.0
        return t["now"]

    monkeypatch.setattr(budget, "time", SimpleNamespace(perf_counter=slow))
    slowed = register(corner, bowl, Guess.none(), cfg)
    assert np.array_equal(fast.transform, slowed.transform)
    assert fast.iterations == slowed.iterations and fast.stop_text == slowed.stop_text
    assert fast.stop_reason is StopReason.WORK_BOUND
    # a bound in seconds (a user's explicit choice) is what a slow machine changes
    timed = register(corner, bowl, Guess.none(), replace(cfg, candidates=replace(cfg.candidates, time_limit=30.0)))
    assert timed.stop_reason is StopReason.TIME_BOUND and timed.iterations.total < fast.iterations.total


def test_the_paper_methods_without_a_budget_are_untouched_and_with_one_stop_at_it(scene):
    from rangereg.core.search.run import run_method

    corner, _ = scene("corner")
    src, tgt = scene("corner")[1], corner
    T0 = np.eye(4)
    free = run_method(src, tgt, T0, Config(method="hybrid"))
    bounded = run_method(src, tgt, T0, Config(method="hybrid"), budget=Budget(steps=7))
    assert free.stop_reason is not StopReason.WORK_BOUND
    assert bounded.stop_reason is StopReason.WORK_BOUND and bounded.iterations.icp + bounded.iterations.sa == 7
