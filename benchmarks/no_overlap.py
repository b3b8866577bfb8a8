"""Pairs of scans that share nothing, registered with no guess: a pose said "trust yes" there is a defect.

    python benchmarks/no_overlap.py [--families turntable-crops,turntable-whole,bunny-crops] [--pairs 30]
    python benchmarks/no_overlap.py --smallest   # two pairs of the turntable's crops: a check that it runs

A user who drops two files that do not overlap (a wrong pair, a campaign's scans from opposite sides) must be told
"trust no": no pose is right. Rules (fixed on 2026-12-07 before the first run; the turntable's crops were looked at
first, in a session's script, for the crop pair 0 -> 14 that a campaign had trusted 150 degrees off):

- families: the 24-stop simulated turntable (core.turntable, seed 0) as crops 0 (app.crops: a quarter to 0.6 of each
  scan's range grid) and whole; the four shared bunny scans' crops 0-2 (../shared/data/bunny; skipped when absent),
  pairs of two different scans only;
- "share nothing": at the truth no point of either scan lies within 1.5 point spacings of the other's points
  (core.merge_tasks.share_at's gate); every such pair j -> i (i < j) in order, ``--pairs`` of them spread evenly;
- each registered as `rangereg register` with no guess does (core.register, Guess.none at the identity, the default
  global method, seed 0);
- a trusted pose is a defect (there is no right one); the seconds are the registration's, in this process.

The first run took a pair where one scan's 2000-point sample had no point near the other, which is weaker than "share
nothing"; a review found it, and the rule above (every point, both ways) was set before the run docs/benchmarks.md
quotes.
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
sys.path.insert(0, str(ROOT))

BUNNY = ROOT.parent / "shared" / "data" / "bunny"
FAMILIES = ("turntable-crops", "turntable-whole", "bunny-crops")
GATE_SPACINGS = 1.5  # core.merge_tasks.Shared.polish_gate: "within" for share_at


def scans_of(family: str) -> list:
    """(scan, T_world_scan, the scan it was cut from) of the family (module notes); [] where its data is absent."""
    from rangereg.app.crops import crop

    if family.startswith("turntable"):
        from rangereg.core.turntable import TurntableConfig, make_campaign

        camp = make_campaign(0, TurntableConfig(scans=24))
        cut = family == "turntable-crops"
        return [(replace(crop(s, 0) if cut else s, guess=None, pose=None), s.pose, s.name) for s in camp.scans]
    from rangereg.core.io import load_scan

    if not BUNNY.is_dir():
        return []
    out = []
    for name in ("bun000", "bun045", "bun090", "bun315"):
        s = load_scan(BUNNY / f"{name}.ply")
        out += [(replace(crop(s, k), guess=None, pose=None), s.pose, name) for k in (0, 1, 2)]
    return out


def shares(a, b, T_a_b: np.ndarray) -> bool:
    """Whether any point of either scan lies within GATE_SPACINGS point spacings of the other's points under T_a_b
    (a's frame from b's)."""
    from rangereg.core.transforms import apply, invert

    gate = GATE_SPACINGS * max(a.spacing, b.spacing)
    for x, y, T in ((b, a, T_a_b), (a, b, invert(T_a_b))):
        d, _ = y.tree.query(apply(T, x.points), distance_upper_bound=gate)
        if np.isfinite(d).any():
            return True
    return False


def pairs_of(scans: list, most: int) -> tuple[list[tuple[int, int]], int]:
    """The pairs that share nothing at the truth (module notes), ``most`` of them spread evenly, and how many there are."""
    from rangereg.core.transforms import invert

    apart = [(i, j) for i in range(len(scans)) for j in range(i + 1, len(scans))
             if scans[i][2] != scans[j][2] and not shares(scans[i][0], scans[j][0], invert(scans[i][1]) @ scans[j][1])]
    if len(apart) <= most:
        return apart, len(apart)
    return [apart[k] for k in np.linspace(0, len(apart) - 1, most).round().astype(int)], len(apart)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--families", default=",".join(FAMILIES), help=f"comma-separated of {', '.join(FAMILIES)}")
    ap.add_argument("--pairs", type=int, default=30, help="pairs a family at most (default 30)")
    ap.add_argument("--smallest", action="store_true", help="two pairs of the turntable's crops")
    a = ap.parse_args()
    families = ["turntable-crops"] if a.smallest else [f for f in a.families.split(",") if f]
    if not set(families) <= set(FAMILIES):
        ap.error(f"--families takes {', '.join(FAMILIES)}")
    if a.pairs < 1:
        ap.error("--pairs takes 1 or more")
    most = 2 if a.smallest else a.pairs

    from rangereg.core.config import Config
    from rangereg.core.errors import InputError
    from rangereg.core.guess import Guess
    from rangereg.core.quiet import quiet_open3d
    from rangereg.core.register import register
    from rangereg.core.transforms import invert, pose_error

    quiet_open3d()  # RANSAC's "too few correspondences" on pairs that share nothing: noise here

    print(f"load {os.getloadavg()[0]:.1f}", flush=True)
    rows = []
    for family in families:
        scans = scans_of(family)
        if not scans:
            print(f"{family}: skipped ({BUNNY} is absent)")
            continue
        pairs, apart = pairs_of(scans, most)
        print(f"{family}: {len(scans)} scans, {apart} pairs that share nothing, {len(pairs)} of them registered", flush=True)
        for i, j in pairs:
            (target, P_i, _), (source, P_j, _) = scans[i], scans[j]
            t0 = time.perf_counter()
            try:
                res = register(source, target, Guess.none(), Config(method="global", seed=0))
            except InputError as exc:  # e.g. no overlap at a candidate: refused, which is "trust no"
                rows.append((family, False, time.perf_counter() - t0))
                print(f"  {source.name} -> {target.name}: refused ({exc})", flush=True)
                continue
            sec = time.perf_counter() - t0
            c = res.verdict.constraint
            rot, move = pose_error(res.transform, invert(P_i) @ P_j, source.centroid)
            rows.append((family, res.trusted, sec))
            if res.trusted:
                pinned = "unmeasured" if c is None else (
                    f"ratio {c.ratio:.4f}, rise {c.rise if c.rise is None else round(c.rise, 3)}")
                print(f"  DEFECT {source.name} -> {target.name}: trusted, {rot:.1f} deg / {move:.3g} {source.units} from "
                      f"the truth (found by {res.found_by}; misfit {res.verdict.misfit:.2f}, {pinned}, {sec:.1f} s)", flush=True)
    print(f"\nload {os.getloadavg()[0]:.1f}\n")
    print("| family | pairs | trusted (defects) | median s |")
    print("|---|---|---|---|")
    for family in dict.fromkeys(r[0] for r in rows):
        mine = [r for r in rows if r[0] == family]
        print(f"| {family} | {len(mine)} | {sum(r[1] for r in mine)} | {np.median([r[2] for r in mine]):.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
