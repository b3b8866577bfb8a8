"""The Lesson tab and what a class needs to read the page, in a real browser (Debian's Chromium, Playwright).

The workbench runs in this process, so a test can read a tab's state and the camera the browser reports.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from tests.test_teach import open_tab, wait_for
from tests.test_workbench import show_tab

pytestmark = pytest.mark.browser
# the console lines viser's own client writes whatever the page shows (its three.js, software WebGL's driver notes)
CLIENT_NOISE = ("THREE.Clock", "GL Driver Message", "websocket is not connected")


def lesson_line(page) -> str:
    """The Lesson tab's sentence (the status names the step; the sentence is under Next)."""
    m = re.search(r"^(\d · .*)$", page.locator("body").inner_text(), re.M)
    return m.group(1) if m else ""


def test_the_lesson_plays_from_the_start_to_below_the_threshold(bench, browser):
    page, tab = open_tab(bench, browser)
    show_tab(page, "Lesson")
    page.get_by_role("button", name="Open the lesson", exact=True).click()
    wait_for(lambda: lesson_line(page).startswith("0 · The start"), 120, "the lesson's start")
    wait_for(lambda: tab.landscape.terrain is not None, 120, "the slice through the truth, as a terrain")
    st = tab.state
    assert len(st.slice.slice.minima()) >= 4  # the small minima in the larger pit
    nxt = page.get_by_role("button", name="Next", exact=True)
    seen = []
    for title in ("1 · ICP runs", "2 · Stuck above the threshold", "3 · Annealing roams, temperature falling",
                  "4 · A lower point", "5 · ICP again", "6 · Below the threshold"):
        wait_for(lambda: nxt.is_enabled(), 120, "Next")
        nxt.click()
        wait_for(lambda t=title: lesson_line(page).startswith(t), 120, title)
        seen.append(title)
        if title.startswith("2"):  # ICP stopped above the threshold, in a marked local minimum
            assert "phase <b>ICP</b>" in tab.status.content and st.events[-1].local_minimum
            assert st.events[-1].error > st.threshold
        if title.startswith("4"):  # annealing ran to a lower point; ICP's next leg waits for the next click
            assert any(e.phase == "sa" for e in st.events) and st.events[-1].phase == "sa"
            assert st.events[-1].error < max(e.error for e in st.events if e.local_minimum)
    wait_for(lambda: "trust yes" in page.locator("body").inner_text() and "from the truth" in lesson_line(page), 120,
             "the run's end")
    assert re.search(r"E = [0-9.e+-]+ mm² is below the threshold", lesson_line(page))
    assert st.result.error < st.result.threshold
    assert len(seen) == 6 and not nxt.is_enabled()
    page.close()


def test_the_legend_names_every_colour_and_fit_view_frames_the_scans_then_the_terrain(bench, browser):
    from rangereg.app.figures import LEGEND, hex_colour
    from rangereg.app.tab.scene3d import shown_extent

    page, tab = open_tab(bench, browser)
    warnings = []
    page.on("console", lambda m: warnings.append(m.text) if m.type in ("warning", "error") else None)
    legend = page.locator(".rangereg-legend")
    for name, rgb in LEGEND:
        assert legend.get_by_text(name, exact=True).count() == 1
        assert legend.locator(f"span[style*='{hex_colour(rgb)}']").count() == 1, name
    camera = tab.client.camera
    camera.position = (40.0, 25.0, 40.0)  # far away and looking elsewhere: the scans are specks off to one side
    camera.look_at = (30.0, 0.0, 0.0)
    wait_for(lambda: np.allclose(camera.look_at, (30.0, 0.0, 0.0), atol=1e-3), 30, "the camera moved away")

    def in_view(points: np.ndarray) -> bool:
        """Whether every point lies inside the camera's vertical and horizontal field of view."""
        pos, at = np.asarray(camera.position), np.asarray(camera.look_at)
        ahead = (at - pos) / np.linalg.norm(at - pos)
        right = np.cross(ahead, (0.0, 1.0, 0.0))
        right /= np.linalg.norm(right)
        up = np.cross(right, ahead)
        rel = points - pos
        depth = rel @ ahead
        tan_v = np.tan(camera.fov / 2)
        return bool(np.all(depth > 0) and np.all(np.abs(rel @ up) <= tan_v * depth * 1.001)
                    and np.all(np.abs(rel @ right) <= tan_v * camera.aspect * depth * 1.001))

    with tab.state.lock:
        scans = shown_extent(tab.state)
    page.get_by_role("button", name="Fit view", exact=True).click()
    # wait for the camera's position as well as its target: under load (the full suite on 2 cores) the target was seen
    # moved while the position was still the old one
    wait_for(lambda: np.allclose(camera.look_at, 0.5 * (scans.min(0) + scans.max(0)), atol=1e-3)
             and np.linalg.norm(np.asarray(camera.position) - camera.look_at) < 10.0, 30, "Fit view")
    assert in_view(scans)
    # a terrain that appears brings the camera round to it and the scans
    show_tab(page, "Landscape")
    tab.landscape.h.steps.value = "9"
    page.get_by_label("Show as 3-D terrain", exact=True).check()
    page.get_by_role("button", name="Compute slice", exact=True).click()
    wait_for(lambda: tab.landscape.terrain is not None, 120, "the terrain")
    terrain = tab.landscape.terrain.extent()
    wait_for(lambda: in_view(terrain) and in_view(scans), 30, "the camera on the terrain")
    # the residual histogram draws without Plotly's colour warnings
    show_tab(page, "Model")
    page.get_by_label("Colour by residual", exact=True).check()
    page.locator(".js-plotly-plot .barlayer .point").first.wait_for(timeout=60_000)  # drawn: its logs are in
    assert not [w for w in warnings if not any(n in w for n in CLIENT_NOISE)], warnings
    page.close()
