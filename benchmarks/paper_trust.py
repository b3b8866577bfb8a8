"""Trust, whichever method: does the paper's methods' "trust yes" ever fall on a wrong pose?

    python benchmarks/paper_trust.py [--runs 10] [--families scenes,lesson,bunny,lidar,small]
    python benchmarks/paper_trust.py --smallest      # the corner's first start, whole and small: a check that it runs

The paper trusts a pose whose E ends below the threshold; since 2026-12-08 the paper's methods ask the pair
threshold's test as well (core.verdict). This counts, per family and method, the runs that are right or wrong and
which of them each rule trusts: "E below" (the paper's rule alone) and "trusted" (the paper's rule and the test).

The rules, fixed before any result was seen (2026-12-08):
- Methods: ``hybrid`` and ``icp``, the paper's, each run k with seed k.
- scenes: the bench's generated scenes (corner, wing, bowl; app/bench.py), its seeded starts (5 deg and the
  scene's translation spread about the truth), ``--runs`` starts each; right: the bench's (1 deg, 1 % of the size).
- lesson: the lesson's scene (the ribbed wall) from its own starts; right as the scenes.
- bunny: the bench's four shared bunny pairs from its starts (15 deg, 25 mm); right: 2 deg, 2 mm.
- lidar: the shared LiDAR pair (../shared/data/lidar, truth in relative.txt) from the identity and from
  ``--runs`` - 1 starts 5 deg / 0.5 m about the truth; right: 1 deg, 5 cm.
- small: the scenes and the lesson with ``--max-points`` 10, 20 and 50 (the paper's E uses 165-341 points), 4
  starts each (a sample of a few points fits wrong poses below the threshold).
A run trusted and wrong is a defect; a run right and not trusted is a miss.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT.parent))

SHARED = ROOT.parent / "shared" / "data"
FAMILIES = ("scenes", "lesson", "bunny", "lidar", "small")
METHODS = ("hybrid", "icp")
SMALL = (10, 20, 50)


def cases(family: str, runs: int):
    """(case, [(label, start T0, max_points or None)]) of ``family``."""
    from rangereg.app.bench import bunny_cases, lesson_case, scene_cases, starts
    from rangereg.app.workbench import ASSETS
    from rangereg.core.scenes import LESSON

    if family in ("scenes", "small"):
        scene = [(c, starts(c, runs if family == "scenes" else min(runs, 4))) for c in scene_cases()]
        lesson = lesson_case(ASSETS)
        scene.append((lesson, [LESSON.start(lesson.source, lesson.target, k)
                               for k in range(min(len(LESSON.starts), runs if family == "scenes" else 4))]))
        if family == "scenes":
            scene = scene[:-1]
        sizes = (None,) if family == "scenes" else SMALL
        return [(c, [(f"start {k}" + (f", {m} points" if m else ""), T0, m) for m in sizes for k, T0 in enumerate(T0s)])
                for c, T0s in scene]
    if family == "lesson":
        c = lesson_case(ASSETS)
        return [(c, [(f"start {k}", LESSON.start(c.source, c.target, k), None)
                     for k in range(min(len(LESSON.starts), runs))])]
    if family == "bunny":
        return [(c, [(f"start {k}", T0, None) for k, T0 in enumerate(starts(c, runs))])
                for c in bunny_cases(SHARED / "bunny")]
    if family == "lidar":
        return lidar_case(runs)
    raise SystemExit(f"unknown family {family!r}")


def lidar_case(runs: int):
    from rangereg.app.cases import Case
    from rangereg.app.sweep_sensors import family_pairs
    from rangereg.core.guess import Guess
    from rangereg.core.problem import ProblemConfig
    from rangereg.core.transforms import perturb, random_perturbation

    if not (SHARED / "lidar").is_dir():
        return []
    pair = family_pairs("lidar", quick=False, data=SHARED)[0]
    source, target, T = pair.load()
    case = Case(pair.name, source, target, T, 5.0, 0.5, 1.0, 0.05, ProblemConfig(), Guess.identity())
    rng = np.random.default_rng(0)
    c = T[:3, :3] @ source.centroid + T[:3, 3]
    T0s = [("identity", np.eye(4), None)]
    for k in range(runs - 1):
        t, r = random_perturbation(rng, 5.0, 0.5)
        T0s.append((f"start {k}", perturb(T, np.r_[t, r], c), None))
    return [(case, T0s)]


def run(case, method: str, T0: np.ndarray, max_points: int | None, seed: int) -> tuple[bool, bool, bool, float]:
    """(right, E below the threshold, trusted, seconds) of one run."""
    from rangereg.core.register import Config, register
    from rangereg.core.transforms import pose_error

    problem = case.problem if max_points is None else replace(case.problem, max_points=max_points)
    res = register(case.source, case.target, case.stated.at(T0), Config(method=method, seed=seed, problem=problem))
    rot, move = pose_error(res.transform, case.T_true, case.source.centroid)
    return (rot < case.ok_rot and move < case.ok_trans, bool(res.error < res.threshold), bool(res.below_threshold),
            res.seconds)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--families", default=",".join(FAMILIES))
    ap.add_argument("--smallest", action="store_true")
    a = ap.parse_args()
    runs = 1 if a.smallest else a.runs
    families = ("scenes", "small") if a.smallest else a.families.split(",")
    print(f"load {os.getloadavg()[0]:.1f}, {runs} starts a case\n")
    table = []
    for family in families:
        for method in METHODS:
            counts = dict(runs=0, right=0, e_below_wrong=0, trusted_wrong=0, e_below_right=0, trusted_right=0)
            seconds = []
            t0 = time.perf_counter()
            for case, starts_ in cases(family, runs)[:1 if a.smallest else None]:
                for k, (label, T0, m) in enumerate(starts_[:1] if a.smallest else starts_):
                    ok, below, trusted, sec = run(case, method, T0, m, k)
                    seconds.append(sec)
                    counts["runs"] += 1
                    counts["right"] += ok
                    counts["e_below_right" if ok else "e_below_wrong"] += below
                    counts["trusted_right" if ok else "trusted_wrong"] += trusted
                    if trusted and not ok:
                        print(f"  DEFECT {family} {method} {case.name} {label}: trusted and wrong", flush=True)
                    elif below and not ok:
                        print(f"  {family} {method} {case.name} {label}: E below, wrong, now doubted", flush=True)
                    elif below and ok and not trusted:
                        print(f"  {family} {method} {case.name} {label}: E below, right, now doubted (a miss)",
                              flush=True)
            table.append((family, method, counts, float(np.median(seconds)) if seconds else float("nan"),
                          time.perf_counter() - t0))
            print(f"{family} {method}: {counts} ({table[-1][4]:.0f} s)", flush=True)
    print(f"\nload {os.getloadavg()[0]:.1f}\n")
    print("| family | method | runs | right | E below: right / wrong | trusted: right / wrong | median s |")
    print("|---|---|---|---|---|---|---|")
    for family, method, c, med, _ in table:
        print(f"| {family} | {method} | {c['runs']} | {c['right']} | {c['e_below_right']} / {c['e_below_wrong']} | "
              f"{c['trusted_right']} / {c['trusted_wrong']} | {med:.2f} |")


if __name__ == "__main__":
    main()
