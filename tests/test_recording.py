"""A run's recording plays from disk in a browser, with no server and no network, and the scan moves."""

from __future__ import annotations

import io
import time
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ASSETS, BUNNY, wait_for
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



def opening_axes(run) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The recording's opening camera for ``run``: its eye (3,) and unit ahead, right and up (3,) (+y up)."""
    from rangereg.app.recording import opening_view
    from rangereg.app.views import Trail

    trail = Trail(run.display, run.events)
    trail.update()
    eye, look_at, _ = opening_view(run, trail)
    ahead = (look_at - eye) / np.linalg.norm(look_at - eye)
    right = np.cross(ahead, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    return eye, ahead, right, np.cross(right, ahead)

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


@cache
def _bunny_run():
    from rangereg.app.recording import RunToRecord
    from rangereg.app.tab.settings import FRUSTUM
    from rangereg.app.views import Display
    from rangereg.core.frustum import frustum_of
    from rangereg.core.io import load_scan
    from rangereg.core.problem import relative_guess
    from rangereg.core.register import Config, register

    source, target = load_scan(BUNNY / "bun045.ply"), load_scan(BUNNY / "bun000.ply")  # the page's first bunny pair
    T0, events = relative_guess(source, target), []
    r = register(source, target, T0, Config(method="hybrid"), listener=events.append)
    frusta = (frustum_of(source, FRUSTUM), frustum_of(target, FRUSTUM))  # the page's default kind
    return RunToRecord(source, target, Display(target, source), frusta, T0, events, units=target.units,
                       threshold=r.threshold)


@pytest.fixture
def bunny_run():
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans (../shared/data/bunny) are absent")
    return _bunny_run()


def test_the_bunny_recording_opens_outside_both_frustums_drawn_round_the_scans_not_from_the_sensors(bunny_run):
    from rangereg.app.recording import frustum_segments, opening_view
    from rangereg.app.tab.scene3d import _inside_frusta, pair_extent
    from rangereg.app.views import Trail
    from rangereg.core.transforms import apply

    run = bunny_run
    d = run.display
    trail = Trail(d, run.events)
    trail.update()
    eye, _, _ = opening_view(run, trail)
    assert not _inside_frusta(eye, d, run.T_start, run.frustums)
    extent = pair_extent(d, run.target, run.source, run.T_start)
    lo, hi = extent.min(0), extent.max(0)
    room = 0.25 * np.linalg.norm(hi - lo)
    for f, scan, T in ((run.frustums[0], run.source, run.T_start), (run.frustums[1], run.target, np.eye(4))):
        drawn = d.points(apply(T, frustum_segments(f, scan.points).reshape(-1, 3)))  # where the page shows them
        # every line within a quarter of the scans' diagonal of their box: no spoke from the sensor 1.2 m away
        assert np.all((drawn >= lo - room) & (drawn <= hi + room)), (drawn.min(0), drawn.max(0), lo, hi)
        assert len(drawn) >= 2 * 3 * len(f.outline)  # spokes and both rings: the frustum's shape, not a stub


def pale_and_scan_pixels(png: bytes) -> tuple[int, int]:
    """(pixels of the scans' colours, pale tinted pixels: the frustums' lines) of a screenshot."""
    from PIL import Image
    from rangereg.app.figures import SOURCE_RGB, TARGET_RGB

    px = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    px[:200, :350] = 255  # the page's note about software WebGL
    scans = sum(int((np.abs(px - np.array(rgb)).sum(2) < 30).sum()) for rgb in (SOURCE_RGB, TARGET_RGB))
    pale = (px.min(2) > 140) & (px.sum(2) < 735) & (np.ptp(px, axis=2) > 25)
    return scans, int(pale.sum())


def test_the_bunny_recordings_opening_view_shows_the_scans_more_than_their_frustums(bunny_run, tmp_path, browser):
    from rangereg.app.recording import recording_html

    path = tmp_path / "bunny.html"
    path.write_bytes(recording_html(bunny_run, frames=20, seconds=2.0, hold=30.0))  # the start held
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(Path(path).as_uri())
    page.locator("canvas").first.wait_for(timeout=60_000)
    counts = []

    def drawn() -> bool:
        counts.append(pale_and_scan_pixels(page.locator("canvas").first.screenshot()))
        return counts[-1][0] > 2000

    wait_for(drawn, 60, what="the scans in the recording")
    scans, pale = counts[-1]
    assert pale < scans, counts[-1]
    # the scene fills the window: the scans' pixels span well over a third of its height (framed for a 50-degree
    # camera beside a docked panel, they spanned a quarter of it), the legend and the line that follows the run in view
    rows = np.nonzero(scan_pixel_rows(page.locator("canvas").first.screenshot()))[0]
    assert np.ptp(rows) > 0.38 * 720, (rows.min(), rows.max())
    page.close()
    # the labels (drawn in the canvas: no element to find) are anchored inside the opening view of that window
    from rangereg.app.recording import _label_anchors
    from rangereg.app.tab.scene3d import DEFAULT_FOV

    eye, ahead, right, up = opening_axes(bunny_run)
    rel = _label_anchors() - eye
    tan_v = np.tan(DEFAULT_FOV / 2)
    x, y = rel @ right / (rel @ ahead) / (tan_v * 1280 / 720), rel @ up / (rel @ ahead) / tan_v
    assert np.all(np.abs(x) < 1) and np.all(np.abs(y) < 1), (x, y)


def scan_pixel_rows(png: bytes) -> np.ndarray:
    """(H,) whether each row of a screenshot holds a good number of the scans' colours' pixels."""
    from PIL import Image
    from rangereg.app.figures import SOURCE_RGB, TARGET_RGB

    px = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)
    scan = sum((np.abs(px - np.array(rgb)).sum(2) < 30) for rgb in (SOURCE_RGB, TARGET_RGB))
    return scan.sum(1) >= 5


def test_the_notice_of_software_webgl_leaves_the_recordings_line_and_legend_readable(tmp_path, browser):
    # viser's client notes software WebGL (headless Chromium's) in a notice at the top-left, where the recording's
    # line and legend are; in a 1000 x 700 window it covered the line and the legend's first entry
    from rangereg.app.recording import LEGEND_AT, _label_anchors, recording_html
    from rangereg.app.tab.scene3d import DEFAULT_FOV

    run = corner_run()
    path = tmp_path / "corner.html"
    path.write_bytes(recording_html(run, frames=20, seconds=2.0, hold=30.0))
    page = browser.new_page(viewport={"width": 1000, "height": 700})
    page.goto(path.as_uri())
    notice = page.locator(".mantine-Notification-root").first
    notice.wait_for(timeout=60_000)
    page.wait_for_timeout(1000)  # slid into place
    box, canvas = notice.bounding_box(), page.locator("canvas").first.bounding_box()
    eye, ahead, right, up = opening_axes(run)
    # the line's, the legend's first and last entries': their text runs right from there
    rel = np.r_[_label_anchors(), [LEGEND_AT]] - eye
    tan_v = np.tan(DEFAULT_FOV / 2)
    x = rel @ right / (rel @ ahead) / (tan_v * canvas["width"] / canvas["height"])
    y = rel @ up / (rel @ ahead) / tan_v
    px = canvas["x"] + (x + 1) / 2 * canvas["width"]
    py = canvas["y"] + (1 - y) / 2 * canvas["height"]
    # the words: from the swatches (a little left of the anchors) to 200 px right, a line's height above and below
    left, right_, top, bottom = px.min() - 15, px.max() + 200, py.min() - 10, py.max() + 10
    apart = (box["x"] > right_ or box["x"] + box["width"] < left or box["y"] > bottom or box["y"] + box["height"] < top)
    assert apart, (box, (left, top, right_, bottom))
    page.close()
