"""Where a campaign's registrations spend their time: every registration a merge makes, by its start (the rough poses,
the identity of a sequence's odometry, the graph's pose, no guess), by the stage of the search that found its pose
(core.global_search: the guess, KISS-Matcher, the rotation samples, FPFH + RANSAC, the hybrid), trusted or not, right
or not, used by the final graph or not, a twin or not (its pose refused by the free-space test: core.intrusion), and
its seconds.

    python benchmarks/campaign_stages.py [--families rgbd,lidar,turntable,crops,bunny]
    python benchmarks/campaign_stages.py --smallest   # a street of 3 small LiDAR frames: a check that it runs

The campaigns are benchmarks/polish_evidence.py's (the RGB-D and LiDAR drives of benchmarks/sequences.py, the 24-stop
turntable's three families and its crops from the frame starts, the bunny campaigns). Right (fixed before the first
run, 2026-12-07, as each campaign's own benchmark judges a scan): for the drives within 1 degree and 5 cm at the
frame's origin; for the objects within 2 degrees and 2 mm at the source's centroid (the pair's pose, polished when
trusted). Each registration is recorded by the task map the merge runs its tasks with (core.merge.serial_map's plain
loop: the campaign itself is unchanged). The question it answers: what an untrusted pair costs against a
trusted one from the same start, and which stages ever give a pose the graph uses.
"""

from __future__ import annotations

import os
import sys
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from polish_evidence import arguments, campaigns  # noqa: E402
from rangereg.core import merge_tasks as mt  # noqa: E402
from rangereg.core.transforms import invert, pose_error  # noqa: E402

DRIVES = ("rgbd", "lidar")  # right within 1 deg / 5 cm at the frame's origin; the objects 2 deg / 2 mm at the centroid
MM = {"m": 1000.0, "mm": 1.0, "cm": 10.0}


def stage_of(found_by: str) -> str:
    """The stage a pose came from ("kiss-matcher, refined on the whole scans" -> "kiss-matcher")."""
    return (found_by or "-").split(",")[0]


def right(family: str, T, T_true, source) -> bool:
    if family in DRIVES:
        rot, move = pose_error(T, T_true)
        return rot < 1.0 and move < 0.05
    rot, move = pose_error(T, T_true, source.centroid)
    return rot < 2.0 and move * MM.get(source.units, 1.0) < 2.0


def main() -> int:
    from rangereg.core.config import Config
    from rangereg.core.merge import clear_geometry_cache, merge, serial_map

    families, smallest = arguments(__doc__)
    print(f"load {os.getloadavg()[0]:.1f}", flush=True)
    rows, recorded = [], []

    def recording(fn, items, shared, label=None, done=None):
        """The merge's plain loop (core.merge.serial_map), keeping each registration's task and outcome."""
        out = serial_map(fn, items, shared, label, done)
        if fn is mt.pair_task:
            recorded.extend(zip(items, out))
        return out

    for family, label, scans, truth, kwargs in campaigns(families, smallest):
        clear_geometry_cache()
        recorded.clear()
        t0 = time.perf_counter()
        res = merge(scans, config=Config(method="global"), build_model=False, map_tasks=recording, **kwargs)
        final = {(p.i, p.j): p for p in res.pairs}
        last = {(t.i, t.j): n for n, (t, _) in enumerate(recorded)}  # the registration the final graph judged
        for n, (t, o) in enumerate(recorded):
            used = last[t.i, t.j] == n and (t.i, t.j) in final and str(final[t.i, t.j].status) == "used"
            rows.append((family, str(t.start), stage_of(o.found_by), bool(o.trusted),
                         right(family, o.T, invert(truth[t.i]) @ truth[t.j], scans[t.j]), used, o.seconds, o.twin))
        print(f"  {family}: {label}: {len(recorded)} registrations, {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"\nload {os.getloadavg()[0]:.1f}\n")
    print("| family | start | found by | trusted | registrations | right | used | used and right | twins | seconds | "
          "median s |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    groups = defaultdict(list)
    for row in rows:
        groups[row[:4]].append(row)
    for key in sorted(groups):
        g = groups[key]
        secs = sorted(r[6] for r in g)
        print(f"| {key[0]} | {key[1]} | {key[2]} | {'yes' if key[3] else 'no'} | {len(g)} | {sum(r[4] for r in g)} | "
              f"{sum(r[5] for r in g)} | {sum(r[4] and r[5] for r in g)} | {sum(r[7] for r in g)} | {sum(secs):.1f} | "
              f"{secs[len(secs) // 2]:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
