"""Hardening: only regular files are read, sizes bounded before reading, causes named, signals end a
command in one line, uploads held to the cap while they arrive, malformed page frames logged in one line.

Most bad inputs run in this process through ``app.cli.main`` (the contract: status, one stderr line,
nothing touched); FIFOs that are read, pipes, signals and a closed stdout run as real subprocesses
through benchmarks/bad_inputs.py, whose table holds every case.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import socket
import sys
import threading
import time
import uuid

import numpy as np
import pytest
from rangereg.core.errors import InputError

from tests.conftest import ASSETS, ROOT

_spec = importlib.util.spec_from_file_location("bad_inputs", ROOT / "benchmarks" / "bad_inputs.py")
bad_inputs = sys.modules.setdefault("bad_inputs", importlib.util.module_from_spec(_spec))
if not hasattr(bad_inputs, "CASES"):
    _spec.loader.exec_module(bad_inputs)

# In-process: each a different reader or a different cause (a few ms to 1 s each here).
IN_PROCESS = (
    "scan fifo info", "scan zero register source", "scan loop merge", "scan dangling info", "scan sock serve",
    "init urandom", "init loop", "sidecar fifo", "sidecar sparse", "slice trace zero", "merge init fifo",
    "merge truth sparse", "merge init names a scan twice", "serve data dir a fifo", "sparse ply", "sparse xyz",
    "ply face 2e9 one row binary", "ply face 2e9 one row ascii", "ply range_grid 0 no property", "ply face scalar",
    "ply faces only", "ply x twice", "ply two vertex elements", "one point at 1e300 among 1600",
    "slice span 1e300", "pcd viewpoint 1e300", "init scaled 1.001", "pcd compressed corrupt", "latin-1 name missing",
    "leica pts with its count", "ply with a utf-8 bom", "conf beside fifo", "conf beside sparse",
    "bench workers without sweep", "merge scheduler unreachable", "rotation uncertainty 1e-300",
    "merge truth translation nan", "merge workers and scheduler", "init entry 1e300",
)
# As real processes: what only a process shows (a pipe read once, a FIFO given up, signals, stdout closed).
SUBPROCESS = ("init pipe accepted", "init fifo without a writer", "register trace SIGTERM", "ctrl-c right after start",
              "stdout closed info")


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    f = tmp_path_factory.mktemp("bad")
    bad_inputs.write_fixtures(f)
    bad_inputs.write_special(f)
    return f


def test_the_table_holds_300_distinct_cases_and_names_the_subsets():
    cases = bad_inputs.CASES
    assert len({c.name for c in cases}) == len(cases) >= 300
    assert len({(c.args, c.pipe, c.signal, c.stdout_closed) for c in cases}) == len(cases)
    names = {c.name for c in cases}
    assert set(IN_PROCESS) <= names and set(SUBPROCESS) <= names


@pytest.mark.parametrize("name", IN_PROCESS)
def test_a_bad_input_meets_the_contract_in_process(name, folder, monkeypatch, capsys):
    from rangereg.app.cli import main

    case = next(c for c in bad_inputs.CASES if c.name == name)
    monkeypatch.chdir(folder)
    before = bad_inputs.snapshot(folder)
    t0 = time.perf_counter()
    status = main(list(case.args))
    seconds = time.perf_counter() - t0
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert status == case.status, err
    assert "Traceback" not in err
    if case.expect or case.status:
        assert len(lines) == 1 and case.expect.lower() in lines[0].lower(), err
    else:
        assert not lines, err
    assert case.stdout_ok or not out.strip()
    assert bad_inputs.snapshot(folder) == before
    assert seconds < 10


def test_the_cases_only_a_process_shows_meet_the_contract():
    failures: list[str] = []
    cases = [c for c in bad_inputs.CASES if c.name in SUBPROCESS]
    assert bad_inputs.run_table(cases, jobs=2, timeout=120.0, say=failures.append, bound=30.0) == 0, "\n".join(failures)


def test_the_smallest_and_spread_selections():
    assert {c.name for c in bad_inputs.select(bad_inputs.CASES, smallest=True)} == set(bad_inputs.FAST)
    spread = bad_inputs.select(bad_inputs.CASES, only=5)
    assert len(spread) == 5 and spread[0] is bad_inputs.CASES[0] and spread[-1] is bad_inputs.CASES[-1]


# ---- core.files: what a path is decides, before a byte is read ----------------------------------------

def test_a_fifo_is_refused_at_once_and_a_pipe_given_as_a_side_file_is_read_once(tmp_path):
    from rangereg.core.files import read_bytes

    os.mkfifo(tmp_path / "f")
    t0 = time.perf_counter()
    with pytest.raises(InputError, match=r"is a pipe \(FIFO\), not a transform"):
        read_bytes(tmp_path / "f", "f", 100, "a transform")
    assert time.perf_counter() - t0 < 1  # refused by what it is: never opened for a writer to come
    r, w = os.pipe()
    os.write(w, b"1 2 3")
    os.close(w)
    assert read_bytes(f"/dev/fd/{r}", "p", 100, "a transform", pipe=True) == b"1 2 3"
    os.close(r)


def test_a_pipe_that_sends_nothing_or_too_much_is_given_up(tmp_path, monkeypatch):
    import rangereg.core.files
    from rangereg.core.files import read_bytes

    monkeypatch.setattr(rangereg.core.files, "PIPE_WAIT", 0.3)
    os.mkfifo(tmp_path / "f")
    with pytest.raises(InputError, match="sent nothing for 0.3 s"):
        read_bytes(tmp_path / "f", "f", 100, "a transform", pipe=True)
    r, w = os.pipe()
    threading.Thread(target=lambda: (os.write(w, b"x" * 500), os.close(w)), daemon=True).start()
    with pytest.raises(InputError, match="more than 100 bytes"):
        read_bytes(f"/dev/fd/{r}", "p", 100, "a transform", pipe=True)
    os.close(r)


def test_links_devices_and_sparse_files_are_named_for_what_they_are(tmp_path):
    from rangereg.core.files import read_bytes

    (tmp_path / "a").symlink_to("b")
    (tmp_path / "b").symlink_to("a")
    (tmp_path / "gone").symlink_to("nowhere")
    (tmp_path / "z").symlink_to("/dev/zero")
    with open(tmp_path / "s", "wb") as fh:
        fh.truncate(10 << 30)
    for name, words in (("a", "too many levels of symbolic links"), ("gone", "link to nowhere, which does not exist"),
                        ("z", "links to /dev/zero, which is a character device"),
                        ("s", "10.7 GB (a sparse file: 0 bytes stored on disk")):
        with pytest.raises(InputError, match=words.replace("(", r"\(")):
            read_bytes(tmp_path / name, name, 1 << 20, "a transform")


def test_a_scan_larger_than_memory_can_read_is_refused_from_its_size(tmp_path):
    from rangereg.core.files import check_memory

    with pytest.raises(InputError, match="reading it takes about 5 x its size in memory; 1 GB is free"):
        check_memory(300_000_000, 5, "big.ply", available=1_000_000_000)
    check_memory(100_000_000, 5, "fine.ply", available=1_000_000_000)


# ---- causes named ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("R, words", [
    (np.eye(3) * 1.001, "a rotation scaled by 1.001"),
    (np.diag([-1.0, 1, 1]), "a reflection"),
    (np.array([[1, 0.5, 0], [0, 1, 0], [0, 0, 1.0]]), "stretches by 1.28078, 1, 0.780776"),
])
def test_a_transform_that_is_not_rigid_says_what_it_is(R, words):
    from rangereg.core.transforms import check_rigid

    T = np.eye(4)
    T[:3, :3] = R
    with pytest.raises(ValueError, match=words):
        check_rigid(T, "T")


def test_scans_in_units_1000_apart_are_told_from_a_part_scanned_finely():
    from dataclasses import replace

    from rangereg.core.io import load_scan
    from rangereg.core.scan import scale_mismatch

    scan = load_scan(ASSETS / "corner" / "scan1.ply")
    metres = replace(scan, points=scan.points / 1000, name="metres")
    assert "about 1000 x smaller" in scale_mismatch(metres, scan)
    assert "(millimetres and metres?)" in scale_mismatch(scan, metres)
    part = replace(scan, points=scan.points[np.linalg.norm(scan.points - scan.points[0], axis=1) < 200], name="part")
    assert scale_mismatch(part, scan) is None  # smaller, but sampled alike: the same units


def test_a_tiny_scan_is_refused_for_registration_and_max_points_3_runs():
    from dataclasses import replace

    from rangereg.core.io import load_scan
    from rangereg.core.problem import ProblemConfig, prepare
    from rangereg.core.register import Config, register

    scan = load_scan(ASSETS / "corner" / "scan1.ply")
    with pytest.raises(InputError, match="only 20 points; registering needs at least 24"):
        prepare(replace(scan, points=scan.points[:20], grid=None), scan)
    other = load_scan(ASSETS / "corner" / "scan2.ply")
    from rangereg.core.problem import relative_guess

    res = register(other, scan, relative_guess(other, scan),
                   Config(method="icp", problem=ProblemConfig(max_points=3)))
    assert np.all(np.isfinite(res.transform))


# ---- the page: uploads held to the cap, malformed frames in one line ----------------------------------

@pytest.fixture
def page():
    """A workbench in this process (1 MB upload cap) and a WebSocket client speaking viser's protocol."""
    import msgspec
    import viser
    from rangereg.app.access import free_port
    from rangereg.app.workbench import ServeOptions, Workbench
    from viser import _messages
    from websockets.sync.client import connect

    port = free_port()
    wb = Workbench(ServeOptions(port=port, upload_cap_mb=1.0))

    def open_page():
        ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        threading.Thread(target=lambda: _drain(ws), daemon=True).start()
        return ws

    ws = open_page()
    camera = _messages.ViewerCameraMessage((1.0, 0, 0, 0), (0, 0, 1.0), 1.0, 0.01, 100.0, 480, 640, (0, 0, 0), (0, 1.0, 0))
    ws.send(msgspec.msgpack.encode(camera.as_serializable_dict()))  # viser makes the client's tab on its first camera
    deadline = time.monotonic() + 60
    while not wb.tabs and time.monotonic() < deadline:
        time.sleep(0.05)
    tab = next(iter(wb.tabs.values()))
    assert _settle(lambda: tab.state.target is not None, 60)  # the first pair shown
    notes: list[tuple[str, str]] = []
    tab.notify = lambda title, body, error=True: notes.append((title, body))
    button = tab.scans.h.upload_source._impl.uuid

    def send(message, socket_=ws):
        socket_.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def upload(size, parts, chunks, name="x.ply"):
        t = str(uuid.uuid4())
        send(_messages.FileTransferStartUpload(button, t, name, "application/octet-stream", parts, size))
        for i, chunk in enumerate(chunks):
            send(_messages.FileTransferPart(button, t, i, chunk))
        return t

    yield type("Page", (), {"wb": wb, "tab": tab, "notes": notes, "upload": staticmethod(upload),
                            "states": tab.client.gui._current_file_upload_states, "open": staticmethod(open_page)})
    ws.close()
    wb.server.stop()


def _drain(ws) -> None:
    try:
        while True:
            ws.recv()
    except Exception:  # noqa: BLE001 - closed
        pass


def _settle(condition, seconds: float = 20.0) -> bool:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.05)
    return False


def test_an_upload_announced_over_the_cap_is_refused_before_its_bytes_are_kept(page):
    t = page.upload(5_000_000, 10, [b"\0" * 500_000] * 3)
    assert _settle(lambda: page.notes)
    assert page.notes[-1] == ("Upload refused", "x.ply: 5 MB is over the upload cap (1 MB)")
    time.sleep(0.5)
    assert t not in page.states  # nothing buffered for it


def test_an_upload_that_sends_more_than_it_announced_is_cut_off(page):
    t = page.upload(1000, 4, [b"\0" * 400_000] * 4)
    assert _settle(lambda: page.notes)
    title, body = page.notes[-1]
    assert title == "Upload refused" and "sent more than the 0.001 MB it announced" in body
    time.sleep(0.5)
    assert t not in page.states


def test_an_honest_upload_within_the_cap_loads(page):
    content = (ASSETS / "corner" / "scan1.ply").read_bytes()
    parts = [content[k:k + 512 * 1024] for k in range(0, len(content), 512 * 1024)]
    page.upload(len(content), len(parts), parts, name="scan1.ply")
    assert _settle(lambda: page.notes, 60)
    assert page.notes[-1][0] == "Loaded", page.notes


def test_malformed_page_frames_are_one_log_line_each_and_the_server_keeps_serving(page, caplog, capfd):
    import msgspec

    frames = [b"\x00\x01garbage", msgspec.msgpack.encode({"type": "NoSuchMessage"}),
              msgspec.msgpack.encode({"type": "FileTransferPart", "source_component_uuid": None,
                                      "transfer_uuid": "x", "part_index": "one", "content": 5})]
    with caplog.at_level(logging.WARNING, logger="rangereg.workbench"):
        for frame in frames:
            ws = page.open()
            ws.send(frame)
            time.sleep(0.5)
            ws.close()
        assert _settle(lambda: len([r for r in caplog.records if "malformed frame" in r.getMessage()]) >= 3)
    assert "Traceback" not in capfd.readouterr().err
    with socket.create_connection(("127.0.0.1", page.wb.options.port), timeout=5):
        pass


@pytest.mark.parametrize("text", ["[" * 100_000 + "]" * 100_000, '{"viewpoint": [' + "9" * 5000 + ", 0, 0]}"])
def test_a_sidecar_nested_past_the_stack_or_holding_a_number_of_thousands_of_digits_is_one_message(tmp_path, text):
    # json raises RecursionError for the one and ValueError (int's digit limit) for the other, neither a JSONDecodeError
    import shutil

    from rangereg.core.io import load_scan
    from rangereg.core.sidefiles import transform_from_text

    scan = tmp_path / "scan2.ply"
    shutil.copy(ASSETS / "corner" / "scan2.ply", scan)
    scan.with_suffix(".json").write_text(text)
    with pytest.raises(InputError, match="the sidecar is not valid JSON"):
        load_scan(scan)
    with pytest.raises(InputError, match="expected JSON with a 'transform'"):
        transform_from_text('{"transform": ' + text + "}", "--init")
