"""A trace file's header: what the run was (both scans by content, the guess, every knob, the seed, the
version), read back, and a trace of other scans refused by ``slice --trace``, ``serve --trace`` and the
page's replay, while a trace without a header is still drawn."""

from __future__ import annotations

import json
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from rangereg.app.cli import main
from rangereg.core.config import Config
from rangereg.core.errors import InputError
from rangereg.core.events import Event
from rangereg.core.io import load_scan
from rangereg.core.problem import prepare, relative_guess
from rangereg.core.trace import NO_HEADER, TRACE_VERSION, ScanPrint, TraceHeader, read_trace

from tests.conftest import ASSETS, run_cli

CORNER = ASSETS / "corner" / "scan2.ply", ASSETS / "corner" / "scan1.ply"
WING = ASSETS / "wing" / "scan2.ply", ASSETS / "wing" / "scan1.ply"


@pytest.fixture(scope="module")
def corner_trace(tmp_path_factory):
    """(trace path, register's --json result) of a seeded hybrid run on the corner."""
    path = tmp_path_factory.mktemp("trace") / "run.jsonl"
    code = main(["register", *map(str, CORNER), "--method", "hybrid", "--seed", "2", "--json", "--trace", str(path)])
    assert code == 0
    return path


def lines(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def old_style(path) -> str:
    """The trace as rangereg wrote it before headers: its events alone."""
    return "".join(line + "\n" for line in path.read_text().splitlines()[1:-1])


def test_the_header_is_the_first_line_and_says_what_the_run_was(corner_trace):
    header = lines(corner_trace)[0]["header"]
    assert header["format"] == "rangereg-trace" and header["format_version"] == TRACE_VERSION
    source = load_scan(CORNER[0])
    assert header["source"] == {"path": str(CORNER[0]), "name": "scan2", "points": len(source.points),
                                "sha256": ScanPrint.of(source).sha256}
    assert header["method"] == "hybrid" and header["seed"] == 2 and header["rangereg"]
    assert header["config"]["seed"] == 2 and header["config"]["guess"]["rotation_deg"] == 15.0
    target = load_scan(CORNER[1])
    assert np.allclose(header["T_init"], relative_guess(source, target))  # the guess the run started from
    trace = read_trace(corner_trace.read_text(), "run.jsonl")
    assert trace.header.method == "hybrid" and np.array_equal(trace.start, np.array(header["T_init"]))
    assert len(trace.events) == len(lines(corner_trace)) - 2 and "scan2 (6634 points)" in repr(trace)
    assert np.array_equal(trace.end, np.array(lines(corner_trace)[-1]["result"]["transform"]))


def test_a_header_reads_back_as_written():
    source, target = (load_scan(p) for p in CORNER)
    from rangereg.app.options import Settings, to_config

    cfg = to_config(Settings(method="global", seed=5, lock="rx"))
    h = TraceHeader.of(source, target, np.eye(4), cfg, "a.ply", "b.ply")
    back = TraceHeader.from_json(json.loads(json.dumps(h.to_json())))
    assert (back.source, back.target, back.method, back.seed, back.version) == (h.source, h.target, "global", 5, h.version)
    assert back.config == h.config and back.config["lock"]["locked"] == ["rx"] and np.array_equal(back.T_init, np.eye(4))
    assert back.differences(np.eye(4), cfg) == []
    assert back.differences(np.eye(4), to_config(Settings(method="global", seed=6))) == [
        "lock.locked ['rx'] (here [])", "seed 5 (here 6)"]


def test_register_then_slice_draws_the_same_run_from_its_guess_to_its_final_pose(rangereg, corner_trace, tmp_path):
    code, out, err = rangereg("register", *CORNER, "--method", "hybrid", "--seed", "2", "--json")
    assert code == 0, err
    final = np.array(json.loads(out)["transform"])
    *events, result = lines(corner_trace)[1:]
    assert np.array_equal(result["result"]["transform"], final)  # the closing line: the pose the run returned
    assert any(np.array_equal(e["transform"], final) for e in events)  # one the run went through
    npz = tmp_path / "s.npz"
    code, out, err = rangereg("slice", *CORNER, "--params", "tx,ry", "--steps", "5", "--trace", corner_trace,
                              "--center", "end", "--png", tmp_path / "s.png", "--npz", npz)
    assert code == 0 and err == "", err
    assert "trace: scan2 -> scan1, method hybrid, seed 2" in out and "differs" in out  # slice's seed is 0
    data = np.load(npz)
    assert np.array_equal(data["center"], final) and len(data["path"]) == len(events) + 1
    code, out, err = rangereg("slice", *CORNER, "--params", "tx,ry", "--steps", "3", "--trace", corner_trace,
                              "--png", tmp_path / "s.png", "--npz", npz)
    data = np.load(npz)  # around the guess: the path starts there (the header's T_init)
    assert code == 0 and np.allclose(data["center"], lines(corner_trace)[0]["header"]["T_init"])
    assert np.allclose(data["path"][0], [0.0, 0.0])


def test_a_renamed_copy_of_the_scans_is_the_same_pair(rangereg, corner_trace, tmp_path):
    for src, name in zip(CORNER, ("a", "b"), strict=True):
        shutil.copy(src, tmp_path / f"{name}.ply")
        shutil.copy(src.with_suffix(".json"), tmp_path / f"{name}.json")
    code, out, err = rangereg("slice", tmp_path / "a.ply", tmp_path / "b.ply", "--steps", "3", "--trace", corner_trace,
                              "--png", tmp_path / "s.png")
    assert code == 0, err


@pytest.mark.parametrize("scans, edit, said", [
    (WING, None, "was recorded on other scans: its source is scan2 (6634 points) from"),
    (CORNER[::-1], None, "these scans are the other way round"),
    (CORNER, "sha256", "its target is scan1 (6550 points)"),  # same count, other content (an edited file)
])
def test_slice_refuses_a_trace_of_other_scans_in_one_line(rangereg, corner_trace, tmp_path, scans, edit, said):
    trace = corner_trace
    if edit:
        rows = lines(corner_trace)
        rows[0]["header"]["target"]["sha256"] = "0" * 64
        trace = tmp_path / "edited.jsonl"
        trace.write_text("".join(json.dumps(r) + "\n" for r in rows))
    code, out, err = rangereg("slice", *scans, "--steps", "3", "--trace", trace, "--png", tmp_path / "s.png")
    assert code == 2 and out == "" and err.count("\n") == 1 and said in err, err
    assert not (tmp_path / "s.png").exists()


def test_a_real_process_refuses_a_mismatched_trace_with_one_line_and_no_traceback(corner_trace, tmp_path):
    r = run_cli("slice", *WING, "--steps", "3", "--trace", corner_trace, "--png", tmp_path / "s.png", timeout=120)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "recorded on other scans" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("text, said", [
    ("x y z\n1 2 3\n", "line 1 is not JSON: not a rangereg trace"),
    ('{"header": {"format": "rangereg-trace", "format_version": 99, "rangereg": "9"}}\n', "newer rangereg"),
    ('{"header": {"format": "something-else"}}\n', "not a rangereg-trace header"),
    ('{"header": {"format": "rangereg-trace", "format_version": 1}}\n', "a header without 'source'"),
    ("[1, 2, 3]\n", "a JSON object expected"),
    ("[" * 100_000 + "]" * 100_000 + "\n", "line 1 is not JSON"),  # nested past Python's stack
])
def test_a_file_that_is_not_a_trace_is_one_message_naming_its_line(text, said):
    with pytest.raises(InputError, match=said):
        read_trace(text, "bad.jsonl")


def test_a_header_only_on_the_first_line(corner_trace):
    rows = lines(corner_trace)
    text = "".join(json.dumps(r) + "\n" for r in [*rows[:3], rows[0]])
    with pytest.raises(InputError, match="line 4 .*first line only"):
        read_trace(text, "twice.jsonl")


def test_an_old_trace_without_a_header_is_still_drawn_and_says_it_could_not_be_checked(rangereg, corner_trace,
                                                                                          tmp_path):
    old = tmp_path / "old.jsonl"
    old.write_text(old_style(corner_trace))
    npz = tmp_path / "s.npz"
    code, out, err = rangereg("slice", *CORNER, "--steps", "3", "--trace", old, "--png", tmp_path / "s.png",
                              "--npz", npz)
    assert code == 0 and NO_HEADER in out, err
    assert len(np.load(npz)["path"]) == len(lines(old)) + 1


# ---- the page: replay's loading (app/tab/replay.py) and serve --trace (app/workbench.py)

@pytest.fixture(scope="module")
def panel():
    """A Replay panel on a real viser GUI (no browser) over a tab state holding the corner pair."""
    import viser
    from rangereg.app.access import free_port
    from rangereg.app.tab.replay import ReplayPanel
    from rangereg.app.tab.state import TabState

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    st = TabState()
    st.source, st.target = (load_scan(p) for p in CORNER)
    st.T_init = relative_guess(st.source, st.target)
    st.problem = prepare(st.source, st.target, st.T_init, seed=0)
    said = []

    def guarded(fn, *args):
        try:
            fn(*args)
        except InputError as exc:
            said.append(("Not done", str(exc)))

    def action(fn, *args, event=None):  # Tab.action's callback, run at once (no click order to keep here)
        return lambda e: guarded(fn, *args, *(event(e) if event else ()))

    tab = SimpleNamespace(gui=server.gui, state=st, nodes=None, said=said, guarded=guarded, action=action,
                          notify=lambda title, body, error=True: said.append((title, body)))
    yield ReplayPanel(tab)
    server.stop()


def test_the_page_refuses_a_trace_of_other_scans_and_stays_as_it_was(panel, tmp_path):
    st, said = panel.state, panel.tab.said
    said.clear()
    source, target = (load_scan(p) for p in WING)
    rows = [TraceHeader.of(source, target, np.eye(4), Config(method="icp")).to_json(),
            Event("icp", 1, 1, 1, np.eye(4), 1.0).to_json()]
    content = "".join(json.dumps(r) + "\n" for r in rows).encode()
    panel.tab.guarded(panel.load_trace, "wing.jsonl", content)
    n = [len(s.points) for s in (source, target, st.source, st.target)]
    assert said == [("Not done", f"wing.jsonl was recorded on other scans: its source is scan2 ({n[0]} points) from "
                     f"{WING[0]}, this source is scan2 ({n[2]} points) from {CORNER[0]}; its target is scan1 ({n[1]} "
                     f"points) from {WING[1]}, this target is scan1 ({n[3]} points) from {CORNER[1]}")]
    assert st.events == [] and panel.events == [] and panel.trace is None
    panel.tab.guarded(panel.load_trace, "words.txt", b"just words\n")
    assert "not a rangereg trace" in said[-1][1] and st.events == []


def test_the_page_replays_a_trace_of_its_scans_and_shows_its_method_seed_and_guess(panel, corner_trace):
    st, said = panel.state, panel.tab.said
    said.clear()
    panel.tab.guarded(panel.load_trace, "run.jsonl", corner_trace.read_bytes())
    assert said[-1][0] == "Trace loaded", said
    n = len(lines(corner_trace)) - 2
    assert len(st.events) == n and panel.slider.max == n and panel.trace.header.seed == 2
    assert "Trace **run.jsonl**: method hybrid, seed 2" in panel.info.content
    assert "its guess is this page's" in panel.info.content
    st.T_init = np.eye(4)  # another guess on the page: the trace is still of these scans, and says how far its guess is
    panel.describe(1)
    assert "deg" in panel.info.content and "from this page's" in panel.info.content
    assert np.array_equal(panel.start(), panel.trace.header.T_init)  # event 0 is where the traced run began
    st.T_init = relative_guess(st.source, st.target)


def test_the_page_replays_an_old_trace_checked_by_its_error(panel, corner_trace):
    said = panel.tab.said
    said.clear()
    old = old_style(corner_trace)
    panel.tab.guarded(panel.load_trace, "old.jsonl", old.encode())
    assert said[-1][0] == "Trace loaded" and NO_HEADER in said[-1][1]
    assert NO_HEADER in panel.info.content and panel.trace.header is None


def test_serve_refuses_a_trace_of_other_scans_before_it_listens(corner_trace):
    from rangereg.app.workbench import ServeOptions, Workbench

    with pytest.raises(InputError, match="recorded on other scans"):
        Workbench(ServeOptions(source=str(WING[0]), target=str(WING[1]), trace=str(corner_trace), port=1))


def test_the_page_exports_a_trace_with_its_header_that_replays_on_these_scans(panel, corner_trace):
    from rangereg.app.tab.export import ExportPanel

    st, tab = panel.state, panel.tab
    got = {}
    tab.client = SimpleNamespace(send_file_download=lambda name, data, save_immediately: got.update({name: data}))
    export = ExportPanel(tab)
    tab.guarded(panel.load_trace, "run.jsonl", corner_trace.read_bytes())
    export.trace()  # a loaded trace goes out with the header it came with
    back = read_trace(got["trace.jsonl"].decode(), "exported.jsonl")
    assert back.header.seed == 2 and len(back.events) == len(lines(corner_trace)) - 2
    back.check_scans(st.source, st.target)
    # a run of the page: its header is made when it starts (app/tab/run.py), its result closes the file
    end = back.events[-1].T
    with st.lock:
        st.reset_run()
        st.events = back.events[:3]
        st.run_header = TraceHeader.of(st.source, st.target, st.T_init, Config(method="icp", seed=4))
        st.result = SimpleNamespace(transform=end, to_json=lambda: {"transform": end.tolist(), "error": 1.0})
    export.trace()
    again = read_trace(got["trace.jsonl"].decode(), "exported.jsonl")
    assert (again.header.method, again.header.seed, len(again.events)) == ("icp", 4, 3)
    assert np.array_equal(again.end, end) and again.check_scans(st.source, st.target)
    with st.lock:
        st.reset_run()
    assert st.run_header is None
