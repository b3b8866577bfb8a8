"""What gives the corner its small minima: the plain corner scanned with a real scanner's faults, and folded faces.

    python benchmarks/lesson_minima.py [--starts 10]

Each variant is the paper's 4 ft corner seen from the corner scene's two viewpoints (core/simulate.py), the
scanner changed one fault at a time (range noise, range steps, the paper's sparse sampling) or the faces folded
into ribs (core.simulate.ribbed_corner_mesh: a regular pitch, and the lesson's pitch growing 80 -> 160 mm). For
each it prints the local minima of the lesson's tx-ry slice through the truth (core.landscape.Slice.minima, the
grid's points lower than their eight neighbours) and how many lie in the pit (E below half the slice's median:
the rest are dips in the flat rim, where the robust cap leaves E nearly level far from the truth), and ICP alone
from the lesson's starts and from the paper's spread (5 deg about a random axis and 250 mm, seeded): how often
it succeeds (within 1 deg and 1 % of the scene's size) and how often it is stuck (ends above the threshold, off
the truth). The lesson's scene is the last row.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from rangereg.core.landscape import compute_slice  # noqa: E402
from rangereg.core.problem import ProblemConfig, prepare  # noqa: E402
from rangereg.core.register import Config, register  # noqa: E402
from rangereg.core.scenes import LESSON  # noqa: E402
from rangereg.core.simulate import (  # noqa: E402
    Scanner,
    corner_mesh,
    look_at,
    ribbed_corner_mesh,
    scan_mesh,
    true_transform,
)
from rangereg.core.transforms import perturb, pose_error, random_perturbation  # noqa: E402

EYES = ((1750, 1150, 1350), (1150, 1750, 1300))  # the corner scene's (core/simulate.py)
TARGETS = ((250, 520, 420), (520, 250, 420))
PLAIN = Scanner(rows=85, cols=85, fov_deg=(52, 52))  # the corner scene's scanner
DENSE = Scanner(rows=120, cols=120, fov_deg=(52, 52))  # the lesson's
VARIANTS = (
    ("plain corner (the corner scene's scanner)", corner_mesh, PLAIN),
    ("plain, range noise 3 mm (0.8)", corner_mesh, replace(PLAIN, noise=3.0)),
    ("plain, ranges in 5 mm steps", corner_mesh, replace(PLAIN, quantum=5.0)),
    ("plain, ranges in 10 mm steps", corner_mesh, replace(PLAIN, quantum=10.0)),
    ("plain, 18 x 18 rays (the paper's ~300 points)", corner_mesh, replace(PLAIN, rows=18, cols=18)),
    ("plain, 18 x 18 rays, noise 3 mm, 5 mm steps", corner_mesh, replace(PLAIN, rows=18, cols=18, noise=3.0,
                                                                         quantum=5.0)),
    ("plain, the lesson's denser scanner", corner_mesh, DENSE),
    ("ribs +-30 mm, regular 120 mm pitch", lambda: ribbed_corner_mesh(pitch=(120.0, 120.0)), DENSE),
    ("ribs +-30 mm, pitch 160 -> 80 mm", lambda: ribbed_corner_mesh(pitch=(160.0, 80.0)), DENSE),
    ("ribs +-30 mm, pitch 80 -> 160 mm (the lesson)", ribbed_corner_mesh, DENSE),
)


def scans(mesh, scanner: Scanner, seed: int = 3):
    """(source, target) of the corner's two views of ``mesh`` (the lesson's scene uses seed 3)."""
    rng = np.random.default_rng(seed)
    verts, faces = mesh()
    target, source = (scan_mesh(verts, faces, look_at(e, t), scanner, rng, name=f"scan{i}")
                      for i, (e, t) in enumerate(zip(EYES, TARGETS), 1))
    return source, target


def in_pit(sl) -> int:
    """How many of the slice's local minima have E below half the slice's median E (measured: the plain corner's
    rim dips lie at 0.96-1.4 x the median, the ribbed corner's minima at 0.16-0.49 x)."""
    minima = sl.minima()
    i = np.searchsorted(sl.axis_a, minima[:, 0])
    j = np.searchsorted(sl.axis_b, minima[:, 1])
    return int(np.sum(sl.values[i, j] < 0.5 * np.median(sl.values)))


def icp_outcomes(source, target, T_true, starts) -> tuple[int, int]:
    """(successes, stuck) of ICP alone from each start, run k with seed k."""
    ok = stuck = 0
    for k, T0 in enumerate(starts):
        r = register(source, target, T0, Config(method="icp", seed=k))
        rot, tr = pose_error(r.transform, T_true, source.centroid)
        good = rot < 1.0 and tr < 0.01 * target.size
        ok += good
        stuck += (not good) and r.error >= r.threshold
    return ok, stuck


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=10, help="random starts at the paper's spread (default 10)")
    ap.add_argument("--smallest", action="store_true", help="the first variant, a 9 x 9 slice, one start of each kind")
    a = ap.parse_args()
    variants, steps, n_lesson = VARIANTS, LESSON.steps, len(LESSON.starts)
    if a.smallest:
        variants, steps, n_lesson, a.starts = VARIANTS[:1], 9, 1, 1
    print("| variant | minima of the tx-ry slice (in the pit) | ICP from the lesson's starts: right / stuck | ICP from "
          f"5 deg / 250 mm ({a.starts} seeded): right / stuck |")
    print("|---|---|---|---|")
    for name, mesh, scanner in variants:
        t0 = time.perf_counter()
        source, target = scans(mesh, scanner)
        T_true = true_transform(source, target)
        problem = prepare(source, target, T_true, ProblemConfig(), seed=0)
        sl = compute_slice(problem, T_true, LESSON.params, LESSON.spans, steps)
        lesson = [LESSON.start(source, target, k) for k in range(n_lesson)]
        rng = np.random.default_rng(0)
        c = T_true[:3, :3] @ source.centroid + T_true[:3, 3]
        paper = [perturb(T_true, np.r_[random_perturbation(rng, 5.0, 250.0)], c) for _ in range(a.starts)]
        ok_l, stuck_l = icp_outcomes(source, target, T_true, lesson)
        ok_p, stuck_p = icp_outcomes(source, target, T_true, paper)
        print(f"| {name} | {len(sl.minima())} ({in_pit(sl)}) | {ok_l} / {stuck_l} of {len(lesson)} | {ok_p} / "
              f"{stuck_p} of {len(paper)} |", flush=True)
        sys.stderr.write(f"  {name}: {time.perf_counter() - t0:.0f} s\n")


if __name__ == "__main__":
    main()
