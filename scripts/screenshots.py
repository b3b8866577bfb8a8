"""The README's pictures of the workbench, taken in headless Chromium: docs/lesson.png, docs/landscape.png,
docs/residuals.png, docs/workbench.png.

    python scripts/screenshots.py [BUNNY_DIR] [--lesson-only]

The first is the Lesson tab played to its end (the paper's Fig. 7 on the ribbed corner): the workbench in this
process on its default scene, the lesson opened at its shown start, Next clicked through every step, the
frustums hidden and Fit view pressed, so the scans, the terrain with the run's path and the E chart are in view.

Serves bun045 -> bun000 (the Stanford bunny, metres) with the workbench in this process, starts from
60 degrees off the files' pose about the vertical, computes the tx-ry slice around that start, shows it
as the 3-D terrain, runs the hybrid, hides the frustums, then points the camera at the terrain and waits
until the page's camera says it is there before taking the picture. Then it hides the terrain, ticks
"Colour by residual" on the Model tab (the source coloured by its distance to the target at the
hybrid's pose, the histogram with the cap), hides the gizmo and points the camera back at the scans
for the second picture. The third is an annealing run from the same start, paused after 4 s, with the
frustums shown. The camera's position is set before
its look-at point: viser moves the look-at point along with a new position (keeping the orientation),
which is why a camera set the other way round never looked at the terrain.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.browser import bunny_page  # noqa: E402

START_DEG = 60.0  # the initial pose: this far off the files' pose, about the target's vertical axis
SLICE = ("tx", "ry", "0.04", "75", "41")  # parameters, spans (m, deg) and steps of the slice
LOOK_AT = (1.6, -0.3, 0.0)  # page units: the terrain's box is centred at app.tab.terrain.TERRAIN_AT; a little
# right of its centre, so that the terrain sits left of the control panel
CAMERA_AT = (1.3, 1.05, 1.25)  # in front of the terrain, 45 degrees above it, a little to the scans' side
LESSON_VIEW = (1.2, 1.9, 2.4)  # the lesson's picture looks from here at LOOK_AT, then Fit view frames scans and terrain
CLOSE_NOTICE_JS = """() => {
  const el = [...document.querySelectorAll('div')].find(d => d.innerText.startsWith('Software WebGL rendering'));
  let n = el; while (n && !n.querySelector('button')) n = n.parentElement;
  if (n) n.querySelector('button').click();
}"""


def wait_for(test, timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if test():
            return
        time.sleep(0.2)
    raise SystemExit(f"timed out waiting for {what}")


def turned(T: np.ndarray, degrees: float, about: np.ndarray) -> np.ndarray:
    """T followed by a rotation of ``degrees`` about the vertical (y) through ``about`` (target frame)."""
    from scipy.spatial.transform import Rotation

    D = np.eye(4)
    D[:3, :3] = Rotation.from_euler("y", degrees, degrees=True).as_matrix()
    D[:3, 3] = about - D[:3, :3] @ about
    return D @ T


def scans_camera(st) -> np.ndarray:
    """Where the page's camera opens (app/tab/scene3d.draw_pair): behind the target's sensor, looking at the scans."""
    eye = st.display.points(st.target.viewpoint).astype(np.float64)
    return 1.5 * eye / max(np.linalg.norm(eye), 1e-9) + np.array([0.0, 0.3, 0.0])


def lesson_shot(viewport: tuple[int, int] = (1600, 1000)) -> None:
    """docs/lesson.png: the Lesson tab played to its end."""
    from benchmarks.browser import served_page

    with served_page(viewport) as (wb, _browser, page):
        tab = next(iter(wb.tabs.values()))
        page.get_by_role("tab", name="Lesson", exact=True).click()
        page.get_by_role("button", name="Open the lesson", exact=True).click()
        wait_for(lambda: tab.lesson.story is not None and tab.landscape.terrain is not None, 300, "the lesson")
        nxt = page.get_by_role("button", name="Next", exact=True)
        while tab.lesson.story.step not in ("below", "gave-up") or tab.state.running:
            wait_for(lambda: nxt.is_enabled() or not tab.state.running and tab.lesson.story.step == "below", 300,
                     "Next")
            if nxt.is_enabled():
                nxt.click()
                time.sleep(0.3)  # the click reaches the server
        wait_for(lambda: "from the truth" in tab.lesson.line, 120, "the lesson's end")
        tab.scans.h.show.frustums.value = False
        tab.apply_visibility()
        page.evaluate(CLOSE_NOTICE_JS)
        camera = tab.client.camera
        camera.position = LESSON_VIEW  # the direction Fit view keeps: above and in front of scans and terrain
        camera.look_at = LOOK_AT
        wait_for(lambda: np.allclose(camera.position, LESSON_VIEW, atol=1e-3), 30, "the camera")
        page.get_by_role("button", name="Fit view", exact=True).click()
        wait_for(lambda: not np.allclose(camera.position, LESSON_VIEW, atol=1e-3), 30, "Fit view")
        time.sleep(3.0)  # the terrain's labels settle
        page.mouse.move(5, 5)
        out = ROOT / "docs" / "lesson.png"
        page.screenshot(path=str(out))
        print(f"wrote {out}")


def main() -> None:
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    lesson_shot()
    if "--lesson-only" in sys.argv:
        return
    folder = Path(args[0]) if args else ROOT.parent / "shared" / "data" / "bunny"
    with bunny_page(folder, (1600, 1000)) as (wb, _, page):
        tab = next(iter(wb.tabs.values()))
        st = tab.state
        source_centre = st.T_file[:3, :3] @ st.source.centroid + st.T_file[:3, 3]
        tab.set_initial(turned(st.T_file, START_DEG, source_centre))
        tab.update_status()
        page.get_by_role("tab", name="Landscape", exact=True).click()
        h = tab.landscape.h
        h.param_a.value, h.param_b.value = SLICE[:2]
        h.span_a.value, h.span_b.value, h.steps.value = SLICE[2:]
        page.get_by_role("button", name="Compute slice", exact=True).click()
        wait_for(lambda: st.slice is not None, 900, "the slice")
        page.get_by_label("Show as 3-D terrain", exact=True).check()
        wait_for(lambda: tab.landscape.terrain is not None, 60, "the terrain")
        page.get_by_role("tab", name="Run", exact=True).click()
        page.get_by_role("button", name="Run hybrid", exact=True).click()
        page.get_by_text("Finished:").wait_for(timeout=300_000)
        wait_for(lambda: len(tab.landscape.terrain.segments.points) >= len(st.events), 60, "the path on the terrain")
        page.get_by_role("tab", name="Scans", exact=True).click()
        tab.scans.h.show.frustums.value = False
        tab.apply_visibility()
        page.get_by_role("tab", name="Landscape", exact=True).click()
        page.evaluate(CLOSE_NOTICE_JS)  # the software-WebGL notice
        camera = tab.client.camera
        camera.up_direction = (0.0, 1.0, 0.0)
        camera.position = CAMERA_AT  # first: setting the position moves the look-at point with it
        camera.look_at = LOOK_AT
        wait_for(lambda: np.allclose(camera.position, CAMERA_AT, atol=1e-3)
                 and np.allclose(camera.look_at, LOOK_AT, atol=1e-3), 30, "the camera")
        time.sleep(3.0)
        out = ROOT / "docs" / "landscape.png"
        page.screenshot(path=str(out))
        print(f"wrote {out}")
        tab.landscape.h.terrain.value = False
        tab.landscape.update_terrain()
        page.get_by_role("tab", name="Model", exact=True).click()
        page.get_by_label("Colour by residual", exact=True).check()
        wait_for(lambda: tab.model.residuals.plot is not None and st.residual_rgb is not None, 120, "the residuals")
        page.mouse.move(5, 5)  # off the checkbox: its hint would cover the panel
        tab.nodes.gizmo.visible = False  # the picture is about the colours
        scans_at = tuple(float(x) for x in scans_camera(st))
        camera.position = scans_at
        camera.look_at = (0.0, 0.0, 0.0)
        wait_for(lambda: np.allclose(camera.position, scans_at, atol=1e-3)
                 and np.allclose(camera.look_at, (0.0, 0.0, 0.0), atol=1e-3), 30, "the camera")
        time.sleep(3.0)
        out = ROOT / "docs" / "residuals.png"
        page.screenshot(path=str(out))
        print(f"wrote {out}")
        page.get_by_label("Colour by residual", exact=True).uncheck()
        tab.scans.h.show.frustums.value = True
        tab.apply_visibility()
        page.get_by_role("tab", name="Run", exact=True).click()
        page.get_by_role("button", name="Reset", exact=True).click()
        page.get_by_role("button", name="Run SA", exact=True).click()
        page.get_by_text("· running ·").wait_for(timeout=60_000)
        time.sleep(4.0)
        page.get_by_role("button", name="Pause", exact=True).click()
        page.get_by_text("· paused ·").wait_for(timeout=30_000)
        page.mouse.move(5, 5)
        time.sleep(3.0)
        out = ROOT / "docs" / "workbench.png"
        page.screenshot(path=str(out))
        print(f"wrote {out}")
        page.get_by_role("button", name="Cancel", exact=True).click()


if __name__ == "__main__":
    main()
