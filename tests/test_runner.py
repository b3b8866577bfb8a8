"""The run controller's state machine (app/runner.py), driven by a scripted optimiser: no scans, no page."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
import rangereg.app.runner as runner
from rangereg.app.runner import Run
from rangereg.core.events import Cancelled, Event

# icp leg 1 (3 iterations, ending in a local minimum), sa leg 1 (4 moves), icp leg 2 (2 iterations)
SCRIPT = ([("icp", 1, False)] * 2 + [("icp", 1, True)] + [("sa", 1, False)] * 4 + [("icp", 2, False)] * 2)


def scripted(script=SCRIPT, gate: threading.Event | None = None):
    """A stand-in for core.register: emits ``script`` through the listener, returns how many went through."""

    def work(listener):
        for k, (phase, leg, minimum) in enumerate(script, start=1):
            try:
                listener(Event(phase, k, k, leg, np.eye(4), 1.0 / k, None, True, minimum))
            except Cancelled:
                return ("cancelled", k)
            if gate is not None:
                gate.wait()
        return ("done", len(script))

    return work


def settle(run: Run, n: int | None = None, timeout: float = 10.0) -> None:
    """Wait until the run is paused (with ``n`` events when given) or finished."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not run.running or (run.paused and (n is None or len(run.events) == n)):
            return
        time.sleep(0.005)
    raise AssertionError(f"the run neither paused nor finished: {len(run.events)} events")


def test_step_mode_lets_exactly_one_event_through_then_pauses():
    run = Run(scripted(), mode="step").start()
    settle(run, 1)
    time.sleep(0.1)  # a paused run stays paused
    assert run.paused and len(run.events) == 1


@pytest.mark.parametrize("steps", [1, 3])
def test_each_step_lets_exactly_one_more_event_through(steps):
    run = Run(scripted(), mode="step").start()
    settle(run, 1)
    for k in range(steps):
        run.step()
        settle(run, 2 + k)
    time.sleep(0.1)
    assert run.paused and len(run.events) == 1 + steps
    run.cancel()
    run.join(5)
    assert run.result == ("cancelled", 1 + steps)  # cancelled at the event it paused on


def test_next_phase_stops_at_the_local_minimum_that_ends_an_icp_leg():
    run = Run(scripted(), mode="phase").start()
    settle(run)
    assert run.paused and len(run.events) == 3 and run.events[-1].local_minimum


def _annealing_leg_held_then_icp_to_the_end(run) -> None:
    """After Next phase into annealing's leg: it pauses holding ICP's next leg; Next phase runs that to the end."""
    settle(run, 7)
    time.sleep(0.1)  # the next leg's first event is held: the events end with annealing's last move
    assert run.paused and [(e.phase, e.leg) for e in run.events[-2:]] == [("sa", 1), ("sa", 1)]
    run.next_phase()  # the held event begins the leg Next phase runs: ICP's second leg, to the run's end
    run.join(5)
    assert [(e.phase, e.leg) for e in run.events[7:]] == [("icp", 2), ("icp", 2)]
    assert run.result == ("done", len(SCRIPT))


def test_next_phase_from_annealing_stops_where_the_next_leg_begins():
    run = Run(scripted(), mode="phase").start()
    settle(run, 3)
    run.step()  # the first annealing move
    settle(run, 4)
    run.next_phase()
    _annealing_leg_held_then_icp_to_the_end(run)


def test_next_phase_from_a_local_minimum_runs_the_next_leg_to_its_end():
    # paused where ICP stopped (the lesson's "annealing roams"): one click runs all of annealing's leg
    run = Run(scripted(), mode="phase").start()
    settle(run, 3)
    run.next_phase()
    _annealing_leg_held_then_icp_to_the_end(run)


def test_a_step_from_a_held_leg_start_lets_that_one_event_through():
    run = Run(scripted(), mode="phase").start()
    settle(run, 3)
    run.next_phase()  # annealing's leg, to where ICP's second begins
    settle(run, 7)
    run.step()
    settle(run, 8)
    time.sleep(0.1)
    assert run.paused and len(run.events) == 8 and run.events[-1].phase == "icp"
    run.cancel()
    run.join(5)


def test_resume_runs_to_the_end_and_reports_the_result():
    done = []
    run = Run(scripted(), mode="step", on_done=done.append).start()
    settle(run, 1)
    run.resume()
    run.join(5)
    assert not run.running and run.result == ("done", len(SCRIPT)) and len(run.events) == len(SCRIPT)
    assert done == [run] and run.failure is None


def test_pause_holds_a_running_run():
    gate = threading.Event()
    run = Run(scripted(gate=gate)).start()
    run.pause()  # while the optimiser is between events: the next event is recorded and held there
    gate.set()
    settle(run, 2)
    time.sleep(0.1)
    assert run.paused and len(run.events) == 2


def test_cancel_while_paused_ends_within_0_2_s_without_waiting_for_the_poll(monkeypatch):
    monkeypatch.setattr(runner, "POLL", 30.0)  # a cancel must wake the paused worker, not wait for its next look
    run = Run(scripted(), mode="step").start()
    settle(run, 1)
    t0 = time.monotonic()
    run.cancel()
    run.join(5)
    assert not run.running and time.monotonic() - t0 < 0.2
    assert run.result == ("cancelled", 1)


def test_a_failing_optimiser_is_reported_not_raised():
    def work(listener):
        raise ValueError("boom")

    done = []
    run = Run(work, on_done=done.append).start()
    run.join(5)
    assert isinstance(run.failure, ValueError) and run.result is None and done == [run]
