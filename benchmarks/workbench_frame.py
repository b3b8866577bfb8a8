"""What one frame of the workbench costs the browser during a run, part of the scene by part.

    python benchmarks/workbench_frame.py [BUNNY_DIR] [--smallest]

Serves bun045 -> bun000 in this process and opens it in headless Chromium with the flags and the
1400 x 900 viewport of benchmarks/workbench_rate.py (software WebGL). While a long annealing run
moves the scan, it hides one part of the scene at a time from the server, in alternating rounds,
and prints for each: the frames the page draws a second, and the CPU time per drawn frame of
Chromium's GPU process (where software WebGL executes the frame, when the compositor reads it back)
and of its renderer (JavaScript, the panel's layout and paint). What a part costs is the drop when
it is hidden; what is left with every node hidden is the page's own cost of a frame (its
multisampled canvas and the read-back), which the server cannot change. The figures share 2 cores
with the optimiser: compare rows of one run, not runs. ``--smallest``: the bundled corner pair, each
part counted for 0.3 s in one round (a check that the script runs).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.browser import bunny_page  # noqa: E402

SECONDS = 3.0  # counted per part and round
ROUNDS = 2
FRAMES_JS = """(ms) => new Promise(done => {
  let n = 0; const t0 = performance.now();
  const tick = () => { n++; if (performance.now() - t0 < ms) requestAnimationFrame(tick); else done(n); };
  requestAnimationFrame(tick);
})"""


def chromium_cpu() -> dict[str, float]:
    """CPU seconds so far of this process's Chromium children, by kind (gpu-process, renderer, ...)."""
    import psutil

    out: dict[str, float] = {}
    for proc in psutil.Process().children(recursive=True):
        try:
            kind = next((a[7:] for a in proc.cmdline() if a.startswith("--type=")), "browser")
            t = proc.cpu_times()
            out[kind] = out.get(kind, 0.0) + t.user + t.system
        except psutil.Error:
            continue
    return out


def parts(nodes) -> dict[str, list]:
    """The scene's parts during a run, as lists of viser handles (app/tab/scene3d.SceneNodes)."""
    clouds = [c.light or c.points for c in (nodes.source, nodes.target)]
    path = [nodes.path, nodes.minima]
    viewpoints = [nodes.source.viewpoint, nodes.target.viewpoint]
    return {"as drawn": [], "path hidden": path, "moving clouds hidden": clouds,
            "every node hidden": clouds + path + viewpoints}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--smallest", action="store_true", help="the corner pair, 0.3 s per part, one round")
    a = ap.parse_args()
    seconds, rounds, settle = (0.3, 1, 0.1) if a.smallest else (SECONDS, ROUNDS, 1.0)
    folder, pair = (ROOT / "assets" / "corner", ("scan2.ply", "scan1.ply")) if a.smallest else \
        (Path(a.bunny), ("bun045.ply", "bun000.ply"))
    print(f"load average before: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    with bunny_page(folder, (1400, 900), pair) as (wb, _, page):
        tab = next(iter(wb.tabs.values()))
        tab.run_panel.h.settings.numbers["sa_max_evaluations"].value = "10000000"  # a run that outlasts the count
        tab.run_panel.start("sa")
        page.wait_for_function("() => document.body.innerText.includes('· running ·')", timeout=60_000)
        print(f"{'':22s} {'frames/s':>9s} {'GPU process ms/frame':>21s} {'renderer ms/frame':>18s}")
        for _ in range(rounds):
            for name, hidden in parts(tab.nodes).items():
                shown = [h.visible for h in hidden]
                for h in hidden:
                    h.visible = False
                time.sleep(settle)  # the hidden parts leave the page before the count
                before = chromium_cpu()
                frames = page.evaluate(FRAMES_JS, seconds * 1000)
                after = chromium_cpu()
                for h, v in zip(hidden, shown):
                    h.visible = v
                per = {k: 1000 * (after[k] - before.get(k, 0.0)) / max(frames, 1) for k in after}
                state = "" if tab.state.running else "  (the run had ended: not a measurement)"
                print(f"{name:22s} {frames / seconds:9.1f} {per.get('gpu-process', 0):21.0f} "
                      f"{per.get('renderer', 0):18.0f}{state}", flush=True)
        tab.state.run.cancel()
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
