"""A run's recording plays from disk in a browser, with no server and no network, and the scan moves."""

from __future__ import annotations

import io
import time
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ASSETS, wait_for
from tests.test_workbench import CHROMIUM, FLAGS

pytestmark = pytest.mark.browser


def corner_run():
    from rangereg.app.recording import RunToRecord
    from rangereg.app.views import Display
    from rangereg.core.frustum import frustum_of
    from rangereg.core.io import load_scan
    from rangereg.core.problem import relative_guess
    from rangereg.core.register import Config, register
    from rangereg.core.scenes import scene_paths

    source, target = (load_scan(p) for p in scene_paths(ASSETS, "corner"))
    T0, events = relative_guess(source, target), []
    register(source, target, T0, Config(method="hybrid"), listener=events.append)
    frusta = (frustum_of(source, "convex"), frustum_of(target, "convex"))
    return RunToRecord(source, target, Display(target, source), frusta, T0, events, units=target.units)


def orange_centre(png: bytes) -> np.ndarray | None:
    """Mean pixel of the moving scan's orange (its points and frustum); None while it is not drawn."""
    from PIL import Image

    px = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    mask = (px[..., 0] > 200) & (px[..., 1] > 100) & (px[..., 1] < 180) & (px[..., 2] < 90)
    mask[:200, :350] = False  # the page's note about software WebGL
    ys, xs = np.nonzero(mask)
    return None if len(xs) < 200 else np.array([xs.mean(), ys.mean()])


def test_the_recording_plays_from_disk_and_the_scan_moves(tmp_path):
    if not CHROMIUM.exists():
        pytest.skip("Debian's chromium is not installed")
    from playwright.sync_api import sync_playwright
    from rangereg.app.recording import recording_html

    path = tmp_path / "run.html"
    path.write_bytes(recording_html(corner_run(), frames=60, seconds=4.0, hold=4.0))
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=FLAGS)
        page = browser.new_page(viewport={"width": 1000, "height": 700})
        schemes = set()
        page.on("request", lambda r: schemes.add(r.url.split(":")[0]))
        page.goto(Path(path).as_uri())
        page.locator("canvas").first.wait_for(timeout=60_000)
        deadline, early = time.monotonic() + 60, None
        while early is None and time.monotonic() < deadline:
            early = orange_centre(page.screenshot())
        assert early is not None, "the moving scan never appeared"
        moved = []

        def has_moved() -> bool:
            late = orange_centre(page.screenshot())
            moved.append(0.0 if late is None else float(np.linalg.norm(late - early)))
            return moved[-1] > 5.0  # pixels: the scan moved along the run

        wait_for(has_moved, 12.0, what="the scan")  # the start is held 4 s; the run plays in 4 s
        browser.close()
    assert schemes <= {"file", "data", "blob"}  # nothing from a server or the network


def test_the_opening_camera_is_outside_both_frustums_and_the_chart_beside_the_scans():
    from rangereg.app.recording import CHART_SIZE, chart_of
    from rangereg.app.tab.scene3d import _inside_frusta, default_view, pair_extent
    from rangereg.app.views import Trail

    run = corner_run()
    d = run.display
    eye, look_at = default_view(d, run.target, run.source, run.T_start, run.frustums)
    assert not _inside_frusta(eye, d, run.T_start, run.frustums)
    trail = Trail(d, run.events)
    trail.update()
    extent = pair_extent(d, run.target, run.source, run.T_start)
    chart = chart_of(run, trail, eye, look_at, extent)
    assert len(chart.xy) == len(run.events) + 1 and np.all((chart.xy >= 0) & (chart.xy <= 1))
    assert chart.xy[0, 0] == 0 and chart.xy[-1, 0] == 1  # from the start to the last iteration
    # the chart lies on the camera's right of every corner of the scans' box, and faces the camera
    way = (eye - look_at) / np.linalg.norm(eye - look_at)
    assert abs(chart.right @ way) < 1e-9 and abs(chart.up @ way) < 1e-9
    assert ((chart.corners() - look_at) @ chart.right).min() > ((extent - look_at) @ chart.right).max()
    assert np.isclose(np.ptp(chart.corners() @ chart.right), CHART_SIZE[0])
    # widened to take the chart in, the camera is still outside the frustums
    eye2, _ = default_view(d, run.target, run.source, run.T_start, run.frustums, chart.corners())
    assert not _inside_frusta(eye2, d, run.T_start, run.frustums)
