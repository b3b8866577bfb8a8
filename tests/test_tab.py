"""The tab's state, its threading contract and the refresher (app/tab/), without a browser."""

from __future__ import annotations

import logging
import re
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
from rangereg.app.tab import refresher as refresher_module
from rangereg.app.tab.refresher import Refresher
from rangereg.app.tab.state import TabState
from rangereg.core.errors import InputError


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


def test_closing_a_tab_ends_its_run_and_its_slice():
    from rangereg.app.runner import Run

    from tests.test_runner import scripted, settle

    st = TabState()
    st.run = Run(scripted(), mode="step").start()
    settle(st.run, 1)
    st.slice_cancel = threading.Event()
    st.cancel_work()  # what Tab.close does when the browser tab goes away
    st.run.join(5)
    assert st.slice_cancel.is_set() and not st.running and st.run.result == ("cancelled", 1)


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


# ---- the page's settings, uploads and slices (hardening) ---------------------------------------------


def settings_handles(**typed):
    """The page's settings widgets as first drawn, with ``typed`` (by app.options.Settings field) typed over them."""
    from rangereg.app.tab.settings import FRUSTUM, NUMBERS, SettingsHandles

    numbers = {name: f.initial for name, f in NUMBERS.items()} | {k: v for k, v in typed.items() if k in NUMBERS}
    rest = dict(frustum=FRUSTUM, coarse_to_fine=False, polish=False, lock="", no_guess=False) | {k: v for k, v in typed.items()
                                                                                 if k not in NUMBERS}
    return SettingsHandles(numbers={k: SimpleNamespace(value=v) for k, v in numbers.items()},
                           **{k: SimpleNamespace(value=v) for k, v in rest.items()})


def test_the_annealing_settings_reach_annealing_alone():
    from rangereg.app.tab.settings import page_config, read_settings

    for method in ("sa", "hybrid"):
        cfg = page_config(read_settings(settings_handles(t_min_ratio="0.05", cooling="0.8")), method)
        assert cfg.sa_alone.t_min_ratio == cfg.anneal.t_min_ratio == 0.05
        assert cfg.sa_alone.cooling == cfg.anneal.cooling == 0.8


def test_the_pages_uncertainty_fields_and_no_guess_reach_the_run(scene):
    import numpy as np
    from rangereg.app.tab.settings import guess_text, page_guess, read_settings

    typed = read_settings(settings_handles(rotation_uncertainty="60", translation_uncertainty="25"))
    for method in ("global", "hybrid"):
        g = page_guess(typed, np.eye(4), method)
        assert (g.rotation_deg, g.translation) == (60.0, 25.0)
    nothing = read_settings(settings_handles(rotation_uncertainty="60", no_guess=True))
    g = page_guess(nothing, np.eye(4), "global")
    assert (g.rotation_deg, g.translation) == (180.0, None) and g.is_none  # Run global: no guess
    assert page_guess(nothing, np.eye(4), "hybrid").rotation_deg == 60.0  # the paper's keep their region
    source, target = scene("corner")

    assert guess_text(nothing, np.eye(4), source, target).startswith("no guess")
    assert guess_text(typed, np.eye(4), source, target).startswith("60 deg, ")
    with pytest.raises(InputError, match="^Rotation uncertainty"):
        read_settings(settings_handles(rotation_uncertainty="200"))


@pytest.mark.parametrize("method", ["sa", "hybrid", "icp", "icp-restarts", "basin-hopping", "global"])
def test_a_run_button_on_the_pages_first_settings_runs_what_register_runs(method):
    # as first drawn, the page's settings and register's defaults make one config: the same method from the same
    # settings (annealing alone keeps its own cooling and stop, not the hybrid's)
    from rangereg.app.cli import build_parser
    from rangereg.app.commands.pair import config
    from rangereg.app.tab.settings import page_config, read_settings

    page = page_config(read_settings(settings_handles()), method)
    cli = config(build_parser().parse_args(["register", "a.ply", "b.ply", "--method", method]))
    assert page == cli
    if method == "sa":
        assert page.sa_alone.cooling != page.anneal.cooling  # each keeps its own: the page does not copy one over


@pytest.mark.parametrize("field, typed, says", [
    ("t_start", "inf", "^Start temperature: "), ("t_start", "0", "^Start temperature: "),
    ("t_min_ratio", "1", "^Minimum temperature ratio: "), ("cooling", "12,5", "^Cooling: .*comma"),
    ("cooling", "1.5", "^Cooling: must be > 0 and < 1"), ("seed", "1e30", "^Seed: "), ("seed", "-1", "^Seed: "),
    ("seed", "2.5", "^Seed: "), ("seed", str(2**40), "^Seed: must be .*<= 4294967295"),
    ("icp_max_iterations", "0", "^ICP iteration cap: "), ("icp_max_iterations", "200000", "^ICP iteration cap: "),
    ("sa_max_evaluations", "6", "^SA evaluation cap: "), ("sa_max_evaluations", "100000000", "^SA evaluation cap: "),
    ("max_points", "2", "^Overlap sample size: "), ("max_points", "1000000", "^Overlap sample size: "),
    ("threshold", "-1", "^Threshold: "), ("threshold", "banana", "^Threshold: "),
    ("lock", "rx,rq", "^Locked parameters: .*rq"),
])
def test_a_bad_setting_is_refused_with_the_pages_name_for_it_not_clamped(field, typed, says):
    # the bounds are app.options.KNOBS', the CLI's: a value the page takes, to_config takes too
    from rangereg.app.tab.settings import read_settings

    with pytest.raises(InputError, match=says):
        read_settings(settings_handles(**{field: typed}))


def test_settings_are_read_as_typed():
    from rangereg.app.tab.settings import read_settings

    s = read_settings(settings_handles(t_start="2.5e-3", t_min_ratio="1e-3", seed="12"))
    assert (s.t_start, s.t_min_ratio, s.seed) == (2.5e-3, 1e-3, 12)


@pytest.mark.parametrize("name", ["..", "../../etc/passwd", "a/../../b.ply", "/var/x.ply", "..\\..\\x.ply", ".", ""])
def test_an_upload_name_never_puts_a_server_path_in_the_message(name):
    import tempfile

    from rangereg.app.tab.scans import load_upload

    with pytest.raises(InputError) as refused:
        load_upload(name, b"not a scan")
    assert tempfile.gettempdir() not in str(refused.value)


def test_an_upload_with_a_path_in_its_name_still_loads(tmp_path):
    from rangereg.app.tab.scans import load_upload

    from tests.conftest import ASSETS

    scan = load_upload("some/dir/scan1.ply", (ASSETS / "corner" / "scan1.ply").read_bytes())
    assert scan.name == "scan1" and len(scan.points) > 100 and scan.source == "upload:some/dir/scan1.ply"


def test_a_cancelled_slice_stops_within_a_row():
    from rangereg.app.tab.landscape import compute
    from rangereg.core.io import load_scan
    from rangereg.core.problem import prepare, relative_guess

    from tests.conftest import ASSETS

    src, tgt = load_scan(ASSETS / "corner" / "scan1.ply"), load_scan(ASSETS / "corner" / "scan2.ply")
    T = relative_guess(src, tgt)
    problem = prepare(src, tgt, T)
    cancel, rows = threading.Event(), []

    def progress(fraction):
        rows.append(fraction)
        cancel.set()  # as if Cancel (or closing the tab) came during the first row

    assert compute(problem, T, ("tx", "ry"), (1.0, 1.0), 201, cancel, progress) is None
    assert len(rows) == 1
    assert compute(problem, T, ("tx", "ry"), (1.0, 1.0), 3, threading.Event()).values.shape == (3, 3)


def test_a_reset_drops_the_outcome_of_the_run_it_cancelled():
    """Reset cancels the run and forgets it: the cancelled run's result, handed over later, must not bring it back."""
    from rangereg.app.runner import Run
    from rangereg.app.tab.run import RunPanel

    from tests.test_runner import scripted, settle

    st = TabState()
    panel = RunPanel.__new__(RunPanel)  # only the hand-over, no page
    panel.state, panel.tab = st, SimpleNamespace(notify=lambda *a, **k: None)
    st.run = run = Run(scripted(), mode="step", on_done=panel._done).start()
    st.events = run.events
    settle(run, 1)
    run.cancel()
    run.join(5)
    st.reset_run()  # what Reset does once the run has ended
    st.apply_handed()
    assert st.finished_text == "" and st.result is None


def test_a_moving_scan_is_drawn_by_a_subset_of_larger_points():
    """While a run moves the scan, each cloud is drawn by RUN_POINTS of its points, as large as their spacing
    (capped): software WebGL pays per point drawn, not per pixel of a point."""
    import numpy as np
    import viser
    from rangereg.app.access import free_port
    from rangereg.app.tab import scene3d
    from rangereg.app.views import Display
    from rangereg.core.frustum import frustum_of
    from rangereg.core.io import load_scan
    from rangereg.core.surface import Surface

    from tests.conftest import ASSETS

    source, target = (load_scan(ASSETS / "corner" / f"scan{k}.ply") for k in (2, 1))
    state = SimpleNamespace(pair=0, display=Display(target, source), residual_rgb=None, source=source, target=target,
                            problem=None, frusta={"convex": (frustum_of(source, "convex"), frustum_of(target, "convex"))},
                            surfaces=(Surface.from_scan(source), Surface.from_scan(target)))
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        n = len(source.points)
        assert n > scene3d.RUN_POINTS
        cloud = scene3d._cloud(server.scene, state, "source", state.display.source_local(source.points), 0.01,
                               "convex", False)
        assert len(cloud.points.points) == n and len(cloud.light.points) == scene3d.RUN_POINTS
        assert len(np.unique(cloud.light_index)) == scene3d.RUN_POINTS
        grow = min(scene3d.LIGHT_SIZE_MAX, np.sqrt(n / scene3d.RUN_POINTS))
        assert grow > 1 and cloud.light.point_size == pytest.approx(grow * cloud.points.point_size)
        assert cloud.points.visible and not cloud.light.visible  # the subset is drawn only while a run moves the scan
    finally:
        server.stop()


def test_the_finished_line_leads_with_trust_and_advises_only_when_not_trusted(scene):
    import numpy as np
    from rangereg.app.tab.run import page_advice, result_line
    from rangereg.core.guess import Guess
    from rangereg.core.result import GlobalDetails, Iterations, Result, Stop, StopReason, Verdict
    from rangereg.core.threshold import pair_threshold

    source, target = scene("corner")
    region = Guess.identity().region(source, target)

    def result(trusted, beyond=""):
        d = GlobalDetails(region, not beyond, beyond, 0.1, 3, {}, "guess")
        return Result(np.eye(4), 0.1, Iterations(3), 0, 3, 0.1, "global", 1.0, Stop(StopReason.TRUSTED),
                      trusted=trusted, verdict=Verdict(pair_threshold(1.0, 2.0, 0.1), 1.0, holds=trusted), details=d)

    # trusted, even beyond the stated region (the trust text says so): no advice
    assert page_advice(result(True)) == "" and page_advice(result(True, "found 40 deg beyond")) == ""
    assert "Settings" in page_advice(result(False)) and "--" not in page_advice(result(False))
    assert "drag the gizmo" in page_advice(result(False))
    hybrid = Result(np.eye(4), 0.1, Iterations(3), 0, 3, 0.1, "hybrid", 1.0, Stop(StopReason.BELOW_THRESHOLD))
    assert page_advice(hybrid) == ""
    stuck = Result(np.eye(4), 5.0, Iterations(3), 0, 3, 0.1, "hybrid", 1.0, Stop(StopReason.ICP_ABOVE_THRESHOLD))
    assert page_advice(stuck).startswith("Run global")  # the paper's methods search round the pose only
    for r, trusted in ((result(True, "found 40 deg beyond"), True), (result(False), False), (stuck, False)):
        line = result_line(r, "mm", (1.0, 2.0))
        assert line.startswith(f"<b>Finished: trust {'yes' if trusted else 'no'}</b>")
        assert ("What to do" in line) is not trusted and "from the truth" in line


def test_a_cancelled_runs_line_leads_with_the_cancel_not_a_verdict():
    import numpy as np
    from rangereg.app.tab.run import result_line
    from rangereg.core.result import GlobalDetails, Iterations, Result, Stop, StopReason, Verdict
    from rangereg.core.threshold import pair_threshold

    cancel = Stop(StopReason.CANCELLED)
    hybrid = Result(np.eye(4), 5.0, Iterations(12, 30), 1, 50, 0.5, "hybrid", 1.0, cancel)
    line = result_line(hybrid, "mm", (1.0, 2.0))
    assert line.startswith("<b>Cancelled at iteration 42</b>: E = 5 mm², the best pose so far (not trusted)<br>"), line
    assert "ICP 12, SA 30" in line and "from the truth" in line
    assert "Finished" not in line and "trust" not in line.replace("not trusted", "") and "What to do" not in line
    low = Result(np.eye(4), 0.5, Iterations(3), 0, 3, 0.1, "icp", 1.0, cancel)  # below the threshold, still cancelled
    assert result_line(low).startswith("<b>Cancelled at iteration 3</b>")
    # the global method gives back its initial pose when cancelled: the line says so
    d = GlobalDetails(None, True, "", 0.1, 0, {"guess": 1}, "guess")
    glob = Result(np.eye(4), 9.0, Iterations(4, 0, 7), 0, 20, 0.3, "global", 1.0, cancel, trusted=False,
                  verdict=Verdict(pair_threshold(1.0, 2.0, 0.1), None), details=d)
    line = result_line(glob, "m")
    assert line.startswith("<b>Cancelled at iteration 11</b>: E = 9 m², the initial pose kept (not trusted)<br>"), line
    assert "candidates 7" in line


def test_the_campaigns_overall_pairs_line_leads_its_progress_and_its_report():
    from rangereg.app.tab.model import CampaignLines
    from rangereg.core.merge_progress import MergeProgress, Step

    lines = CampaignLines()
    assert lines.text() == ""
    lines.add(MergeProgress(Step.FEATURES, 0, 4, 4, 1.0))
    assert lines.text() == "features 4/4, 0:01 elapsed, done"  # no pair counted yet: the newest lines alone
    events = [MergeProgress(Step.PAIRS, 1, 0, 6, 1.0, note="registering 6 pairs"),
              MergeProgress(Step.PAIRS, 1, 1, 6, 2.0), MergeProgress(Step.PAIRS, 1, 3, 6, 3.0),
              MergeProgress(Step.PAIRS, 1, 6, 6, 9.0), MergeProgress(Step.GRAPH, 1, 1, 1, 9.0, note="5 of 6 pairs used"),
              "a task runner's line", MergeProgress(Step.OVERLAPS, 1, 1, 1, 9.5),
              MergeProgress(Step.PAIRS, 2, 6, 8, 10.0, note="registering 2 pairs"), MergeProgress(Step.PAIRS, 2, 7, 8, 12.0)]
    for e in events:
        lines.add(e)
        shown = lines.text().split("  \n")
        counts = [line for line in shown if re.match(r"pairs, round \d+ \d+/\d+", line)]
        # the overall line, the newest count of the pairs, is first and alone; every other line is under it
        assert len(counts) <= 1 and (not counts or shown[0] == counts[0]), shown
        assert len(shown) <= 1 + CampaignLines.KEEP
    shown = lines.text().split("  \n")
    assert shown[0] == "pairs, round 2 7/8, 0:12 elapsed, ETA unknown", shown
    assert shown[1:] == ["pairs, round 1: registering 6 pairs", "graph, round 1: 5 of 6 pairs used", "a task runner's line",
                         "overlaps, round 1 1/1, 0:10 elapsed, done", "pairs, round 2: registering 2 pairs"]
    report = lines.report("**4 of 4 scans placed** · 5 of 6 pairs used  \nbun000: placed").split("  \n")
    assert report == ["pairs, round 2 7/8, 0:12 elapsed, ETA unknown", "**4 of 4 scans placed** · 5 of 6 pairs used",
                      "bun000: placed"]


def test_one_campaign_at_a_time_and_a_runs_end_does_not_free_its_buttons():
    from rangereg.app.tab.model import ModelPanel

    st = TabState()
    button = lambda: SimpleNamespace(disabled=False)  # noqa: E731
    campaign = SimpleNamespace(scans=SimpleNamespace(value="*"), rotation=SimpleNamespace(value=15.0),
                               merge=button(), progress=SimpleNamespace(content=""))
    panel = ModelPanel.__new__(ModelPanel)  # the panel's logic on stand-in handles (no server)
    panel.state, panel.h = st, SimpleNamespace(merge=button(), show=button(), campaign=campaign)
    panel.tab = SimpleNamespace(wb=SimpleNamespace(data_files=lambda: ["a.ply", "b.ply"]),
                                run_panel=SimpleNamespace(settings=lambda: SimpleNamespace(seed=0)))
    with st.lock:
        st.campaign_busy = True  # a campaign is working (set under the lock by start_campaign)
    with pytest.raises(InputError, match="campaign merge is working"):
        panel.start_campaign()
    panel.lock(False)  # a run ends: the campaign's buttons stay held
    assert campaign.merge.disabled and panel.h.merge.disabled
    from rangereg.app.tab.model import _campaign_over

    st.hand(_campaign_over, panel._unlock)  # the campaign's worker hands its end to the owner
    for then in st.apply_handed():
        then()
    assert not st.campaign_busy and not campaign.merge.disabled and not panel.h.merge.disabled
    # a campaign that starts holds the tab until its worker hands back its end, a failure too
    said, gate = [], threading.Event()

    def load(name):
        gate.wait(5)
        raise InputError(f"{name}: unreadable")

    panel.tab.wb.load_data_file = load
    panel.tab.notify = lambda title, text, error=True: said.append(text)
    panel.start_campaign()
    assert st.campaign_busy and campaign.merge.disabled and panel.h.merge.disabled
    with st.lock:
        st.source = object()  # a pair is open
    with pytest.raises(InputError, match="campaign merge is working"):
        panel.start()  # the two-scan merge waits too (the campaign's end sets the model)
    gate.set()
    deadline = time.monotonic() + 5
    while not st._handed and time.monotonic() < deadline:
        time.sleep(0.01)
    assert st.campaign_busy  # the worker never writes the state itself
    for then in st.apply_handed():
        then()
    assert not st.campaign_busy and not campaign.merge.disabled and said == ["a.ply: unreadable"]


LIDAR = Path(__file__).resolve().parents[2] / "shared" / "data" / "lidar"


@pytest.mark.skipif(not (LIDAR / "251370668.pcd").exists(), reason="the shared LiDAR frames are absent")
def test_a_panorama_is_drawn_with_its_sensor_named_and_a_large_cloud_by_a_subset(monkeypatch):
    """A panorama has no frustum to show where its sensor stood: its viewpoint carries the sensor's axes and a label;
    a cloud beyond DRAW_POINTS is drawn by a seeded subset at rest, recoloured through the same indices."""
    import numpy as np
    import viser
    from rangereg.app.access import free_port
    from rangereg.app.tab import scene3d
    from rangereg.app.views import Display
    from rangereg.core.frustum import frustum_of
    from rangereg.core.io import load_scan
    from rangereg.core.scan import ScanKind
    from rangereg.core.surface import Surface

    target, source = (load_scan(LIDAR / f"{n}.pcd") for n in (251370668, 251371071))
    assert source.kind is ScanKind.PANORAMA and target.kind is ScanKind.PANORAMA
    state = SimpleNamespace(pair=0, display=Display(target, source), residual_rgb=None, source=source, target=target,
                            problem=None, frusta={"convex": (frustum_of(source, "convex"), frustum_of(target, "convex"))},
                            surfaces=(Surface.from_scan(source), Surface.from_scan(target)))
    monkeypatch.setattr(scene3d, "DRAW_POINTS", 20_000)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        cloud = scene3d._cloud(server.scene, state, "source", state.display.source_local(source.points), 0.01,
                               "convex", False)
        names = set(server.scene._handle_from_node_name)
        root = cloud.root
        assert {f"{root}/viewpoint", f"{root}/viewpoint/axes", f"{root}/viewpoint/label"} <= names
        assert len(cloud.frustum_segments) == 0  # nothing a frustum would draw
        assert len(cloud.points.points) == 20_000 == len(np.unique(cloud.drawn_index))
        full = np.zeros((len(source.points), 3), np.uint8)
        full[cloud.drawn_index[0]] = (1, 2, 3)
        monkeypatch.setattr(scene3d, "colours", lambda *a: full)
        scene3d.recolour(SimpleNamespace(target=cloud, source=cloud), state, False)
        assert tuple(cloud.points.colors[0]) == (1, 2, 3) and len(cloud.points.colors) == 20_000
    finally:
        server.stop()


def test_viewpoint_fields_show_4_digits_and_a_field_left_as_shown_keeps_the_exact_viewpoint(bunny):
    import re

    import numpy as np
    from rangereg.app.tab.scans import ScansPanel

    source, target = bunny("bun045"), bunny("bun000")
    panel = SimpleNamespace(h=SimpleNamespace(vp_source=SimpleNamespace(value="0 0 0"),
                                              vp_target=SimpleNamespace(value="0 0 0")), vp_shown={})
    ScansPanel.show_viewpoints(panel, source, target)
    for field, scan in ((panel.h.vp_source, source), (panel.h.vp_target, target)):
        shown = field.value.split()
        assert len(shown) == 3 and all(len(re.sub(r"\D", "", v.split("e")[0]).lstrip("0")) <= 4 for v in shown), shown
        assert np.allclose([float(v) for v in shown], scan.viewpoint, rtol=1e-3, atol=1e-12)
        # Apply with the field as shown: the exact viewpoint, not its 4 digits (the scan is not moved)
        assert np.array_equal(ScansPanel._viewpoint(panel, field, "viewpoint"), scan.viewpoint)
    panel.h.vp_source.value = "0.1 0.2 1.5"  # typed: taken as typed
    assert np.array_equal(ScansPanel._viewpoint(panel, panel.h.vp_source, "source viewpoint"), [0.1, 0.2, 1.5])


def test_the_tabs_actions_run_one_at_a_time_in_the_order_of_the_clicks():
    # viser awaits a coroutine callback on its event loop in the order the messages came (a plain one goes to a pool
    # of 32 threads, where a Reset and the Run clicked after it started in either order); the action only queues
    import asyncio
    import inspect

    from rangereg.app.tab.actions import Actions

    seen, notes, closed = [], [], [False]

    def guarded(fn, *args):  # as the tab's: bad input is said, not raised
        try:
            fn(*args)
        except InputError as exc:
            notes.append(str(exc))

    actions = Actions(guarded, lambda: closed[0])

    def reset():
        time.sleep(0.3)  # a Reset that takes a while (cancelling a run, re-cutting the overlap)
        seen.append("reset")

    def refused():
        raise InputError("a run holds the scans")

    run = actions.callback(seen.append, "run")
    callbacks = [actions.callback(reset), run, run, actions.callback(refused),
                 actions.callback(seen.append, event=lambda e: (e,))]
    assert all(inspect.iscoroutinefunction(cb) for cb in callbacks)

    async def clicks():
        t0 = time.monotonic()
        for cb in callbacks:
            await cb("the event")
        return time.monotonic() - t0

    assert asyncio.run(clicks()) < 0.1  # the event loop never waits for an action
    actions.close(drain=True)
    closed[0] = True  # the browser tab went away (Tab.close): a late click is dropped, not an error
    asyncio.run(run("a late click"))
    # in order; the second Run, clicked while the first still waited, was that one (a double click, a drag's burst)
    assert seen == ["reset", "run", "the event"] and notes == ["a run holds the scans"]
