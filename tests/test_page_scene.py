"""What a user sees in the page's scene, checked in a real browser: the campaign's model in view after Merge scans
from another scene, pick markers on the click, distinct legend colours, the residuals' words and layout, the pose
fields, the opening view."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest

from tests.conftest import BUNNY, wait_for
from tests.test_workbench import show_tab, text_input, wait_finished

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def data_bench():
    """A workbench in this process on its bundled scene (corner) with --data-dir the shared bunny scans."""
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans (../shared/data/bunny) are absent")
    yield from serving_folder(BUNNY)


def serving_folder(folder):
    """(Workbench, its URL) in this process on its bundled scene with --data-dir ``folder``; its tabs closed and
    the server stopped when the fixture ends."""
    from rangereg.app.access import free_port
    from rangereg.app.workbench import ServeOptions, Workbench

    port = free_port()
    wb = Workbench(ServeOptions(port=port, data_dir=str(folder)))
    yield wb, f"http://127.0.0.1:{port}"
    for tab in list(wb.tabs.values()):
        tab.close()
    wb.server.stop()


def open_tab(bench, browser, viewport=(1600, 1000)):
    wb, url = bench
    before = set(wb.tabs)
    page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
    page.goto(url)
    page.get_by_text("Initial E =").wait_for(timeout=120_000)
    wait_for(lambda: set(wb.tabs) - before, what="the new tab")
    tab = wb.tabs[(set(wb.tabs) - before).pop()]
    wait_for(lambda: tab.nodes is not None and _camera_known(tab), 60, what="the scene")
    return page, tab


def open_the_bunny(bench, browser):
    """A tab with the served bunny pair (bun045 onto bun000) opened from the Scans tab and its scene settled."""
    page, tab = open_tab(bench, browser)
    show_tab(page, "Scans")
    page.get_by_role("button", name="Open files", exact=True).click()
    wait_for(lambda: tab.state.target.name == "bun000", 120, what="the bunny pair")
    settled(page, tab)
    return page, tab


def _camera_known(tab) -> bool:
    try:
        return tab.client.camera.image_height > 0
    except AssertionError:
        return False


def project(tab, points: np.ndarray) -> np.ndarray:
    """(N, 2) canvas pixels of (N, 3) page points through the camera the browser reports (NaN behind it)."""
    cam = tab.client.camera
    pos, look, up = (np.asarray(v, np.float64) for v in (cam.position, cam.look_at, cam.up_direction))
    f = (look - pos) / np.linalg.norm(look - pos)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    rel = np.asarray(points, np.float64) - pos
    x, y, z = rel @ r, rel @ u, rel @ f
    tan_v = np.tan(cam.fov / 2)
    ndc = np.c_[x / z / (tan_v * cam.aspect), y / z / tan_v]
    ndc[z <= 0] = np.nan
    return np.c_[(ndc[:, 0] + 1) / 2 * cam.image_width, (1 - ndc[:, 1]) / 2 * cam.image_height]


def settled(page, tab) -> None:
    """Wait until the camera the browser reports holds still for a second (it reports a move in steps)."""
    def now():
        cam = tab.client.camera
        return np.r_[cam.position, cam.look_at]

    last, still = now(), 0
    for _ in range(60):
        page.wait_for_timeout(250)
        still = still + 1 if np.allclose(now(), last, atol=1e-9) else 0
        last = now()
        if still >= 4:
            return
    raise AssertionError("the camera did not settle")


def canvas_rgb(page) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(page.locator("canvas").first.screenshot())).convert("RGB")).astype(int)


def in_view(tab, points: np.ndarray) -> tuple[float, float]:
    """(share of the points inside the canvas, height of their projection as a share of the canvas's)."""
    px = project(tab, points)
    cam = tab.client.camera
    ok = np.isfinite(px).all(1)
    inside = ok & (px[:, 0] >= 0) & (px[:, 0] <= cam.image_width) & (px[:, 1] >= 0) & (px[:, 1] <= cam.image_height)
    span = np.ptp(px[ok, 1]) / cam.image_height if ok.any() else 0.0
    return float(inside.mean()), float(span)


def test_the_campaign_model_is_in_view_after_merge_scans_from_another_scene(data_bench, browser):
    from rangereg.app.figures import MODEL_RGB

    page, tab = open_tab(data_bench, browser)
    assert tab.state.target.name == "scan1"  # the corner is open, not the bunny
    show_tab(page, "Model")
    page.get_by_role("button", name="Merge scans", exact=True).click()
    # the report (how many are placed depends on the machine's load: the search is bounded in time when nothing is
    # trusted); whatever is placed is the model to show
    page.get_by_text(re.compile(r"of 4 scans placed · \d+ of \d+ pairs used")).first.wait_for(timeout=400_000)
    wait_for(lambda: tab.nodes.model is not None and tab.nodes.model.visible, what="the model")
    vertices = tab.nodes.model.vertices
    share, span = in_view(tab, vertices)
    assert share > 0.99 and span > 0.3, (share, span)  # framed, not a speck
    # the browser draws it: grey model pixels fill a good part of the canvas, and no scan or gizmo is drawn over it
    px = canvas_rgb(page)
    grey = (np.abs(px - np.array(MODEL_RGB)).max(2) < 60) & (np.ptp(px, axis=2) < 40) & (px.sum(2) < 700)
    assert grey.mean() > 0.02, grey.mean()
    assert not tab.nodes.gizmo.visible and not tab.nodes.source.points.visible
    # Fit view frames the model, from any camera
    tab.client.camera.position = tuple(np.asarray(tab.client.camera.look_at) + np.array([40.0, 5.0, 3.0]))
    page.get_by_role("button", name="Fit view", exact=True).click()
    settled(page, tab)
    wait_for(lambda: in_view(tab, vertices)[1] > 0.5, 20, what="the framed model")
    assert in_view(tab, vertices)[0] > 0.99
    page.close()


CAMPAIGN_LINES = """() => { window._campaign = [];
  const read = () => { const p = [...document.querySelectorAll('p')].find(e => /^(features|overlaps|pairs|graph|model)[ ,]/
      .test(e.innerText));
    const text = p ? p.innerText : '';
    if (text && window._campaign[window._campaign.length - 1] !== text) window._campaign.push(text); };
  new MutationObserver(read).observe(document.body, {subtree: true, childList: true, characterData: true}); }"""

UNCOVERED = """(el) => { const r = el.getBoundingClientRect();
  const x = r.left + Math.min(r.width / 2, 40), y = r.top + r.height / 2;
  const top = document.elementFromPoint(x, y); return top !== null && (el === top || el.contains(top)); }"""


def test_at_1280_by_720_the_campaign_report_leads_with_its_overall_line_and_its_headline_is_in_view(data_bench, browser):
    page, tab = open_tab(data_bench, browser, viewport=(1280, 720))
    show_tab(page, "Model")
    text_input(page, "Scans").fill("bun0[04]*")  # two scans: one pair
    page.evaluate(CAMPAIGN_LINES)
    page.get_by_role("button", name="Merge scans", exact=True).click()
    headline = page.locator("strong", has_text=re.compile(r"^2 of 2 scans placed$"))
    headline.wait_for(timeout=300_000)
    shown = [t.split("\n") for t in page.evaluate("() => window._campaign")]
    counts = re.compile(r"pairs, round \d+ \d+/\d+")
    # while it works and at its end, the overall line (the pairs registered) leads, the other lines below it
    assert any(counts.match(line) for lines in shown for line in lines), shown
    for lines in shown:
        assert all(not counts.match(line) for line in lines[1:]), lines
    report = shown[-1]
    assert counts.match(report[0]) and report[1].startswith("2 of 2 scans placed ·"), report
    assert [line.split(":")[0] for line in report[2:]] == ["bun000", "bun045"], report
    # the headline is in the viewport without scrolling, and nothing (a notification) is drawn over it
    box = headline.bounding_box()
    assert box["y"] >= 0 and box["y"] + box["height"] <= 720 and box["x"] + box["width"] <= 1280, box
    assert page.evaluate("() => document.scrollingElement.scrollTop") == 0
    notes = page.locator(".mantine-Notification-root")
    wait_for(lambda: notes.count() > 0, what="the campaign's notification")
    for i in range(notes.count()):
        n = notes.nth(i).bounding_box()
        assert n is None or n["x"] + n["width"] <= box["x"] or box["x"] + box["width"] <= n["x"] \
            or n["y"] + n["height"] <= box["y"] or box["y"] + box["height"] <= n["y"], (n, box)
    assert headline.evaluate(UNCOVERED)
    page.close()


def s1_label(tab):
    """The first source pick's label node, or None while it is not drawn yet."""
    return next((m for m in list(tab.pairs.markers) if getattr(m, "text", "") == "S1"), None)


def test_a_pick_marker_sits_on_the_click_and_every_click_on_the_source_picks(data_bench, browser):
    from rangereg.app.figures import SOURCE_OVERLAP_RGB, SOURCE_RGB

    page, tab = open_tab(data_bench, browser)
    show_tab(page, "Scans")  # the bunny pair (bun045 onto bun000): where the walk found the markers off
    page.get_by_role("button", name="Open files", exact=True).click()
    wait_for(lambda: tab.state.target.name == "bun000", 120, what="the bunny pair")
    show_tab(page, "Pose")
    said, rays = [], []
    clicked = tab.pairs.clicked
    tab.pairs.clicked = lambda o, d: (rays.append((o, d)), clicked(o, d))[1]
    notify = tab.notify
    tab.notify = lambda *a, **k: (said.append(a), notify(*a, **k))
    page.get_by_text("Pick point pairs").click()
    wait_for(lambda: not tab.nodes.gizmo.visible, what="the gizmo")  # it would take the clicks on the source
    settled(page, tab)
    for zoom in (1.0, 0.3):  # as opened, and zoomed in (where a depth-tested square showed 15-45 px off)
        if zoom != 1.0:  # zoomed in with the wheel, as a user does
            page.mouse.move(500, 500)
            for _ in range(4):
                page.mouse.wheel(0, -250)
                page.wait_for_timeout(300)
            settled(page, tab)
        px = canvas_rgb(page)
        orange = np.zeros(px.shape[:2], bool)
        for rgb in (SOURCE_RGB, SOURCE_OVERLAP_RGB):
            orange |= np.abs(px - np.array(rgb)).sum(2) < 30
        orange[:220, :360] = False  # the browser's note about software WebGL
        ys, xs = np.nonzero(orange)
        assert len(xs) > 500
        for k in np.random.default_rng(0).choice(len(xs), 6, replace=False):
            click = np.array([xs[k] + 0.5, ys[k] + 0.5])
            page.mouse.click(*click)
            # the pick is recorded before its markers are drawn (pairs.clicked: add, then show): wait for both
            wait_for(lambda: tab.pairs.pairs.pending is not None and s1_label(tab) is not None, 10,
                     what=f"a pick at {click} ({said})")
            label = s1_label(tab)
            assert label.position == pytest.approx(
                tab.state.display.source_local(tab.state.source.points[tab.pairs.pairs.pending]), abs=1e-6)
            # the marker's distance from the click, in pixels, measured on the browser's own click ray (the camera it
            # reports may lag a wheel zoom; the ray is the one it draws with)
            o, d = (np.asarray(v, np.float64) for v in rays[-1])
            d /= np.linalg.norm(d)
            rel = tab.pairs.marker_positions()["S1"] - o
            along = rel @ d
            pixel = along * 2 * np.tan(tab.client.camera.fov / 2) / tab.client.camera.image_height
            off = np.linalg.norm(rel - along * d) / pixel
            # within 3 px, or within the drawn point clicked on where zoomed in it is wider (viser draws a point
            # 2 x point_size wide, point_size 0.8 spacing: a half width of 0.8 spacing)
            half = 0.8 * tab.state.source.spacing / tab.state.display.size / pixel
            assert off <= (3.0 if zoom == 1.0 else max(3.0, half)), (zoom, off, half, click)
            tab.pairs.forget()
    page.get_by_text("Pick point pairs").click()
    wait_for(lambda: tab.nodes.gizmo.visible, what="the gizmo back")
    page.close()


def _lab(rgb) -> np.ndarray:
    c = np.asarray(rgb, float) / 255
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ c
    f = np.cbrt(xyz / np.array([0.9505, 1.0, 1.089]))
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


def legend_swatches(page) -> dict[str, str]:
    return page.evaluate("""() => Object.fromEntries([...document.querySelectorAll('.rangereg-legend > span')].map(
        s => [s.textContent.trim(), getComputedStyle(s.firstElementChild).backgroundImage !== 'none'
              ? getComputedStyle(s.firstElementChild).backgroundImage
              : getComputedStyle(s.firstElementChild).backgroundColor]))""")


def test_the_legend_colours_are_distinct_and_follow_the_residual_colouring(data_bench, browser):
    page, tab = open_tab(data_bench, browser)
    swatches = legend_swatches(page)
    assert {"source", "candidates", "source overlap", "local minimum"} <= set(swatches)
    rgb = {k: tuple(int(x) for x in re.findall(r"\d+", v)[:3]) for k, v in swatches.items()}
    names = sorted(rgb)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            assert np.linalg.norm(_lab(rgb[a]) - _lab(rgb[b])) > 25, (a, rgb[a], b, rgb[b])
    # residual colouring: the legend shows its scale, and no longer says yellow is the source's overlap
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_finished(page, 120)
    show_tab(page, "Model")
    page.get_by_label("Colour by residual", exact=True).check()
    wait_for(lambda: any("distance to the target" in k for k in legend_swatches(page)), what="the legend")
    swatches = legend_swatches(page)
    assert "source overlap" not in swatches and "source" not in swatches
    assert any("gradient" in v for v in swatches.values())
    # the summary says what beyond the cap means, without "outliers"
    body = page.locator("body").inner_text()
    assert "Beyond it:" in body and "outside the overlap cut" in body and "Outliers" not in body
    # the histogram: no title on the toolbar's edge, its legend under the plot, clear of the toolbar
    plot = page.locator(".js-plotly-plot").first
    plot.wait_for(timeout=60_000)
    plot.hover()
    assert plot.locator(".gtitle").count() == 0
    legend = plot.locator(".legend").first.bounding_box()
    area = plot.locator(".nsewdrag").first.bounding_box()
    assert legend["y"] >= area["y"] + area["height"], (legend, area)
    bar = plot.locator(".modebar").first.bounding_box()
    if bar is not None:
        assert bar["y"] + bar["height"] <= legend["y"] or bar["y"] >= legend["y"] + legend["height"]
    page.get_by_label("Colour by residual", exact=True).uncheck()
    wait_for(lambda: "source overlap" in legend_swatches(page), what="the legend back")
    page.close()


def _significant(text: str) -> int:
    digits = re.sub(r"[^0-9]", "", text.split("e")[0]).lstrip("0")
    return len(digits)


def test_pose_fields_are_the_initial_pose_in_4_digits_beside_the_runs_result(data_bench, browser):
    page, tab = open_tab(data_bench, browser)
    show_tab(page, "Pose")
    body = page.locator("body").inner_text()
    assert "Initial pose (where runs start)" in body and "No run yet" in body
    names = ("tx (mm)", "ty (mm)", "tz (mm)", "rx (deg)", "ry (deg)", "rz (deg)")
    shown = [text_input(page, n).input_value() for n in names]
    assert all(_significant(v) <= 4 for v in shown), shown
    assert any(float(v) != 0 for v in shown)
    T_init = tab.state.T_init.copy()
    # Apply with the fields as shown keeps the exact pose (the 4 digits are for reading)
    page.get_by_role("button", name="Apply pose", exact=True).click()
    page.wait_for_timeout(1500)
    assert np.allclose(tab.state.T_init, T_init, rtol=0, atol=1e-9)  # not rounded to the 4 digits shown
    show_tab(page, "Run")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_finished(page, 120)
    show_tab(page, "Pose")
    wait_for(lambda: "No run yet" not in page.locator("body").inner_text(), what="the result line")
    body = page.locator("body").inner_text()
    line = re.search(r"tx (\S+) mm · ty (\S+) mm · tz (\S+) mm · rx (\S+) deg · ry (\S+) deg · rz (\S+) deg", body)
    assert line, body
    from rangereg.core.transforms import to_params

    p = to_params(tab.state.result.transform)
    want = np.r_[p[:3], np.degrees(p[3:])]
    got = np.array([float(v) for v in line.groups()])
    assert np.allclose(got, want, rtol=1e-3, atol=1e-9) and all(_significant(v) <= 4 for v in line.groups())
    assert [text_input(page, n).input_value() for n in names] == shown  # the initial pose stays the initial pose
    page.get_by_role("button", name="Start from the result", exact=True).click()
    wait_for(lambda: np.allclose(tab.state.T_init, tab.state.T), what="the initial pose from the result")
    page.close()


def test_the_opening_view_frames_the_bunny_from_outside_its_frustums(data_bench, browser):
    from rangereg.app.tab.scene3d import _inside_frusta, shown_extent

    page, tab = open_the_bunny(data_bench, browser)
    st = tab.state
    eye = np.asarray(tab.client.camera.position)
    assert not _inside_frusta(eye, st.display, st.T, st.frusta[tab.run_panel.settings().frustum])
    share, span = in_view(tab, shown_extent(st))
    assert share == 1.0 and span > 0.6, (share, span)  # framed for the field of view the browser draws with (75 deg)
    # the scans, not the frustum lines, are most of what is drawn
    px = canvas_rgb(page)
    from rangereg.app.figures import SOURCE_RGB, TARGET_RGB, faded

    def count(rgb):
        return int((np.abs(px - np.array(rgb)).sum(2) < 30).sum())

    assert count(SOURCE_RGB) + count(TARGET_RGB) > 5 * (count(faded(SOURCE_RGB)) + count(faded(TARGET_RGB)))
    page.close()


def test_the_first_pair_is_seen_upright_from_the_opening_view_the_page_chose(data_bench, browser):
    # the first pair of a page (drawn as the browser connects): the camera the browser reports is the one the page set,
    # +y up (a pose sent with the first change of up was read in viser's +z frame: the scans seen on their side)
    from rangereg.app.tab.scene3d import default_view

    page, tab = open_tab(data_bench, browser)
    settled(page, tab)
    st = tab.state
    eye, look_at = default_view(st.display, st.target, st.source, st.T, st.frusta[tab.run_panel.settings().frustum])
    cam = tab.client.camera
    assert np.allclose(cam.up_direction, (0.0, 1.0, 0.0), atol=1e-6), cam.up_direction
    assert np.allclose(cam.position, eye, atol=1e-4) and np.allclose(cam.look_at, look_at, atol=1e-4), (cam.position, eye)
    # the page's +y points up the screen
    up = project(tab, np.array([look_at, look_at + np.array([0.0, 0.2, 0.0])]))
    assert up[1, 1] < up[0, 1] - 20 and abs(up[1, 0] - up[0, 0]) < 1, up
    page.close()


def test_the_gizmo_is_sized_to_the_scans_on_the_opening_view(data_bench, browser):
    # its handles reach a small share of the scans' height on screen (a fixed size drew them half the bunny's height
    # across from the closer opening view), and are still there to grab
    from rangereg.app.tab.scene3d import shown_extent

    page, tab = open_the_bunny(data_bench, browser)
    st = tab.state
    centre = project(tab, np.asarray(st.display.node_pose(st.T)[1], np.float64)[None])[0]
    px = canvas_rgb(page)
    r, g, b = px[..., 0], px[..., 1], px[..., 2]
    crimson = (r > 220) & (g < 70) & (b > 80) & (b < 130)  # the gizmo's x handles: a colour no scan has
    crimson[-120:, :120] = False  # the orientation axes in the corner
    ys, xs = np.nonzero(crimson)
    assert len(xs) > 20, "the gizmo is not on screen"
    reach = float(np.hypot(xs - centre[0], ys - centre[1]).max())
    _, span = in_view(tab, shown_extent(st))
    scans = span * tab.client.camera.image_height
    assert 25 < reach < 0.25 * scans, (reach, scans)
    page.close()


def _icp_points_spread(page) -> float:
    """The horizontal spread of the E chart's ICP points, as a share of its plotting canvas's width."""
    from PIL import Image
    from rangereg.app.figures import PHASE_RGB

    canvas = page.locator(".uplot canvas").first
    px = np.asarray(Image.open(io.BytesIO(canvas.screenshot())).convert("RGB")).astype(int)
    green = np.abs(px - np.array(PHASE_RGB["icp"])).sum(2) < 40
    xs = np.nonzero(green.any(0))[0]
    return float(np.ptp(xs) / px.shape[1]) if len(xs) else 0.0


def test_a_run_on_a_pair_in_other_units_is_charted_over_its_own_iterations(data_bench, browser):
    # the chart's axes are in the scans' units: a pair in other units once re-labelled the old chart, and viser's
    # client then read its kept x range against the new data (the lesson's 148 iterations, then a 72-iteration bunny
    # run drawn on 0-10,000: every point in a column at 0)
    page, tab = open_tab(data_bench, browser)
    assert tab.scans.h.scene.value == "corner"  # the page opened on its bundled scene
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_finished(page)
    show_tab(page, "Scans")
    page.get_by_role("button", name="Open files", exact=True).click()  # the bunny, in metres
    wait_for(lambda: tab.state.target.name == "bun000", 120, what="the bunny pair")
    wait_for(lambda: "Method - · idle" in page.locator(".rangereg-status").inner_text(), 10,
             what="the status's method (the corner's run is not the bunny's)")
    assert tab.scans.h.scene.value == "-"  # the Scene dropdown no longer says "corner"
    show_tab(page, "Run")
    page.get_by_role("button", name="Run ICP", exact=True).click()
    wait_finished(page)
    assert "log10 E (m²)" in str(tab.run_panel.h.plot.axes)
    wait_for(lambda: _icp_points_spread(page) > 0.6, 10, what=f"the chart's x range ({_icp_points_spread(page):.2f})")
    page.close()


def test_another_pair_takes_the_old_pairs_slice_off_the_landscape_tab(data_bench, browser):
    page, tab = open_tab(data_bench, browser)
    show_tab(page, "Landscape")
    tab.landscape.h.steps.value = "5"
    page.get_by_role("button", name="Compute slice", exact=True).click()
    page.locator(".js-plotly-plot:visible").first.wait_for(timeout=120_000)
    assert "scan2 → scan1" in page.locator(".js-plotly-plot:visible").first.inner_text()
    show_tab(page, "Scans")
    page.get_by_role("button", name="Open files", exact=True).click()
    wait_for(lambda: tab.state.target.name == "bun000", 120, what="the bunny pair")
    show_tab(page, "Landscape")
    wait_for(lambda: page.locator(".js-plotly-plot:visible").count() == 0, 10, what="the corner's contour")
    page.close()
