"""The Run panel and the Lesson as an operator and a class see them, in a real browser (Debian's Chromium, Playwright):
the default method first, a result line that leads with trust, Pause at once, the lesson's sentences quoting the
status, the lesson at 1280 x 720.

The workbench runs in this process (tests/conftest.bench), so a test reads the tab's state beside the page.
"""

from __future__ import annotations

import re
import time

import numpy as np
import pytest

from tests.conftest import ROOT, wait_for
from tests.test_teach import open_tab
from tests.test_workbench import show_tab, wait_cancelled, wait_finished

pytestmark = pytest.mark.browser
ARTIFACTS = ROOT / "artifacts"
NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:e[+-]\d+)?")


def status_text(page) -> str:
    return page.locator(".rangereg-status").inner_text()


def test_the_default_method_is_the_first_button_and_the_papers_methods_are_grouped_under_it(bench, browser):
    from rangereg.app.tab.run import GLOBAL_BUTTON, PAPERS_FOLDER, RUN_BUTTONS

    page, tab = open_tab(bench, browser)
    labels = [t.strip() for t in page.locator("button").all_inner_texts()]
    runs = [t for t in labels if t in RUN_BUTTONS]
    assert runs[0] == GLOBAL_BUTTON and set(runs) == set(RUN_BUTTONS), runs
    y = {t: page.get_by_role("button", name=t, exact=True).bounding_box()["y"] for t in RUN_BUTTONS}
    folder = page.get_by_text(PAPERS_FOLDER, exact=True).bounding_box()["y"]
    assert all(y[GLOBAL_BUTTON] < folder < y[t] for t in RUN_BUTTONS if t != GLOBAL_BUTTON), (y, folder)
    # the threshold row says which threshold it is: the paper's E threshold until Run global shows its own
    assert re.search(r"Threshold \S+ mm² \(the paper's, on E: from the scans' noise\)", status_text(page))
    page.close()


def test_the_result_line_leads_with_trust_and_advises_only_when_not_trusted(bench, browser):
    page, tab = open_tab(bench, browser)
    page.get_by_role("button", name="Run global", exact=True).click()
    line = wait_finished(page)
    assert line.startswith("trust yes:") and "What to do" not in status_text(page), line
    assert re.search(r"Pair threshold \S+ mm² \(Run global's test", status_text(page))
    # the row never wraps: where the panel is narrow its words are cut, its value stays in view
    page.set_viewport_size({"width": 1280, "height": 720})
    page.wait_for_timeout(500)
    assert page.evaluate(VALUE_IN_VIEW, "Pair threshold "), status_text(page)
    page.close()


VALUE_IN_VIEW = """(name) => { const row = [...document.querySelectorAll('.rangereg-status > div')].find(
    d => d.textContent.startsWith(name)); const node = row.firstChild;
  const value = node.textContent.match(/^[^(]*?\\d\\S* \\S+²/);  // the name, the value and its unit
  if (!value) return false;
  const r = document.createRange(); r.setStart(node, 0); r.setEnd(node, value[0].length);
  return r.getBoundingClientRect().right <= row.getBoundingClientRect().right; }"""


def test_icp_stuck_from_the_run_tab_says_trust_no_then_what_to_do_and_ends_the_lesson(bench, browser):
    page, tab = open_tab(bench, browser)
    show_tab(page, "Lesson")
    page.get_by_role("button", name="Open the lesson", exact=True).click()
    wait_for(lambda: "Lesson: 0 · The start" in status_text(page), 120, "the lesson's start")
    show_tab(page, "Run")
    page.get_by_role("button", name="Run ICP", exact=True).click()  # ICP alone stops in the lesson's local minimum
    line = wait_finished(page)
    text = status_text(page)
    assert line.startswith("trust no:"), line
    assert "What to do: Run global" in text and text.index("trust no") < text.index("What to do"), text
    assert "Lesson:" not in text and tab.lesson.story is None  # a run from the Run tab ends the lesson
    assert tab.lesson.h.next.disabled
    page.close()


PAUSED_AT = """() => { window._paused = 0; window._down = 0;
  document.addEventListener('mousedown', () => { window._down = window._down || Date.now(); }, true);
  new MutationObserver((_, obs) => { if (document.body.innerText.includes('· paused ·')) {
    window._paused = Date.now(); obs.disconnect(); } }).observe(document.body, {subtree: true, childList: true,
    characterData: true}); }"""


def test_pause_says_paused_within_a_third_of_a_second_of_the_click_and_the_run_stops(bench, browser):
    # a click where the button is (the browser's own input path, as a user's), timed in the page from the click
    # reaching it to the status saying "paused": what the page's code takes (the server, the runner, the refresher).
    # Playwright's own click first waits for a busy page to look stable, and on a loaded machine the browser's input
    # queue waits behind its frames: neither is the page's doing (both are printed when this fails)
    page, tab = open_tab(bench, browser)
    st = tab.state
    seconds, clicks = [], []

    def seen(step: str, k: int) -> str:  # what a failure message shows: the step, the status and the tab's state
        return (f"click {k + 1}, {step}: paused {st.paused}, events {len(st.events)}, "
                f"status: {status_text(page)!r}")

    def wait_until(predicate, timeout: float, step: str, k: int) -> None:
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                raise AssertionError(f"not within {timeout} s: " + seen(step, k))
            time.sleep(0.05)

    for k in range(3):
        page.get_by_role("button", name="Reset", exact=True).click()
        page.get_by_role("button", name="Run SA", exact=True).click()  # annealing alone: a long run
        wait_until(lambda: "· running ·" in status_text(page), 60, "waiting for the run", k)
        time.sleep(1.0)
        box = page.get_by_role("button", name="Pause", exact=True).bounding_box()
        page.evaluate(PAUSED_AT)
        t0 = time.time()
        page.mouse.click(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        wait_until(lambda: page.evaluate("() => window._paused > 0"), 30, f"Pause clicked at {box}", k)
        paused, down = page.evaluate("() => [window._paused, window._down]")
        seconds.append((paused - down) / 1000.0)
        clicks.append(paused / 1000.0 - t0)
        n = len(st.events)
        time.sleep(0.5)
        # it stopped (at most the move under way when clicked)
        assert st.paused and len(st.events) <= n + 1, seen(f"0.5 s after paused ({n} events then)", k)
        page.get_by_role("button", name="Cancel", exact=True).click()
        wait_cancelled(page)
    # the best of three: a loaded machine delays some clicks, not every one
    assert min(seconds) < 0.3, f"click reached the page -> paused {seconds} s; mouse click -> paused {clicks} s"
    page.close()


def test_a_cancelled_run_leads_with_the_cancel_and_its_pose_so_far_not_with_a_finished_verdict(bench, browser):
    page, tab = open_tab(bench, browser)
    page.get_by_role("button", name="Run SA", exact=True).click()  # annealing alone: a long run
    wait_for(lambda: len(tab.state.events) > 20, 60, "the run's moves")
    page.get_by_role("button", name="Cancel", exact=True).click()
    wait_cancelled(page)
    text = status_text(page)
    counts = re.search(r"Iterations: ICP (\d+), SA (\d+)", text)
    result = text[text.index("Guess"):].split("\n", 1)[1]  # what follows the progress rows: the run's end
    m = re.match(r"Cancelled at iteration (\d+): E = (\S+) mm², the best pose so far \(not trusted\)\n", result)
    assert m and int(m.group(1)) == int(counts.group(1)) + int(counts.group(2)) == len(tab.state.events), text
    assert float(m.group(2)) == pytest.approx(tab.state.result.error, rel=1e-3)
    assert "Finished" not in text and "trust no" not in text and "What to do" not in text, text
    # the status's E row says so too (not "the result"), and the chart draws no result level
    said = re.search(r"\nE = (\S+) mm² \(cancelled: the best pose so far, not a result\)", text)
    assert said and "(the result)" not in text, text
    assert np.isfinite(tab.run_panel.h.plot.data[-1]).sum() <= 1  # only the first value uPlot takes its range from
    assert tab.pose.h.result.content.endswith("(cancelled: the best pose so far, not trusted)")  # the Pose tab's too
    # the replay's end tells the same story: the pose shown is the best so far, E the status's, and it says so (its
    # last event, annealing's last move, is another pose with another E)
    show_tab(page, "Landscape")
    line = page.get_by_text(re.compile(r"^Event \d+ of \d+")).first
    line.wait_for(timeout=10_000)
    n = len(tab.state.events)
    m = re.match(rf"Event {n} of {n}, the run's end: E = (\S+) mm² \(cancelled: the best pose so far, not a result\), "
                 r"the pose shown\. Its last event: .* E = (\S+) mm²", line.inner_text())
    assert m and m.group(1) == said.group(1), (line.inner_text(), text)
    assert float(m.group(2)) == pytest.approx(tab.state.events[-1].error, rel=1e-3)
    assert np.allclose(tab.state.T, tab.state.result.transform)  # the scene shows the pose both name
    page.close()


UNCOVERED = """(el) => { const r = el.getBoundingClientRect();
  if (r.width === 0 || r.top < 0 || r.left < 0 || r.bottom > innerHeight || r.right > innerWidth) return false;
  // not scrolled out of its panel nor covered: near its corners (inside the panel's overlay scrollbar) and at its centre
  // the page shows it
  const dx = Math.min(12, r.width / 4), dy = Math.min(12, r.height / 4);
  const at = [[r.left + dx, r.top + dy], [r.right - dx, r.top + dy], [r.left + dx, r.bottom - dy],
              [r.right - dx, r.bottom - dy], [(r.left + r.right) / 2, (r.top + r.bottom) / 2]];
  return at.every(([x, y]) => { const e = document.elementFromPoint(x, y); return e !== null && el.contains(e); }); }"""


def uncovered(locator) -> bool:
    """Whether the element is wholly in the window, unscrolled and uncovered (UNCOVERED)."""
    return locator.count() > 0 and all(locator.nth(k).evaluate(UNCOVERED) for k in range(locator.count()))


def contour(page):
    """The lesson's contour: the Plotly figure on show (the Landscape tab's is on a hidden tab)."""
    return page.locator(".js-plotly-plot:visible")


def test_the_lesson_at_1280_by_720_keeps_its_contour_next_and_the_charts_axis_titles_in_view_and_its_sentences_quote_the_status(
        bench, browser):
    from rangereg.app.figures import fmt

    wb, url = bench
    before = set(wb.tabs)
    page = browser.new_page(viewport={"width": 1280, "height": 720})
    page.goto(url)
    page.get_by_text("Initial E =").wait_for(timeout=60_000)
    (key,) = set(wb.tabs) - before
    tab = wb.tabs[key]
    show_tab(page, "Lesson")
    page.get_by_role("button", name="Open the lesson", exact=True).click()
    wait_for(lambda: tab.lesson.view is not None and tab.lesson.h.plot is not None, 120, "the lesson's contour")
    nxt = page.get_by_role("button", name="Next", exact=True)

    def in_view(locator) -> bool:
        box = locator.bounding_box()
        return box is not None and box["y"] >= 0 and box["y"] + box["height"] <= 720

    assert in_view(nxt) and in_view(page.get_by_role("tab", name="Lesson", exact=True))
    # with no scrolling: the contour the sentences speak of, the tabs, Next and the chart's axis titles, all at once
    wait_for(lambda: contour(page).count() == 1, 30, "the contour on show")
    page.wait_for_timeout(1000)  # the panel docked and the contour drawn
    assert uncovered(contour(page)), contour(page).first.bounding_box()
    assert uncovered(page.get_by_role("tab", name="Lesson", exact=True)) and uncovered(nxt)
    # uPlot draws its axes and their titles in its canvas: the whole chart, title to legend, is on show
    assert uncovered(page.locator(".uplot")), page.locator(".uplot").first.bounding_box()
    # the start as the contour draws it (the path's first point on the slice)
    sentence = tab.lesson.h.text.content
    start = tab.landscape.path.xy[0]
    assert f"tx = {fmt(start[0])} mm and ry = {fmt(start[1])}°" in sentence, sentence
    # and the Start dropdown's own numbers, so its tx and the sentence's do not read as two starts
    chosen = re.match(r"\d+: (\S+) mm, (\S+)°", str(tab.lesson.h.start.value))
    assert f"the Start's {chosen[1]} mm is about" in sentence and chosen[2] == fmt(start[1]), (chosen[0], sentence)
    words = page.get_by_text(re.compile(r"^0 · The start\.")).last
    assert in_view(words), words.bounding_box()  # the whole sentence above the fold, under Next
    steps = []
    while True:
        wait_for(lambda: nxt.is_enabled() or "Finished" in status_text(page), 120, "Next")
        if not nxt.is_enabled():
            break
        before = steps[-1] if steps else "start"
        nxt.click()
        wait_for(lambda b=before: tab.lesson.story.step != b, 60, "the click")
        time.sleep(0.3)
        wait_for(lambda: tab.lesson.run_state() != "running", 120, "the step's run")
        wait_for(lambda: nxt.is_enabled() or "Finished" in status_text(page), 120, "Next")
        time.sleep(0.5)  # the last push of a step: the status and the sentence are written together
        step, sentence, status = tab.lesson.story.step, tab.lesson.h.text.content, status_text(page)
        steps.append(step)
        page.screenshot(path=str(ARTIFACTS / f"lesson-1280x720-{len(steps)}.png")) if ARTIFACTS.is_dir() else None
        assert in_view(nxt) or step == "below"
        assert uncovered(contour(page)), (step, contour(page).first.bounding_box())
        assert step == "below" or in_view(page.get_by_text(sentence.split("**")[1], exact=False).last)
        assert f"Lesson: {tab.lesson.title}" in status
        body = sentence.split("**", 2)[2]
        shown = body.replace(" Click Next to let the run finish.", "")
        for number in NUMBER.findall(shown):
            assert number in status, (step, number, sentence, status)
        if step == "stuck":
            assert "phase ICP" in status and "local minima 1" in status
            # the red marker the sentence speaks of is on the Lesson tab's own contour, with its legend entry
            wait_for(lambda: "ICP's local minimum" in [t.name for t in tab.lesson.h.plot.figure.data], 30,
                     "the run's minimum on the lesson's contour")
        if step in ("anneal", "lower"):  # paused where annealing's leg ended: its phase and temperature
            assert "phase SA" in status and re.search(r"temperature \d", status), status
        if len(steps) > 10:
            break
    assert steps[:6] == ["icp", "stuck", "anneal", "lower", "icp-again", "below"], steps
    assert "trust yes" in status_text(page)
    page.close()


def test_the_empty_chart_has_its_axes_and_replay_shows_no_timeline_without_a_run(bench, browser):
    page, tab = open_tab(bench, browser)
    data = tab.run_panel.h.plot.data
    assert len(data[0]) >= 2 and data[0][-1] > data[0][0]  # an x range: uPlot draws the iteration axis
    assert all(np.isfinite(s[0]) for s in data[1:])  # every series starts with a number (its range)
    show_tab(page, "Landscape")
    page.get_by_text("No run to replay yet.").wait_for(timeout=10_000)
    assert not tab.replay.slider.visible
    assert page.get_by_text(re.compile(r"\d+ of \d+")).count() == 0
    page.close()
