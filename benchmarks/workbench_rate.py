"""How often the workbench page updates during a run, with two 40,000-point bunny scans loaded.

    python benchmarks/workbench_rate.py [BUNNY_DIR] [--smallest]

Starts `rangereg serve bun045.ply bun000.ply` on a free port, opens it in headless Chromium,
presses "Run SA" (a long run), and, once the page says it is running, counts in the browser how
often the status panel (sent in one batch with the pose and the path on every push, so it changes
only in a frame that draws them) changes over 5 s, and how many frames the page draws meanwhile; then
clicks "Pause" from inside the page and times, in the page, until it says "paused" (Playwright's
own click waits for the busy page to look stable, which is not what a user waits for). Then it
computes a 21 x 21 slice, shows it as the 3-D terrain, and counts again during a second run.
Targets: >= 10 updates per second with the terrain hidden, >= 6 with it shown; Pause within 0.2 s.
``--smallest``: the bundled corner pair, counts of 0.5 s and a 5 x 5 slice (a check that the script runs).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.app.access import free_port  # noqa: E402

from benchmarks.browser import launch  # noqa: E402

PAUSE_JS = """() => new Promise(done => {
  const button = [...document.querySelectorAll('button')].find(b => b.innerText.trim() === 'Pause');
  const t0 = performance.now();
  setTimeout(() => done(-1), 10000);
  const obs = new MutationObserver(() => {
    if (document.body.innerText.includes('paused')) { obs.disconnect(); done(performance.now() - t0); }
  });
  obs.observe(document.body, {subtree: true, childList: true, characterData: true});
  button.click();
})"""
FRAMES_JS = """(ms) => new Promise(done => {
  let n = 0; const t0 = performance.now();
  const tick = () => { n++; if (performance.now() - t0 < ms) requestAnimationFrame(tick); else done(n * 1000 / ms); };
  requestAnimationFrame(tick);
})"""
COUNT_JS = """(ms) => new Promise(done => {
  const el = document.querySelector('.rangereg-status');  // the status block (app/tab/status.py)
  let n = 0; const obs = new MutationObserver(() => n++);
  obs.observe(el.parentElement, {subtree: true, childList: true, characterData: true});
  setTimeout(() => { obs.disconnect(); done(n); }, ms);
})"""
COUNT_S, FRAMES_S, STEPS = 5.0, 3.0, 21  # the counts' lengths and the slice's grid (--smallest: 0.5 s, 0.5 s, 5)


RUNNING = "() => document.body.innerText.includes('· running ·')"


def count(page, what: str, count_s: float = COUNT_S, frames_s: float = FRAMES_S) -> None:
    """Status updates and frames during a run that is running (said on the page) before and after the count."""
    page.wait_for_function(RUNNING, timeout=60_000)
    time.sleep(min(1.0, count_s))
    n = page.evaluate(COUNT_JS, count_s * 1000)
    still = page.evaluate(RUNNING)
    print(f"status/path updates during the run, {what}: {n / count_s:.1f} per second"
          + ("" if still else " (the run ended during the count: not a measurement)"))
    print(f"frames the page draws during the run: {page.evaluate(FRAMES_JS, frames_s * 1000):.1f} per second")


def main() -> None:
    from playwright.sync_api import sync_playwright

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--smallest", action="store_true", help="the corner pair, 0.5 s counts, a 5 x 5 slice")
    a = ap.parse_args()
    counts, steps = ((0.5, 0.5), 5) if a.smallest else ((COUNT_S, FRAMES_S), STEPS)
    folder, pair = (ROOT / "assets" / "corner", ("scan2.ply", "scan1.ply")) if a.smallest else \
        (Path(a.bunny), ("bun045.ply", "bun000.ply"))
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (the figures are noisy above ~2)")
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "rangereg.app.cli", "serve", *(str(folder / f) for f in pair),
                             "--port", str(port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        while "rangereg workbench:" not in proc.stdout.readline():
            if proc.poll() is not None:
                raise SystemExit("the server did not start")
        with sync_playwright() as p:
            browser = launch(p)
            page = browser.new_page(viewport={"width": 1400, "height": 900})
            t0 = time.perf_counter()
            page.goto(f"http://127.0.0.1:{port}")
            page.get_by_text("Initial E =").wait_for(timeout=120_000)
            print(f"page ready with both scans in {time.perf_counter() - t0:.1f} s")
            page.get_by_role("button", name="Run SA", exact=True).click()
            count(page, "terrain hidden", *counts)
            print(f"Pause click to 'paused' on the page: {page.evaluate(PAUSE_JS):.0f} ms (-1: not within 10 s)")
            page.get_by_role("button", name="Cancel", exact=True).click()
            page.get_by_role("button", name="Reset", exact=True).click()
            page.get_by_role("tab", name="Landscape", exact=True).click()
            field = page.locator("label", has_text=re.compile("^Steps$")).first.locator("xpath=ancestor::div[2]")
            field.locator("input").fill(str(steps))
            t0 = time.perf_counter()
            page.get_by_role("button", name="Compute slice", exact=True).click()
            page.get_by_text("log10 E(").first.wait_for(timeout=600_000)
            print(f"{steps} x {steps} slice in {time.perf_counter() - t0:.1f} s")
            page.get_by_label("Show as 3-D terrain", exact=True).check()
            time.sleep(min(2.0, counts[0]))
            page.get_by_role("tab", name="Run", exact=True).click(timeout=120_000)
            page.get_by_role("button", name="Run SA", exact=True).click()
            count(page, "terrain shown", *counts)
            page.get_by_role("button", name="Cancel", exact=True).click()
            browser.close()
            print(f"load average after: {os.getloadavg()[0]:.1f}")
    finally:
        proc.terminate()
        proc.wait(10)


if __name__ == "__main__":
    main()
