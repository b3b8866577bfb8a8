"""The evidence for the merge's polish rule (core.merge_tasks: POLISH_STEP_DEG, POLISH_STEP_SPACINGS,
POLISH_MORE_MATCHING): every trusted pair's polish in a set of campaigns, how far it moved the pose, how the share of
the pair matching (core.merge_tasks.share_at) changed, and how far the pose lay from the truth before and after.

    python benchmarks/polish_evidence.py [--families rgbd,lidar,turntable,crops,bunny]
    python benchmarks/polish_evidence.py --smallest   # a street of 3 small LiDAR frames: a check that it runs

Campaigns (fixed on 2026-12-06, the set the rule was first measured on): rgbd, the six RGB-D drives of
benchmarks/sequences.py (steps 0.1, 0.2 and 0.4 m, seeds 0 and 1); lidar, four of its LiDAR drives (street 1 m seed 0
and 2 m seed 1, room 0.5 m seed 0 and 1 m seed 1); turntable, benchmarks/campaign.py's three families of the 24-stop
turntable (seed 0); crops, its crops 0 from the frame starts; bunny, benchmarks/campaign_bunny.py's ten campaigns
(when ../shared/data/bunny is present). Each polish is recorded as the merge runs (the campaign itself is unchanged).

Prints one line per polish that moves the pose beyond the small step, whether the rule takes it, and per family the
largest change of the share a small polish made: the noise POLISH_MORE_MATCHING must stand above.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from rangereg.core import merge_tasks as mt  # noqa: E402
from rangereg.core.transforms import invert, pose_error  # noqa: E402

FAMILIES = ("rgbd", "lidar", "turntable", "crops", "bunny")


class Recorder:
    """Wraps core.merge_tasks.polished: each trusted pair's pose before and after the polish against the truth."""

    def __init__(self):
        self.rows: list[dict] = []
        self.family, self.label, self.truth = "", "", []
        self._polished, self._polish = mt.polished, mt.polish

    def __enter__(self) -> Recorder:
        last = {}

        def polish(*args, **kwargs):
            last["P"] = self._polish(*args, **kwargs)
            return last["P"]

        def polished(shared, task, T):
            out = self._polished(shared, task, T)
            source, target = mt.built(shared, task.j)[0], mt.built(shared, task.i)[0]
            P, truth = last.pop("P"), invert(self.truth[task.i]) @ self.truth[task.j]
            rot, move = pose_error(P, T, source.centroid)
            self.rows.append(dict(family=self.family, label=self.label, i=task.i, j=task.j, move_deg=rot,
                                  move_spacings=move / max(source.spacing, target.spacing),
                                  before=mt.share_at(shared, task.i, task.j, T), after=mt.share_at(shared, task.i, task.j, P),
                                  err_before=pose_error(T, truth, source.centroid),
                                  err_after=pose_error(P, truth, source.centroid),
                                  taken=out is not T))
            return out

        mt.polish, mt.polished = polish, polished
        return self

    def __exit__(self, *exc) -> None:
        mt.polish, mt.polished = self._polish, self._polished


def campaigns(families: list[str], smallest: bool):
    """(family, label, scans, truth, merge keyword arguments) per campaign of the module notes."""
    from dataclasses import replace

    from rangereg.core.guess import Guess
    from rangereg.core.turntable import FAMILIES as STARTS
    from rangereg.core.turntable import TurntableConfig, make_campaign, rough_poses
    from sequences import frames

    if smallest:
        scans, truth = frames("street", 1.0, 0, smallest=True)
        yield "lidar", "street of 3 small frames", scans, truth, dict(pairs="sequence")
        return
    drives = {"rgbd": [("rgbd", s, seed) for s in (0.1, 0.2, 0.4) for seed in (0, 1)],
              "lidar": [("street", 1.0, 0), ("street", 2.0, 1), ("room", 0.5, 0), ("room", 1.0, 1)]}
    for family in ("rgbd", "lidar"):
        if family in families:
            for scene, step, seed in drives[family]:
                scans, truth = frames(scene, step, seed)
                yield family, f"{scene} {step:g} m seed {seed}", scans, truth, dict(pairs="sequence")
    if "turntable" in families or "crops" in families:
        from rangereg.app.crops import crop

        camp = make_campaign(0, TurntableConfig(scans=24))
        truth = [s.pose for s in camp.scans]
        for family, cut, starts in (("turntable", False, STARTS), ("crops", True, ("frame",))):
            if family not in families:
                continue
            scans = [replace(crop(s, 0) if cut else s, guess=None, pose=None) for s in camp.scans]
            for start in starts:
                initial = None if start == "identity" else rough_poses(truth, start, 15.0, 0.1 * camp.size, 0)
                yield family, f"turntable, {start}", scans, truth, dict(initial=initial, stated=Guess.identity(15.0))
    if "bunny" in families:
        from campaign_bunny import BUNNY, OFFSET_DEG, SHIFT
        from campaign_bunny import campaigns as bunny_campaigns

        if not BUNNY.is_dir():
            print(f"{BUNNY}: the shared bunny scans are absent; bunny left out")
            return
        for label, scans, start in bunny_campaigns(None):
            truth = [s.pose for s in scans]
            initial = None if start == "none" else rough_poses(truth, "frame", OFFSET_DEG, SHIFT, start)
            yield "bunny", label, [replace(s, guess=None, pose=None) for s in scans], truth, dict(
                initial=initial, stated=Guess.identity(OFFSET_DEG))


def arguments(doc: str) -> tuple[list[str], bool]:
    """The families asked for (``--families``, checked) and ``--smallest``, for a script of these campaigns."""
    ap = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    ap.add_argument("--families", default=",".join(FAMILIES), help=f"comma-separated of {', '.join(FAMILIES)}")
    ap.add_argument("--smallest", action="store_true", help="one street of 3 small frames: a check that it runs")
    a = ap.parse_args()
    families = [f for f in a.families.split(",") if f]
    if not set(families) <= set(FAMILIES):
        ap.error(f"--families takes {', '.join(FAMILIES)}")
    return families, a.smallest


def main() -> int:
    from rangereg.core.config import Config
    from rangereg.core.merge import clear_geometry_cache, merge

    families, smallest = arguments(__doc__)
    print(f"load {os.getloadavg()[0]:.1f}", flush=True)
    with Recorder() as rec:
        for family, label, scans, truth, kwargs in campaigns(families, smallest):
            clear_geometry_cache()
            rec.family, rec.label, rec.truth = family, label, truth
            merge(scans, config=Config(method="global"), build_model=False, **kwargs)
            mine = sum(r["family"] == family and r["label"] == label for r in rec.rows)
            print(f"  {family}: {label}: {mine} polishes", flush=True)
    rows = rec.rows
    small = [r for r in rows if r["move_deg"] < mt.POLISH_STEP_DEG and r["move_spacings"] < mt.POLISH_STEP_SPACINGS]
    print(f"\n{len(rows)} polishes, {len(small)} within the small step; load {os.getloadavg()[0]:.1f}")
    print("\n| family | polishes | small | largest share change of a small polish | larger polishes |")
    print("|---|---|---|---|---|")
    for family in dict.fromkeys(r["family"] for r in rows):
        mine = [r for r in small if r["family"] == family]
        change = max((abs(r["after"] - r["before"]) for r in mine), default=float("nan"))
        print(f"| {family} | {sum(r['family'] == family for r in rows)} | {len(mine)} | {change:.4f} | "
              f"{sum(r['family'] == family for r in rows) - len(mine)} |")
    print("\nlarger polishes (degrees / units at the source's centroid):")
    for r in rows:
        if r in small:
            continue
        print(f"  {r['family']}: {r['label']}: {r['i']} -> {r['j']} moved {r['move_deg']:.2f} deg / "
              f"{r['move_spacings']:.1f} spacings; share {r['before']:.3f} -> {r['after']:.3f}; off "
              f"{r['err_before'][0]:.2f} deg / {r['err_before'][1]:.3g} -> {r['err_after'][0]:.2f} deg / "
              f"{r['err_after'][1]:.3g}; {'taken' if r['taken'] else 'refused'}")
    every = np.array([r["err_after"][0] - r["err_before"][0] for r in small]) if small else np.zeros(0)
    if len(every):
        print(f"\nsmall polishes: rotation error after minus before, median {np.median(every):.3f} deg, "
              f"max {every.max():.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
