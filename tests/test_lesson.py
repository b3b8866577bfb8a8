"""The lesson without a browser: its scene and starts, its step machine and sentences, and the page's numbers."""

from __future__ import annotations

import re

import numpy as np
import pytest
from rangereg.app.figures import fmt, tidy
from rangereg.app.tab.lesson import Facts, Leg, Story, legs, sentence
from rangereg.core.events import Event


def leg(phase: str, E_best: float, minimum: bool = False, number: int = 1, events: int = 10, T=(np.nan, np.nan)):
    return Leg(phase, number, events, 10 * E_best, E_best, E_best, T[0], T[1], minimum)


@pytest.mark.parametrize("value, shown", [
    (9.285e-05, "0.00009285"), (-2.775557562e-17, "-2.776e-17"), (706.140608, "706.1"), (12345.678, "12350"),
    (1.32679e-08, "1.327e-08"), (0.5, "0.5"), (0.0, "0"), (2.0, "2"), (123456789.0, "1.235e+08"), (None, "-"),
    (float("nan"), "-"), (0.1 + 0.2, "0.3")])
def test_numbers_are_shown_with_four_significant_digits(value, shown):
    assert fmt(value) == shown


def test_core_text_is_tidied_to_four_digits_and_other_numbers_are_left_alone():
    assert tidy("E is below the threshold (1.32679e-08); 0.46 s; misfit 2.31 < 4.5; 40 ICP runs") == (
        "E is below the threshold (1.327e-08); 0.46 s; misfit 2.31 < 4.5; 40 ICP runs")
    assert tidy("pose 706.140608 mm") == "pose 706.1 mm"


def test_legs_group_a_run_by_phase_and_leg_and_skip_the_temperature_before_it_is_set():
    def ev(phase, leg_, E, T=None, minimum=False):
        return Event(phase, 0, 0, leg_, np.eye(4), E, T, True, minimum)

    events = [ev("icp", 1, 9.0), ev("icp", 1, 5.0), ev("icp", 1, 5.0, minimum=True),
              ev("sa", 1, 7.0, 0.0), ev("sa", 1, 6.0, 4.0), ev("sa", 1, 4.0, 3.0), ev("icp", 2, 3.0), ev("icp", 2, 1.0)]
    got = legs(events)
    assert [(g.phase, g.number, g.events, g.minimum) for g in got] == [("icp", 1, 3, True), ("sa", 1, 3, False),
                                                                      ("icp", 2, 2, False)]
    assert got[1].T_first == 4.0 and got[1].T_last == 3.0 and got[1].E_best == 4.0  # 0: the first simplex's
    assert np.isnan(got[0].T_first) and got[2].E_best == 1.0


def test_the_story_walks_the_papers_figure_7_one_click_at_a_time():
    story, thr = Story(), 2.0
    assert story.advance("idle", [], thr) == "start" and story.step == "icp"
    assert not story.ready("running") and story.advance("running", [], thr) is None  # Next waits while it moves
    stuck = [leg("icp", 50.0, minimum=True)]
    assert story.advance("paused", stuck, thr) is None and story.step == "stuck"  # nothing runs: what it means
    assert story.advance("paused", stuck, thr) == "next" and story.step == "anneal"
    lower = stuck + [leg("sa", 40.0), leg("icp", 40.0, number=2, events=1)]  # paused where ICP's next leg began
    assert story.advance("paused", lower, thr) is None and story.step == "lower"
    assert story.advance("paused", lower, thr) == "next" and story.step == "icp-again"
    below = stuck + [leg("sa", 40.0), leg("icp", 1.0, number=2), leg("icp", 0.9, number=3, events=1)]
    assert story.advance("paused", below, thr) == "resume" and story.step == "below"
    assert not story.ready("finished")
    assert story.history == ["icp", "stuck", "anneal", "lower", "icp-again", "below"]


def test_a_second_local_minimum_sends_the_story_back_to_stuck_and_a_cold_annealing_gives_up():
    story, thr = Story(step="icp-again"), 2.0
    again = [leg("icp", 50.0, minimum=True), leg("sa", 40.0), leg("icp", 30.0, minimum=True, number=2)]
    assert story.advance("paused", again, thr) is None and story.step == "stuck"
    assert story.advance("paused", again, thr) == "next"
    assert story.advance("finished", again + [leg("sa", 31.0, number=2)], thr) is None and story.step == "gave-up"
    assert not story.ready("finished") and not story.ready("idle")


def test_each_step_is_one_sentence_quoting_the_statuss_own_numbers():
    from rangereg.app.tab.status import Progress, rows

    sa_last = Event("sa", 97, 72, 1, np.eye(4), 533.17, 472.05)
    at_lower = Progress(n_icp=25, n_sa=72, n_min=1, last=sa_last, E=533.17, E_kind="event", temperature=472.05,
                        temperature_first=582.78, minimum_E=582.78)
    stuck = Progress(n_icp=25, n_min=1, last=Event("icp", 25, 25, 1, np.eye(4), 582.78, None, True, True), E=582.78,
                     E_kind="event", minimum_E=582.78)
    done = Progress(n_icp=76, n_sa=72, n_min=1, E=0.579, E_kind="result", minimum_E=582.78)

    def f(p, **kw):
        return Facts(10.57, "mm", (362.3, -15.0), p, **kw)

    assert "tx = 362.3 mm and ry = -15°" in sentence("start", f(Progress()))
    # the Start dropdown's numbers (about the source's centre) are named beside the slice's, so the two tx agree
    text = sentence("start", f(Progress(), chosen=(325.0, -15.0)))
    assert "tx = 362.3 mm and ry = -15°" in text and "the Start's 325 mm is about" in text, text
    assert "E = 582.8 mm² after 25 ICP iterations, above the threshold 10.57 mm²" in sentence("stuck", f(stuck))
    text = sentence("lower", f(at_lower))
    assert "72 annealing moves" in text and "from 582.8 to 472.1 mm²" in text and "E = 533.2 mm²" in text
    assert "below ICP's minimum at 582.8 mm²" in text
    text = sentence("below", f(done, finished=True, off=(0.04, 0.54)))
    assert "E = 0.579 mm² is below the threshold 10.57 mm²" in text and "0.04° and 0.54 mm from the truth" in text
    assert "in 76 ICP and 72 SA iterations" in text
    # every number of a sentence is written in the status rows of the same Progress
    for step, p in (("stuck", stuck), ("lower", at_lower), ("below", done)):
        status = " ".join(rows(p, pair="a → b", units="mm", overlap=1, method="hybrid", state="paused", lock="",
                               threshold=10.57, threshold_name="Threshold", guess=""))
        numbers = re.findall(r"-?\d+(?:\.\d+)?(?:e[+-]\d+)?", sentence(step, f(p)).split("**", 2)[2])
        assert numbers and all(n in status for n in numbers if n not in ("0.04", "0.54")), (step, numbers, status)
    # the threshold's value comes before what it is (a narrow panel cuts the row's end, not the number)
    row = rows(done, pair="a → b", units="mm", overlap=1, method="hybrid", state="idle", lock="", threshold=4.478e-2,
               threshold_name="Pair threshold", threshold_basis="Run global's test", guess="")[4]
    assert row == "Pair threshold 0.04478 mm² (Run global&#x27;s test)", row
    for step, title in (("icp", "1 · ICP runs"), ("stuck", "2 · Stuck above the threshold"),
                        ("anneal", "3 · Annealing roams, temperature falling"), ("lower", "4 · A lower point"),
                        ("icp-again", "5 · ICP again"), ("below", "6 · Below the threshold")):
        assert sentence(step, f(at_lower)).startswith(f"**{title}.**")
        assert sentence(step, f(at_lower)).count(". ") <= 2  # a title and one sentence


def test_the_page_runs_the_lesson_with_the_settings_the_bench_uses():
    # the Lesson tab sets the page's fields to their first values and seed k, whatever was typed before: the page
    # shows bench --lesson's run k
    from types import SimpleNamespace

    from rangereg.app.tab.run import RunPanel
    from rangereg.app.tab.settings import page_config, read_settings
    from rangereg.core.register import Config

    from tests.test_tab import settings_handles

    for k in (0, 7):
        typed = settings_handles(seed="99", cooling="0.5", max_points="40", lock="rx", no_guess=True)
        RunPanel.use_lesson_settings(SimpleNamespace(h=SimpleNamespace(settings=typed)), seed=k)
        assert page_config(read_settings(typed), "hybrid") == Config(method="hybrid", seed=k)


def test_the_lesson_starts_lie_where_written_in_the_target_frame():
    from rangereg.core.scenes import LESSON
    from rangereg.core.simulate import make_scene, true_transform
    from rangereg.core.transforms import pose_error

    target, source = make_scene(LESSON.scene, 3)  # seeds are the scenes' indices: 'ribbed' is the fourth
    T_true = true_transform(source, target)
    for k, (tx, ry) in enumerate(LESSON.starts):
        T = LESSON.start(source, target, k)
        rot, shift = pose_error(T, T_true, source.centroid)
        assert rot == pytest.approx(abs(ry), abs=1e-9) and shift == pytest.approx(abs(tx), abs=1e-6)
    from rangereg.core.errors import InputError

    with pytest.raises(InputError):
        LESSON.start(source, target, len(LESSON.starts))


def test_the_lesson_slice_shows_small_minima_in_a_larger_pit_and_the_plain_corner_one():
    # the README's claim, on the lesson's slice through the truth (a coarser grid than the page's: the budget)
    from rangereg.core.landscape import compute_slice
    from rangereg.core.problem import prepare
    from rangereg.core.scenes import LESSON
    from rangereg.core.simulate import make_scene, true_transform

    counts = {}
    for name, seed in (("ribbed", 3), ("corner", 0)):
        target, source = make_scene(name, seed)
        T_true = true_transform(source, target)
        p = prepare(source, target, T_true, seed=0)
        sl = compute_slice(p, T_true, LESSON.params, LESSON.spans, 35)
        minima = sl.minima()
        counts[name] = len(minima)
        assert np.allclose(minima[0], 0.0, atol=1e-9)  # the lowest is the truth
    assert counts["corner"] == 1 and counts["ribbed"] >= 4, counts


def test_the_lesson_bench_says_each_target_with_its_value_and_refuses_more_starts_than_it_has(rangereg):
    from rangereg.app.bench import lesson_verdict

    rows = [{"method": "icp", "success_rate": 0.0, "mean_iterations": 41.0, "median_seconds": 0.8},
            {"method": "sa", "success_rate": 0.9, "mean_iterations": 13729.0, "median_seconds": 66.0},
            {"method": "hybrid", "success_rate": 0.8, "mean_iterations": 155.0, "median_seconds": 0.99}]
    text = lesson_verdict(rows)
    assert "met: ICP alone success <= 0.2 (0.00)" in text and "MISSED: hybrid success >= 0.9 (0.80)" in text
    assert "met: hybrid's mean iterations <= 25 % of annealing's (1.1%)" in text and "(0.99 s)" in text
    code, out, err = rangereg("bench", "--lesson", "--runs", "11")
    assert code == 2 and "the lesson has 10 starts" in err


def test_a_bad_lock_is_said_in_the_pages_words_not_the_clis_flag():
    from rangereg.app.tab.settings import checked_lock
    from rangereg.core.errors import InputError

    with pytest.raises(InputError) as bad:
        checked_lock("rx,foo")
    assert str(bad.value).startswith("Locked parameters: cannot lock foo") and "--lock" not in str(bad.value)
    assert checked_lock(" rx,ry ") == "rx,ry"
