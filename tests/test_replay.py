"""Replay's trace files without a browser: parsed line by line, and refused when recorded on other scans."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.app.tab.replay import check_trace_fits, parse_trace
from rangereg.core.errors import InputError
from rangereg.core.events import Event
from rangereg.core.io import load_scan
from rangereg.core.problem import prepare, relative_guess
from rangereg.core.scenes import scene_paths
from rangereg.core.transforms import from_params

from tests.conftest import ASSETS


def corner_problem(name: str = "corner"):
    source, target = (load_scan(p) for p in scene_paths(ASSETS, name))
    return prepare(source, target, relative_guess(source, target), seed=0), source, target


def test_a_trace_of_these_scans_is_taken_and_one_of_other_scans_refused():
    problem, source, target = corner_problem()
    from rangereg.core.transforms import invert

    truth = invert(target.pose) @ source.pose
    events = [Event("icp", 1, 1, 1, truth, float(problem.error(truth)))]
    text = "\n".join(json.dumps(e.to_json()) for e in events)  # a trace from before headers: checked by E
    back = parse_trace(text, "run.jsonl")
    assert len(back) == 1 and np.allclose(back[0].T, truth)
    check_trace_fits(problem, back, threshold=0.0, name="run.jsonl")
    # the same numbers from another pair: its best pose puts these scans far apart
    moved = from_params(np.array([0.0, 0.0, 0.0, 0.0, 0.5, 0.0])) @ truth
    wrong = [Event("icp", 1, 1, 1, moved, events[0].error)]
    with pytest.raises(InputError, match="does not fit these scans"):
        check_trace_fits(problem, wrong, threshold=0.0, name="other.jsonl")


@pytest.mark.parametrize("text, said", [("", "holds no events"), ('{"phase": "icp"}', "line 1"),
                                         ("\nnot json", "line 2")])
def test_a_bad_trace_is_one_message_naming_its_line(text, said):
    with pytest.raises(InputError, match=said):
        parse_trace(text, "bad.jsonl")


def test_serve_refuses_a_trace_of_other_scans_before_it_listens(tmp_path):
    from rangereg.app.workbench import ServeOptions, Workbench

    problem, source, target = corner_problem()
    far = from_params(np.array([0.0, 0.0, 0.0, 0.0, 0.6, 0.0])) @ relative_guess(source, target)
    path = tmp_path / "other.jsonl"
    path.write_text(json.dumps(Event("icp", 1, 1, 1, far, 1e-3).to_json()) + "\n")
    with pytest.raises(InputError, match="does not fit these scans"):
        Workbench(ServeOptions(trace=str(path), port=1))


def test_a_loaded_traces_path_on_the_slice_starts_at_its_own_guess_not_the_pages():
    # the trace was run from another guess than the page's: its path (contour, terrain, recording) starts there
    from rangereg.app.tab.landscape import picture
    from rangereg.app.tab.state import SliceView, TabState
    from rangereg.core.config import Config
    from rangereg.core.landscape import Slice, project
    from rangereg.core.trace import TraceHeader

    problem, source, target = corner_problem()
    T_page = relative_guess(source, target)
    T_trace = from_params(np.array([4.0, -2.0, 1.0, 0.0, 0.1, 0.0])) @ T_page  # the trace's own guess
    events = [Event("icp", 1, 1, 1, T_page, float(problem.error(T_page)))]
    a, b = np.linspace(-10.0, 10.0, 3), np.linspace(-20.0, 20.0, 3)
    st = TabState(source=source, target=target, T_init=T_page, T=T_page, problem=problem)
    st.slice = SliceView(Slice(("tx", "ry"), a, b, np.ones((3, 3)), T_page), problem, 1)
    st.events = events
    st.run_header = TraceHeader.of(source, target, T_trace, Config())  # as ReplayPanel.load_trace sets it
    assert st.run_start is st.run_header.T_init
    _, xy, *_ = picture(st)
    want = project(problem, T_page, ("tx", "ry"), [T_trace, T_page])
    assert np.allclose(xy, want) and not np.allclose(xy[0], xy[1])
    st.run_header = None  # a page run without a header starts at the page's guess
    assert picture(st)[1][0] == pytest.approx(project(problem, T_page, ("tx", "ry"), [T_page])[0])


def test_auto_speed_plays_any_run_in_a_few_seconds_and_a_chosen_speed_is_kept():
    from rangereg.app.tab.replay import AUTO, REPLAY_SECONDS, SPEEDS, play_speed

    assert SPEEDS[0] == AUTO  # the default
    for n in (39, 149, 2000, 20000):
        assert n / play_speed(AUTO, n) == pytest.approx(REPLAY_SECONDS)  # 39 events at 100/s were over in 0.4 s
    assert play_speed(AUTO, 3) == 1.0  # a few events: one a second, not a blink
    assert play_speed("300", 39) == 300.0
