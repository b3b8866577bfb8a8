"""The workbench in a real browser: Debian's Chromium driven by Playwright, against `rangereg serve`."""

from __future__ import annotations

import io
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ROOT, holds_for, serving, wait_for

pytestmark = pytest.mark.browser
CHROMIUM = Path("/usr/bin/chromium")
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]
ARTIFACTS = ROOT / "artifacts"


@pytest.fixture(scope="module")
def server():
    with serving() as (url, port, _):
        yield url, port


def open_page(browser, url):
    page = browser.new_page(viewport={"width": 1400, "height": 900})
    page.goto(url)
    page.get_by_text("Initial E =").wait_for(timeout=60_000)
    page.wait_for_function("() => document.body.innerText.includes('overlap')", timeout=60_000)
    return page


def show_tab(page, name: str) -> None:
    """Bring one of the panel's tabs (Run, Pose, Scans, Landscape, Model, Export) to the front."""
    page.get_by_role("tab", name=name, exact=True).click()


def initial_E(page) -> float:
    return float(re.search(r"Initial E = ([0-9.eE+-]+)", page.get_by_text("Initial E =").inner_text()).group(1))


def text_input(page, label: str):
    """A text field by its label (viser's text fields carry a label whose "for" names no element)."""
    return page.locator("label", has_text=re.compile(f"^{re.escape(label)}$")).first.locator(
        "xpath=ancestor::div[2]").locator("input")


def pose_fields(page) -> np.ndarray:
    names = ("tx (mm)", "ty (mm)", "tz (mm)", "rx (deg)", "ry (deg)", "rz (deg)")  # the corner is in mm
    return np.array([float(text_input(page, n).input_value()) for n in names])


def canvas_pixels(page) -> np.ndarray:
    from PIL import Image

    png = page.locator("canvas").first.screenshot()
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"))


def wait_finished(page, timeout=120.0) -> str:
    text = ""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = page.locator("body").inner_text()
        m = re.search(r"Finished: ([^\n]+\n[^\n]+)", text)  # trust and why, then E, the stop, the time
        if m:
            return m.group(1)
        time.sleep(0.2)
    raise AssertionError(f"the run did not finish in {timeout} s; the page: {text[-800:]!r}")


def wait_cancelled(page, timeout=60.0) -> str:
    """The line a cancelled run ends with: where it was cancelled, E and the pose it left, then its steps."""
    text = ""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        text = page.locator("body").inner_text()
        m = re.search(r"Cancelled at iteration ([^\n]+\n[^\n]+)", text)
        if m:
            return m.group(1)
        time.sleep(0.2)
    raise AssertionError(f"the run did not end cancelled in {timeout} s; the page: {text[-800:]!r}")


def test_scene_renders_and_hybrid_finishes_below_threshold(server, browser):
    page = open_page(browser, server[0])
    wait_for(lambda: len(np.unique(canvas_pixels(page).reshape(-1, 3), axis=0)) > 50, what="the blank canvas")
    for button, method in (("Run hybrid", "hybrid"), ("Basin hopping", "basin-hopping"), ("Run global", "global")):
        page.get_by_role("button", name="Reset", exact=True).click()
        page.get_by_role("button", name=button, exact=True).click()
        page.wait_for_function(f"() => document.body.innerText.includes('Method {method}')", timeout=60_000)
        line = wait_finished(page)
        m = re.search(r"^trust (yes|no): (.*)\nE = ([0-9.eE+-]+) ", line)  # trust first, then E
        assert m and m.group(1) == "yes" and "What to do" not in line, line
        trust, E = m.group(2), float(m.group(3))
        if method == "global":  # the pair threshold: distance and normals on the fixed basis (core.threshold)
            assert "misfit" in trust, line
        else:
            t = re.search(r"E is below the threshold \(([0-9.eE+-]+)\)", trust)
            assert t and E < float(t.group(1)), line
        if method == "hybrid":
            ARTIFACTS.mkdir(exist_ok=True)
            page.screenshot(path=str(ARTIFACTS / "workbench-finished.png"))
    page.close()


def icp_iterations(page) -> int:
    return int(re.search(r"Iterations: ICP (\d+)", page.locator("body").inner_text()).group(1))


def wait_paused(page, iterations: int | None = None, timeout: float = 60.0) -> int:
    """Wait until the page says the run is paused (after ``iterations`` ICP iterations when given)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if "· paused ·" in page.locator("body").inner_text():
            n = icp_iterations(page)
            if iterations is None or n == iterations:
                return n
        time.sleep(0.1)
    raise AssertionError(f"the run did not pause: {page.locator('body').inner_text()[:400]}")


def test_step_next_phase_resume_walk_a_hybrid_run_to_its_end(server, browser):
    """The corner opens with ICP in two legs (the second on an overlap re-cut at the pose found)."""
    page = open_page(browser, server[0])
    page.get_by_role("button", name="Step", exact=True).click()
    assert wait_paused(page, 1) == 1 and "Method hybrid" in page.locator("body").inner_text()
    holds_for(lambda: icp_iterations(page) == 1, 0.5, what="the paused run")  # a step is one iteration; it stays paused
    from playwright.sync_api import expect

    expect(page.get_by_role("button", name="Pause", exact=True)).to_be_disabled()  # paused: only Resume is offered
    expect(page.get_by_role("button", name="Resume", exact=True)).to_be_enabled()
    page.get_by_role("button", name="Next phase", exact=True).click()
    wait_for(lambda: icp_iterations(page) != 1, 60, what="the ICP count")
    n = wait_paused(page)
    assert n > 2 and "Finished" not in page.locator("body").inner_text()  # paused where the first leg ended
    page.get_by_role("button", name="Resume", exact=True).click()
    assert "below" in wait_finished(page, 60)
    assert icp_iterations(page) > n
    page.close()


def _gizmo_pixel(px: np.ndarray) -> tuple[int, int] | None:
    """A pixel of the gizmo's red (x) handles: a crimson (about 250, 45, 105) no scan colour has."""
    r, g, b = (px[..., k].astype(int) for k in range(3))
    mask = (r > 220) & (g < 70) & (b > 80) & (b < 130)
    mask[:, -450:] = False  # the control panel
    mask[-120:, :120] = False  # the orientation axes in the corner
    ys, xs = np.nonzero(mask)
    if len(xs) < 20:
        return None
    k = np.argmax(np.hypot(xs - xs.mean(), ys - ys.mean()))  # the tip of the handle: far from the centre
    return int(xs[k]), int(ys[k])


def test_dragging_the_gizmo_changes_the_initial_error(server, browser):
    page = open_page(browser, server[0])
    show_tab(page, "Scans")
    for box in ("Frustums", "Overlap points", "Path"):
        page.get_by_label(box, exact=True).first.uncheck()
    show_tab(page, "Pose")
    wait_for(lambda: _gizmo_pixel(canvas_pixels(page)) is not None, what="the gizmo (not on screen)")
    E_before = initial_E(page)
    pose_before = pose_fields(page)
    box = page.locator("canvas").first.bounding_box()
    hit = _gizmo_pixel(canvas_pixels(page))
    x, y = box["x"] + hit[0], box["y"] + hit[1]
    page.mouse.move(x, y)
    page.mouse.down()
    for k in range(1, 11):
        page.mouse.move(x + 8 * k, y + 3 * k)
        time.sleep(0.05)
    page.mouse.up()
    wait_for(lambda: initial_E(page) != E_before, 10, what="the initial E")
    assert not np.allclose(pose_fields(page), pose_before)  # the typed parameters follow the gizmo
    page.close()


def test_two_tabs_are_independent(server, browser):
    a, b = open_page(browser, server[0]), open_page(browser, server[0])
    E_a, E_b = initial_E(a), initial_E(b)
    assert E_a == pytest.approx(E_b)
    show_tab(a, "Pose")
    tx = text_input(a, "tx (mm)")
    tx.fill(str(float(tx.input_value()) + 40.0))
    a.get_by_role("button", name="Apply pose", exact=True).click()
    wait_for(lambda: initial_E(a) != E_a, 10, what="tab A's initial E")
    show_tab(a, "Run")
    a.get_by_role("button", name="Run SA", exact=True).click()  # a long run in tab A ...
    wait_for(lambda: "running" in a.locator("body").inner_text(), what="tab A's run")
    assert initial_E(b) == pytest.approx(E_b)  # ... moves nothing in tab B, whose page still answers
    b.get_by_role("button", name="Run ICP", exact=True).click()
    assert "below" in wait_finished(b, 60)
    assert "running" in a.locator("body").inner_text() and "Finished" not in a.locator("body").inner_text()
    a.get_by_role("button", name="Cancel", exact=True).click()
    assert "(not trusted)" in wait_cancelled(a, 10) and "Finished" not in a.locator("body").inner_text()
    a.close()
    b.close()


def test_bad_setting_is_a_notification_and_the_session_lives_on(server, browser):
    page = open_page(browser, server[0])
    page.get_by_text("Settings", exact=True).click()
    thr = text_input(page, "Threshold")
    thr.fill("banana")
    thr.press("Enter")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    page.get_by_text("Threshold: expected a number").first.wait_for(timeout=10_000)
    thr.fill("auto")
    thr.press("Enter")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    assert "E =" in wait_finished(page, 60)
    page.close()


def handshake(port: int, host: str, origin: str | None) -> int:
    """HTTP status of a raw WebSocket opening handshake sent with these Host and Origin headers."""
    lines = ["GET / HTTP/1.1", f"Host: {host}", "Upgrade: websocket", "Connection: Upgrade",
             "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==", "Sec-WebSocket-Version: 13"]
    if origin is not None:
        lines.append(f"Origin: {origin}")
    with socket.create_connection(("127.0.0.1", port), timeout=10) as s:
        s.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        return int(s.recv(4096).split(b" ", 2)[1])


def test_websocket_only_from_the_workbench_page(server):
    port = server[1]
    assert handshake(port, f"127.0.0.1:{port}", f"http://127.0.0.1:{port}") == 101
    assert handshake(port, f"localhost:{port}", f"http://localhost:{port}") == 101
    assert handshake(port, f"127.0.0.1:{port}", "http://evil.example") == 403
    assert handshake(port, f"evil.example:{port}", f"http://evil.example:{port}") == 403  # DNS rebinding
    assert handshake(port, "evil.example", None) == 403


def test_a_library_websocket_client_from_a_foreign_origin_is_refused(server):
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    port = server[1]
    with pytest.raises(InvalidStatus) as refused:
        connect(f"ws://127.0.0.1:{port}", origin="http://evil.example", open_timeout=10)
    assert refused.value.response.status_code == 403
    connect(f"ws://127.0.0.1:{port}", origin=f"http://127.0.0.1:{port}", open_timeout=10).close()


def test_a_page_request_under_a_foreign_host_is_refused(server):
    import http.client

    conn = http.client.HTTPConnection("127.0.0.1", server[1], timeout=10)
    conn.request("GET", "/", headers={"Host": "evil.example"})
    assert conn.getresponse().status == 403
    conn = http.client.HTTPConnection("127.0.0.1", server[1], timeout=10)
    conn.request("GET", "/")
    assert conn.getresponse().status == 200


def test_every_interface_is_said_aloud_with_the_real_addresses():
    with serving(host="0.0.0.0") as (_, port, seen):
        text = "".join(seen)
    assert "warning: --host 0.0.0.0 listens on every network interface" in text
    urls = re.findall(r"http://\S+", seen[-1])
    assert urls and f"http://127.0.0.1:{port}" in urls and not any("0.0.0.0" in u for u in urls)


def test_numbers_are_taken_as_typed_and_a_bad_one_is_said_not_mangled(server, browser):
    page = open_page(browser, server[0])
    show_tab(page, "Pose")
    E0, tx = initial_E(page), text_input(page, "tx (mm)")
    before = float(tx.input_value())
    tx.fill("12,5")
    page.get_by_role("button", name="Apply pose", exact=True).click()
    page.get_by_text("write decimals with a point").first.wait_for(timeout=10_000)
    assert initial_E(page) == E0  # nothing applied
    # exponent notation, as a user may type it (viser's number field mangled it); a move E shows in 4 digits
    tx.fill(f"{before + 2.5e1:.12e}")
    page.get_by_role("button", name="Apply pose", exact=True).click()
    wait_for(lambda: initial_E(page) != E0, 10, what="the initial E")
    assert float(text_input(page, "tx (mm)").input_value()) == pytest.approx(before + 2.5e1, abs=1e-9)
    # out of range is a notification, not a silent clamp
    show_tab(page, "Landscape")
    text_input(page, "Steps").fill("1000000")
    page.get_by_role("button", name="Compute slice", exact=True).click()
    page.get_by_text("Steps: must be >= 2 and <= 201").first.wait_for(timeout=10_000)
    # a big slice can be cancelled
    text_input(page, "Steps").fill("201")
    page.get_by_role("button", name="Compute slice", exact=True).click()
    page.get_by_role("button", name="Cancel slice", exact=True).click()
    page.get_by_text("cancelled").first.wait_for(timeout=30_000)
    assert page.locator(".js-plotly-plot").count() == 0
    page.close()


def test_taken_port_is_refused(server):
    r = subprocess.run([sys.executable, "-m", "rangereg.app.cli", "serve", "--port", str(server[1])], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "taken" in r.stderr and "Traceback" not in r.stderr


@pytest.fixture(scope="module")
def data_server(tmp_path_factory):
    """A server with --data-dir (the corner scans renamed) and a tiny upload cap."""
    import shutil

    folder = tmp_path_factory.mktemp("data")
    for src, dst in (("scan1", "left"), ("scan2", "right")):
        for ext in (".ply", ".json"):
            shutil.copy(ROOT / "assets" / "corner" / f"{src}{ext}", folder / f"{dst}{ext}")
    (folder.parent / "outside.ply").write_bytes((ROOT / "assets" / "corner" / "scan1.ply").read_bytes())
    with serving("--data-dir", folder, "--upload-cap-mb", "0.05") as (url, _, _):
        yield url, folder


def test_data_dir_upload_cap_merge_and_exports(data_server, browser):
    import json

    url, folder = data_server
    page = open_page(browser, url)
    # files from --data-dir, and nothing outside it, are offered; opening them shows them
    show_tab(page, "Scans")
    body = page.locator("body").inner_text()
    assert "outside" not in body
    page.get_by_role("button", name="Open files", exact=True).click()
    page.wait_for_function("() => document.body.innerText.includes('right → left')", timeout=60_000)
    # an upload above the cap is refused with a reason, and the session keeps its scans
    page.locator("input[type=file]").first.set_input_files(str(folder / "right.ply"))
    page.get_by_text("over the upload cap").first.wait_for(timeout=20_000)
    assert "right → left" in page.locator("body").inner_text()
    # register, then merge into one model
    show_tab(page, "Run")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    assert "below" in wait_finished(page, 60)
    show_tab(page, "Model")
    page.get_by_role("button", name="Fuse this pair", exact=True).click()
    page.get_by_text(re.compile(r"\d+ vertices, \d+ triangles")).first.wait_for(timeout=120_000)
    # a slice of the error surface around the pose, drawn in the page
    show_tab(page, "Landscape")
    page.get_by_role("button", name="Compute slice", exact=True).click()
    page.locator(".js-plotly-plot").first.wait_for(timeout=120_000)
    # every export arrives as a download in the browser
    show_tab(page, "Export")

    def download(label: str) -> bytes:
        with page.expect_download(timeout=60_000) as d:
            page.get_by_role("button", name=label, exact=True).click()
        return Path(d.value.path()).read_bytes()

    T = np.array(json.loads(download("Transform (JSON)"))["transform"])
    assert T.shape == (4, 4) and np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    from rangereg.core.trace import read_trace

    trace = read_trace(download("Trace (JSON lines)").decode(), "trace.jsonl")  # header, events, result
    assert trace.header.source.name == "right" and trace.result is not None
    assert trace.events and all(e.phase in ("icp", "sa") for e in trace.events)
    assert download("Registered scans (PLY)").startswith(b"ply")
    assert download("Model (PLY)").startswith(b"ply")
    assert download("Slice (PNG)").startswith(b"\x89PNG")
    page.close()


def test_a_campaign_of_the_data_folder_merges_with_the_clis_progress(data_server, browser):
    url, _ = data_server
    page = open_page(browser, url)
    show_tab(page, "Model")
    page.get_by_role("button", name="Merge scans", exact=True).click()
    # the report: every scan placed, and the last progress line as the CLI prints it (every round counted)
    page.get_by_text(re.compile(r"right: placed")).first.wait_for(timeout=180_000)
    body = page.locator("body").inner_text()
    assert re.search(r"pairs, round \d+ (\d+)/\1, \d+:\d\d elapsed, done", body), body
    assert "2 of 2 scans placed" in body and "left: placed" in body
    page.close()
