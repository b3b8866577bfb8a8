"""The teaching features of the workbench in a real browser: point pairs, residuals, replay.

The workbench runs in this process (so a test can reach a tab's server-side handlers); the page is
Debian's Chromium driven by Playwright, as in tests/test_workbench.py.
"""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tests.conftest import wait_for
from tests.test_workbench import open_page, show_tab

pytestmark = pytest.mark.browser


def open_tab(bench, browser):
    """A page and the server's Tab object behind it."""
    wb, url = bench
    before = set(wb.tabs)
    page = open_page(browser, url)
    (new,) = set(wb.tabs) - before
    return page, wb.tabs[new]


def angle_deg(T_a: np.ndarray, T_b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(T_a[:3, :3] @ T_b[:3, :3].T).magnitude()))


def spread_overlap_points(tab, k: int = 3) -> list[int]:
    """k source points far apart whose true partner is on the target (farthest-point choice)."""
    from rangereg.core.transforms import apply

    st = tab.state
    moved = apply(st.T_truth, st.source.points)
    d, _ = st.target.tree.query(moved)
    inside = np.flatnonzero(d < st.target.spacing)
    centre = moved[inside].mean(0)
    chosen = [inside[np.argmin(np.linalg.norm(moved[inside] - centre, axis=1))]]
    for _ in range(k):
        gap = np.min([np.linalg.norm(moved[inside] - moved[c], axis=1) for c in chosen], axis=0)
        chosen.append(inside[np.argmax(gap)])
    return [int(c) for c in chosen[1:]]


def ray_to(tab, which: str, index: int):
    """A ray from the scan's own sensor to one of its points: the point is the first it meets."""
    from rangereg.core.transforms import apply

    st = tab.state
    scan, T = (st.source, st.T) if which == "source" else (st.target, np.eye(4))
    origin = st.display.points(apply(T, scan.viewpoint[None]))[0].astype(np.float64)
    return origin, tab.pairs.page_points(which)[index] - origin


def test_three_point_pairs_align_the_corner_within_two_degrees(bench, browser):
    from rangereg.core.transforms import apply

    page, tab = open_tab(bench, browser)
    st = tab.state
    assert angle_deg(st.T_init, st.T_truth) > 2.0  # the file pose is off: the pairs have work to do
    show_tab(page, "Pose")
    page.get_by_label("Pick point pairs", exact=True).check()
    wait_for(lambda: tab.pairs._callback is not None, what="picking mode")
    # a real click in the scene reaches the handler (the scans fill the middle of the view)
    calls = []
    handler = tab.pairs.clicked
    tab.pairs.clicked = lambda o, d: calls.append((o, d)) or handler(o, d)
    box = page.locator("canvas").first.bounding_box()
    for _ in range(10):  # the page turns on click reporting when its message arrives: click until it has
        page.mouse.click(box["x"] + 0.4 * box["width"], box["y"] + 0.5 * box["height"])
        with contextlib.suppress(AssertionError):
            wait_for(lambda: calls, 1.0, what="the click's handler")
        if calls:
            break
    assert calls, "a click in the scene never reached the handler"
    tab.pairs.clicked = handler
    page.get_by_role("button", name="Clear pairs", exact=True).click()
    wait_for(lambda: not len(tab.pairs.pairs) and tab.pairs.pairs.pending is None, what="Clear pairs")
    # three pairs through the same handler, on rays from the page's camera
    for i in spread_overlap_points(tab):
        picked = tab.pairs.clicked(*ray_to(tab, "source", i))
        assert picked is not None
        _, j = st.target.tree.query(apply(st.T_truth, st.source.points[picked]))
        assert tab.pairs.clicked(*ray_to(tab, "target", j)) is not None
    assert len(tab.pairs.pairs) == 3
    assert angle_deg(tab.pairs.pairs.align(st.source.points, st.target.points), st.T_truth) < 2.0
    wait_for(lambda: "pair 3: source" in page.locator("body").inner_text(), what="the pair list")
    assert sorted(m.text for m in tab.pairs.markers if hasattr(m, "text")) == ["S1", "S2", "S3", "T1", "T2", "T3"]
    page.get_by_role("button", name="Align from pairs", exact=True).click()
    wait_for(lambda: angle_deg(st.T_init, st.T_truth) < 2.0, what="the initial pose")
    wait_for(lambda: "Aligned from 3 pairs" in page.locator("body").inner_text(), what="the pairs cleared")
    assert not tab.pairs.markers and not len(tab.pairs.pairs)  # the numbered markers went with them
    units = st.target.units
    assert f"({units})" in page.locator("body").inner_text()
    page.close()


def test_after_a_run_the_source_is_coloured_by_residual_with_its_histogram(bench, browser):
    from rangereg.app.figures import SOURCE_RGB

    from tests.test_workbench import wait_finished

    page, tab = open_tab(bench, browser)
    page.get_by_role("button", name="Run hybrid", exact=True).click()
    wait_finished(page)
    show_tab(page, "Model")
    page.get_by_label("Colour by residual", exact=True).check()
    # the histogram's title comes before its plot (legend and cap line) is drawn: wait for all of it
    wanted = ("by distance to the target surface", "within the cap (d < √t)", "beyond the cap", "cap √t")
    wait_for(lambda: all(w in page.locator("body").inner_text() for w in wanted), what="the histogram")
    body = page.locator("body").inner_text()
    units = tab.state.target.units
    assert f"distance to the target surface ({units})" in body
    colours = tab.nodes.source.points.colors
    assert len(np.unique(colours, axis=0)) > 20 and not np.all(colours == SOURCE_RGB)
    r = tab.model.residuals.current
    assert 0.5 < r.inliers.mean() < 1.0 and np.allclose(r.T, tab.state.result.transform)
    page.close()


def test_scrubbing_the_timeline_moves_the_scan_and_its_marker_on_the_terrain(bench, browser):
    from tests.test_workbench import text_input, wait_finished

    page, tab = open_tab(bench, browser)
    st = tab.state
    page.get_by_role("button", name="Run hybrid", exact=True).click()
    wait_finished(page)
    show_tab(page, "Landscape")
    text_input(page, "Steps").fill("15")
    page.get_by_role("button", name="Compute slice", exact=True).click()
    wait_for(lambda: st.slice is not None, timeout=120, what="the slice")
    page.get_by_label("Show as 3-D terrain", exact=True).check()
    # the terrain appears first, its path right after (built off the callback thread): wait for both
    wait_for(lambda: tab.landscape.terrain is not None and tab.landscape.terrain.segments is not None
             and len(tab.landscape.terrain.segments.points) == len(st.events), what="the terrain with the run's path")
    terrain = tab.landscape.terrain
    assert len(terrain.segments.points) == len(st.events)  # the whole run drawn on the surface
    assert {tuple(c) for c in terrain.segments.colors[:, 0]} == {(30, 170, 70)}  # ICP green only: no annealing
    n = len(st.events)
    wait_for(lambda: f"Event {n} of {n}" in page.locator("body").inner_text(), what="the timeline")
    end = np.array(tab.nodes.source_frame.position)
    slider = page.get_by_role("slider").first
    slider.focus()
    page.keyboard.press("Home")  # the start of the timeline: the initial pose
    wait_for(lambda: f"Event 0 of {n}" in page.locator("body").inner_text(), what="the replay line")
    assert np.allclose(st.T, st.T_init) and not np.allclose(tab.nodes.source_frame.position, end)
    marker = np.array(terrain.current.position)
    for _ in range(3):
        page.keyboard.press("ArrowRight")
    wait_for(lambda: f"Event 3 of {n}" in page.locator("body").inner_text(), what="the replay line")
    assert np.allclose(st.T, st.events[2].T) and "phase ICP" in page.locator("body").inner_text()
    assert not np.allclose(terrain.current.position, marker)
    page.get_by_role("button", name="Play", exact=True).click()  # plays on to the end
    wait_for(lambda: f"Event {n} of {n}" in page.locator("body").inner_text(), what="Play")
    assert np.allclose(st.T, st.result.transform)  # the end of the timeline: the run's outcome
    page.close()


def test_locked_parameters_stay_in_every_event_of_a_run(bench, browser):
    from rangereg.core.transforms import PARAM_NAMES

    from tests.test_workbench import text_input, wait_finished

    page, tab = open_tab(bench, browser)
    st = tab.state
    text_input(page, "Locked parameters").fill("rx,ry,tz")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_finished(page)
    locked = [PARAM_NAMES.index(n) for n in ("rx", "ry", "tz")]
    assert st.events and all(np.all(e.coords[locked] == 0.0) for e in st.events)
    assert not np.allclose(st.result.transform, st.T_init)  # the free ones moved
    text_input(page, "Locked parameters").fill("rx,rq")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_for(lambda: "cannot lock rq" in page.locator("body").inner_text(), what="the notification")
    page.close()
