"""Closest points on a surface and the robust error: throughput on this machine.

    python benchmarks/closest_points.py [BUNNY_DIR] [--smallest]

Prints closest-point queries per second against the 40,256-point bun000 surface (target: >= 200,000)
and the time of one robust-error evaluation over 300 points (target: <= 1 ms). Medians of 7 repeats.
``--smallest``: the bundled corner pair, 2,000 queries, one repeat (a check that the script runs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.core.io import load_scan  # noqa: E402
from rangereg.core.problem import prepare  # noqa: E402
from rangereg.core.surface import Surface  # noqa: E402


def median_time(fn, repeats=7) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--smallest", action="store_true", help="the corner pair, 2,000 queries, one repeat")
    a = ap.parse_args()
    folder = ROOT / "assets" / "corner" if a.smallest else Path(a.bunny)
    names = ("scan1", "scan2") if a.smallest else ("bun000", "bun045")
    n, repeats = (2_000, 1) if a.smallest else (200_000, 7)
    target, source = (load_scan(folder / f"{name}.ply") for name in names)
    surface = Surface.from_scan(target)
    rng = np.random.default_rng(0)
    noise = 4 * target.spacing if a.smallest else 0.002  # 2 mm on the bunny: 4 point spacings
    queries = target.points[rng.integers(0, len(target.points), n)] + rng.normal(0, noise, (n, 3))
    surface.closest(queries[:1000])  # build the scene once
    t = median_time(lambda: surface.closest(queries), repeats)
    print(f"closest points: {len(queries) / t:,.0f} queries/s against {len(target.points)} points "
          f"({surface.n_triangles} triangles); {t / len(queries) * 1e6:.2f} us per query")
    T = np.linalg.inv(target.pose) @ source.pose
    problem = prepare(source, target, T)
    t = median_time(lambda: [problem.error(T) for _ in range(100)], repeats) / 100
    print(f"robust error over {len(problem.points)} points: {t * 1e3:.3f} ms per evaluation")


if __name__ == "__main__":
    main()
