"""The evidence for core.intrusion's tests of where a sensor looked through (FREE_MARGIN, MAX_LOOKED_THROUGH): the
share of each scan's points the other's sensor looked through, at the truths and at the twins the search ends on.

    python benchmarks/free_space_evidence.py [--margins 0.05,0.1,0.2] [--kind panorama|single-view]
    python benchmarks/free_space_evidence.py --smallest   # the first pair from the identity: a check that it runs

Pairs (fixed on 2026-12-06 before the first run): the sensor sweep's simulated street and room pairs (seeds 0-2;
core.scenes_sensor.lidar_pair), the same with a VLP-16-like layout (16 rings x 1800 over +-15 deg, seeds 0-1), the
shared HDL-32E pair (../shared/data/lidar, truth relative.txt, when present), and every third consecutive pair of the
room sequences of benchmarks/sequences.py (seed 0, steps 0.25, 0.5 and 1 m). Twins: the poses `register` ends on from
the identity and from the truth turned 90, 180 and 270 deg about the sensor's vertical (15 deg stated, the default),
kept where they lie 1 deg / 5 cm or more off the truth, with the test under study switched off (its bound lifted, so
the search runs as it did before the test); whether every other test of the pair threshold trusted each is printed.
The measure is core.intrusion.pair_intrusion's (between two such scans the larger of the two ways, each the share of a
sample of 1500 points among those in a direction the other's sensor saw something), as the pair threshold takes it.
(The first run, that day, took the mean of the ways over all 1500 points: core.intrusion's notes give both.)

Single views (--kind single-view; added the same day after the panoramas, when the RGB-D drives of
benchmarks/sequences.py placed 8 of 16 frames a quarter turn off): every third consecutive pair of those drives
(seed 0, steps 0.1, 0.2 and 0.4 m), their twins as above but turned about the target camera's up axis; at the truths
only, the shared Kinect frames' consecutive pairs (at the pose registered on them with no guess, where trusted), the
five shared bunny pairs (../shared/data/bunny, each scan's stored pose) and (added after the supported-points rule,
below) the paper's scenes of assets/ (core.simulate: 3 % of returns on no surface). Its first run found few twins
among those starts (a camera turned about its up axis mostly looks away), while the merge had trusted twins on pairs
it registers with no guess; so pairs 6 frames apart (from frames 0, 3, 6 and 9) and a start with no guess were added,
for every pair. On those, the mean over all points left the real Kinect truths (up to 0.010) close to a trusted twin
(0.017): the measure became the larger way among the points judged, for both kinds. Its second run left the paper's
scenes (not yet among the pairs) reading 0.02-0.03 at their truths, their spurious returns: the measure then skipped a
single view's points without support (core.intrusion.supported), and all was run again. A review then found the
Kinect frames (250k points) measured whole, where the search judges them thinned (core.candidates.for_search): the
shares are now taken on the thinned scans, as the pair threshold takes them. Both rules were chosen after these pairs
were seen, and no twin is held out: the twins come from one simulated room.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from rangereg.core import Config, register
from rangereg.core import intrusion as intr
from rangereg.core import scenes_sensor as ss
from rangereg.core.errors import InputError
from rangereg.core.guess import Guess
from rangereg.core.io import load_scan
from rangereg.core.transforms import invert, pose_error

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sequences import frames  # noqa: E402

LIDAR = Path(__file__).resolve().parents[2] / "shared" / "data" / "lidar"


def shares(s, t, T: np.ndarray, margins) -> list[float]:
    """core.intrusion's measure of pose T at each margin, as the pair threshold takes it: on the scans the search
    judges (core.candidates.for_search: thinned above its limit, as the shared Kinect frames are), their samples and
    seen spaces."""
    from rangereg.core.candidates import for_search

    s, t = for_search(s), for_search(t)
    src, tgt = intr.sample_and_seen(s, 11), intr.sample_and_seen(t, 12)
    return [intr.pair_intrusion(s, t, src, tgt, T, m) for m in margins]


def view_pairs():
    for step in (0.1, 0.2, 0.4):
        scans, truth = frames("rgbd", step, 0)
        for k in range(0, len(scans) - 1, 3):
            yield f"rgbd drive {step:g} m {k}->{k + 1}", scans[k + 1], scans[k], invert(truth[k]) @ truth[k + 1], "twins"
        for k in (0, 3, 6, 9):
            yield f"rgbd drive {step:g} m {k}->{k + 6}", scans[k + 6], scans[k], invert(truth[k]) @ truth[k + 6], "twins"
    from rangereg.core.simulate import true_transform

    assets = Path(__file__).resolve().parents[1] / "assets"
    for scene in ("corner", "bowl", "wing", "ribbed"):  # the paper's scenes: their scanner returns 3 % on no surface
        s, t = load_scan(assets / scene / "scan2.ply"), load_scan(assets / scene / "scan1.ply")
        yield f"scene {scene}", s, t, true_transform(s, t), "simulated"
    kinect = LIDAR.parent / "kinect"
    if kinect.is_dir():
        frames_ = sorted(kinect.glob("capture*.pcd"))
        for a, b in zip(frames_[1:], frames_[:-1]):
            s, t = load_scan(a), load_scan(b)
            r = register(s, t, Guess.none(), Config(method="global", seed=0))
            if r.trusted:
                yield f"Kinect {a.stem}->{b.stem}", s, t, r.transform, "real"
    bunny = LIDAR.parent / "bunny"
    if bunny.is_dir():
        from rangereg.app.sweep import sweep_pairs

        for _, sv, tv, _ in sweep_pairs(bunny, ("whole",)):
            s, t = load_scan(sv.path), load_scan(tv.path)
            yield f"bunny {s.name}->{t.name}", s, t, invert(t.pose) @ s.pose, "real"


def pairs():
    for seed in range(3):
        for scene in ("street", "room"):
            s, t = ss.lidar_pair(scene, seed)
            yield f"sweep {scene}-{seed}", s, t, invert(t.pose) @ s.pose, False
    if LIDAR.is_dir():
        yield ("shared HDL-32E", load_scan(LIDAR / "251371071.pcd"), load_scan(LIDAR / "251370668.pcd"),
               np.loadtxt(LIDAR / "relative.txt"), True)
    vlp16 = ss.Spinning(rings=16, steps=1800, elevation_deg=(-15.0, 15.0))
    for seed in range(2):
        for scene in ("street", "room"):
            s, t = ss.lidar_pair(scene, seed, vlp16)
            yield f"VLP-16-like {scene}-{seed}", s, t, invert(t.pose) @ s.pose, False
    for step in (0.25, 0.5, 1.0):
        scans, truth = frames("room", step, 0)
        for k in range(0, len(scans) - 1, 3):
            yield f"sequence room {step:g} m {k}->{k + 1}", scans[k + 1], scans[k], invert(truth[k]) @ truth[k + 1], False


def turned(T: np.ndarray, deg: float, up: np.ndarray = np.r_[0.0, 0.0, 1.0]) -> np.ndarray:
    """T turned ``deg`` about the target sensor's ``up`` axis."""
    from rangereg.core.transforms import rotation_matrix

    R = np.eye(4)
    R[:3, :3] = rotation_matrix(up * np.radians(deg))
    return R @ T


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--margins", default="0.05,0.1,0.2")
    ap.add_argument("--kind", default="panorama", choices=("panorama", "single-view"))
    ap.add_argument("--smallest", action="store_true", help="the first pair from the identity: a check that it runs")
    a = ap.parse_args()
    margins = [float(m) for m in a.margins.split(",")]
    config = Config(method="global", seed=0)
    intr.MAX_LOOKED_THROUGH = np.inf  # the search as before the test: the twins it ended on (module notes)
    views = a.kind == "single-view"
    up = np.r_[0.0, -1.0, 0.0] if views else np.r_[0.0, 0.0, 1.0]
    truths, twins = [], []
    for n, (name, s, t, T, real) in enumerate(view_pairs() if views else pairs()):
        if a.smallest and n:
            break
        real, no_twins = real in (True, "real"), real in ("real", "simulated")
        at_truth = shares(s, t, T, margins)
        truths.append((name, real, at_truth))
        print(f"{name}: truth {np.round(at_truth, 4).tolist()}", flush=True)
        starts = (0,) if a.smallest else (0, 90, 180, 270, None) if views else (0, 90, 180, 270)
        for deg in () if no_twins else starts:
            guess = Guess.none() if deg is None else Guess.identity() if deg == 0 else Guess(turned(T, deg, up))
            try:
                r = register(s, t, guess, config)
            except InputError:  # no overlap under that start (a camera turned half a turn looks away)
                continue
            rot, tr = pose_error(r.transform, T)
            if rot < 1.0 and tr < 0.05:
                continue
            at_twin = shares(s, t, r.transform, margins)
            twins.append((name, at_twin, r.trusted))
            start = "no guess" if deg is None else "the identity" if deg == 0 else f"the truth turned {deg} deg"
            print(f"    from {start}: {rot:.0f} deg / "
                  f"{tr:.2f} m off, trusted by the other tests {r.trusted}, "
                  f"{np.round(at_twin, 4).tolist()}", flush=True)
    print(f"\n{len(truths)} truths, {len(twins)} twins")
    print("| margin | highest truth (simulated) | the real pairs' | least twin the other tests trust | bound |")
    print("|---|---|---|---|---|")
    for k, m in enumerate(margins):
        sim = max((x[2][k] for x in truths if not x[1]), default=0.0)
        real = max((x[2][k] for x in truths if x[1]), default=float("nan"))
        least = min((x[1][k] for x in twins if x[2]), default=float("nan"))  # those every other test trusts
        high = max(sim, real) if np.isfinite(real) else sim
        print(f"| {m:g} | {sim:.4f} | {real:.4f} | {least:.4f} | {np.sqrt(high * least):.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
