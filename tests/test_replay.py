"""Replay's trace files without a browser: parsed line by line, and refused when recorded on other scans."""

from __future__ import annotations

import json

import numpy as np
import pytest

from app.tab.replay import check_trace_fits, parse_trace
from core.errors import InputError
from core.events import Event
from core.io import load_scan
from core.problem import prepare, relative_guess
from core.scenes import scene_paths
from core.transforms import from_params
from tests.conftest import ASSETS


def corner_problem(name: str = "corner"):
    source, target = (load_scan(p) for p in scene_paths(ASSETS, name))
    return prepare(source, target, relative_guess(source, target), seed=0), source, target


def test_a_trace_of_these_scans_is_taken_and_one_of_other_scans_refused():
    problem, source, target = corner_problem()
    from core.transforms import invert

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
    from app.workbench import ServeOptions, Workbench

    problem, source, target = corner_problem()
    far = from_params(np.array([0.0, 0.0, 0.0, 0.0, 0.6, 0.0])) @ relative_guess(source, target)
    path = tmp_path / "other.jsonl"
    path.write_text(json.dumps(Event("icp", 1, 1, 1, far, 1e-3).to_json()) + "\n")
    with pytest.raises(InputError, match="does not fit these scans"):
        Workbench(ServeOptions(trace=str(path), port=1))
