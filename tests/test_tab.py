"""The tab's state, its threading contract and the refresher (app/tab/), without a browser."""

from __future__ import annotations

import logging
import threading
import time
from types import SimpleNamespace

import pytest

from app.tab import refresher as refresher_module
from app.tab.refresher import Refresher
from app.tab.state import TabState
from core.errors import InputError


def test_worker_results_are_applied_by_the_owner_under_the_lock_in_order():
    st = TabState()
    seen = []

    def apply(s):
        # the lock is held by the applying thread (an RLock: a re-entrant acquire succeeds at once)
        assert s.lock.acquire(blocking=False)
        s.lock.release()
        seen.append(("apply", s.finished_text))
        s.finished_text = "done"

    worker = threading.Thread(target=lambda: st.hand(apply, lambda: seen.append(("then", st.finished_text))))
    worker.start()
    worker.join()
    assert st.finished_text == "" and seen == []  # a worker never writes the state itself
    for then in st.apply_handed():
        then()
    assert seen == [("apply", ""), ("then", "done")] and st.apply_handed() == []


def test_one_reset_forgets_the_run():
    st = TabState()
    st.events, st.finished_text, st.result = [1, 2], "Finished", object()
    st.reset_run()
    assert (st.events, st.finished_text, st.result) == ([], "", None)


def test_a_tab_without_scans_refuses_work_with_a_reason():
    with pytest.raises(InputError, match="open two scans"):
        TabState().require_scans()


def test_cancel_work_stops_the_slice():
    st = TabState()
    st.slice_cancel = threading.Event()
    st.cancel_work()
    assert st.slice_cancel.is_set()


def test_the_refresher_logs_a_failing_tick_and_keeps_going(monkeypatch, caplog):
    monkeypatch.setattr(refresher_module, "REFRESH", 0.001)
    monkeypatch.setattr(refresher_module.time, "sleep", lambda s: time.perf_counter())  # no back-off in the test
    st = TabState()
    r = Refresher(SimpleNamespace(state=st, client=SimpleNamespace(client_id=7)))
    ticks = []

    def tick():
        ticks.append(1)
        if len(ticks) == 1:
            raise RuntimeError("a bug in a push")
        if len(ticks) == 3:
            st.closed = True

    r.tick = tick
    with caplog.at_level(logging.ERROR, logger="rangereg.workbench"):
        r._loop()
    assert len(ticks) == 3 and r.failures == 1
    assert "a bug in a push" in caplog.text and "client 7" in caplog.text
