"""Does a ring-aware noise floor make the pair threshold's trust honest on spinning LiDAR? (core/noise.py,
core/threshold.py). The rules below were fixed before any result was looked at.

Why: a spinning LiDAR's floor is measured today on a random half of the scan against local planes (k = 12) of the
other half, so each query's nearest points lie along its own ring (the same laser) and the floor sees only that
laser's noise, not the range offset and angle error between lasers that a registration meets (a source point lies
between the target's rings, on a surface spanning two lasers). Real multi-laser scanners carry such per-laser
errors after factory calibration: the HDL-64E's calibration file holds a range correction (cm) and a vertical angle
per laser (Velodyne HDL-64E S3 manual, "Calibration parameters"); Glennie and Lichti (Remote Sensing 2(6) 1610,
2010, doi:10.3390/rs2061610) cut the planar misclosure RMSE three-fold below the factory calibration's, and Chen and
Chien (Sensors 12(10) 13736, 2012, doi:10.3390/s121013736) name the "layered misalignment of scans among the
rangefinders" a systematic error of the HDL-64E S2 that recalibration reduces (RMS planar error up to 49 % lower).
The simulated LiDAR (core.scenes_sensor.Spinning) had none, so it agreed with the random-half floor.

Pairs (source, target, T_target_source):
    real            the shared HDL-32E pair (../shared/data/lidar), truth relative.txt (app/sweep_sensors.py)
    street, room    core.scenes_sensor.lidar_pair seeds 0, 1, 2 with the sweep's LiDAR (32 x 1024):
      - plain       no per-laser error (the sweep's families as they are)
      - biased      per-laser range offset sigma 2 cm and elevation error sigma 0.05 deg (1 cm at 10 m), one unit
                    per pair (calibration seed = the pair's seed), both scans of a pair from the same unit
      - quiet+bias  the same per-laser errors with 3 mm range noise (the real pair's regime: a laser's own noise
                    well below the offsets between lasers)
    layouts         street and room seed 0, plain and biased: 16 x 1800 over -15..15 deg (a VLP-16), 64 x 2048 over
                    -25..15, 128 x 1024 over -22.5..22.5 (an Ouster OS-128's field), 64 x 1800 over -24.9..2 (an
                    HDL-64's) (benchmarks/other_lidars.py's three and a 16-ring one)
    objects         the five shared bunny pairs, the Kinect frames, simulated RGB-D fragments: a ring rule must not
                    apply to them (no rings), checked, so their floors stay bit for bit
Scans as the pipeline judges them: core.candidates.for_search (thinned above SEARCH_POINTS), the setup of
core.global_search.setup.prepare_setup at the truth, seed 0; its basis (160 points) rebuilt per rule with the
rule's floor from the very generator state the pipeline has there (the floors' draws made as core.noise makes them).

Poses (T_target_source), judged by the pair threshold's test (PairThreshold.holds: overlap both ways, >= 30 % of
the basis sample matched, misfit < FACTOR, the matched overlap pins the pose):
    truth           the truth
    slid            the truth shifted along the road by +-0.1, +-0.25, +-0.5, +-1 m (street: the world's x, the
                    street's axis, in the target frame; room: the room's length, x; real: the direction of the
                    truth's own translation, the vehicle's motion)
    yawed           the truth turned about the vertical through the source sensor by +-1.5, +-3, +-6 deg
    tilted          the truth turned about the target frame's x and y axes through the source sensor by +-2 deg
Every slid, yawed or tilted pose is wrong by the sweep's rule (beyond 1 deg or 5 cm at the sensor). They are
raw (not refined): the question is whether the test would call such a pose right, wherever a search ends.

Floor rules (each scan's floor, the pair's the mean of the two, as core.global_search.setup takes it):
    random          today's: a random half's queries against local planes (k = 12) of the other half
    parity          the even rings' points as queries (the same count, seeded) against local planes (k = 12)
                    of the odd rings' points
    neighbours      today's queries (the same draw), each against the plane fitted to its 6 nearest points on the
                    ring below and its 6 nearest on the ring above (all of those rings' points; a query on an
                    outermost ring has no plane and is left out): the surface a registration meets between rings
    max-neighbours  the larger of random and neighbours
    max-parity      the larger of random and parity
The rings are core.panorama's (image_of(scan).rings; a point's ring its image row); a scan without rings keeps
the random floor under every rule.

Printed: per pair and rule the floor (rms, mm), the matched share at the truth and the largest at a wrong pose,
trusted at the truth, wrong poses trusted; and per family the counts.

Decision (fixed beforehand): a rule passes when (1) no wrong pose is trusted in any pair, (2) the truth is trusted
on the real pair and on every biased and quiet+biased pair, and (3) no plain pair whose truth the random floor
trusts loses it. Among the rules that pass the order of preference is max-neighbours, neighbours, max-parity,
parity (the max keeps today's floor as a lower bound; the neighbours' plane is the surface a registration meets).
Leave-one-out across kinds: the decision is re-made with each kind (real, plain, biased and quiet+biased,
layouts) left out, and the left-out kind must pass under the rule chosen without it. If no rule passes, the
engine stays as it is and the figures are reported.

Added after the first results were seen (reported beside the decision, never part of it): per rule, the wrong
poses it trusts that the random floor does not (every rule failed condition (1), the random floor too, so the
question became whether a ring rule adds any); and ``--profile``: on the real pair, the matched share, the misfit
and the test's answer along the road in 5 cm steps from relative.txt and from the pose the pipeline ends at from
the identity (the share is nearly flat along the road there, whatever the floor).

    python benchmarks/lidar_floor.py [--smallest] [--profile]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.app.sweep_sensors import SHARED, family_pairs  # noqa: E402
from rangereg.core import noise  # noqa: E402
from rangereg.core import scenes_sensor as ss  # noqa: E402
from rangereg.core.candidates import for_search, make_basis  # noqa: E402
from rangereg.core.config import Config  # noqa: E402
from rangereg.core.global_search.setup import prepare_setup  # noqa: E402
from rangereg.core.guess import Guess  # noqa: E402
from rangereg.core.intrusion import max_intrusion_of  # noqa: E402
from rangereg.core.scan import Scan, ScanKind  # noqa: E402
from rangereg.core.threshold import pair_threshold  # noqa: E402
from rangereg.core.transforms import invert, rotation_matrix  # noqa: E402

RULES = ("random", "parity", "neighbours", "max-neighbours", "max-parity")
PREFERENCE = ("max-neighbours", "neighbours", "max-parity", "parity")
BIAS = dict(laser_range_bias=0.02, laser_elevation_deg=0.05)
LAYOUTS = {"16 x 1800": ss.Spinning(rings=16, steps=1800, elevation_deg=(-15.0, 15.0)),
           "64 x 2048": ss.Spinning(rings=64, steps=2048),
           "128 x 1024": ss.Spinning(rings=128, steps=1024, elevation_deg=(-22.5, 22.5)),
           "64 x 1800": ss.Spinning(rings=64, steps=1800, elevation_deg=(-24.9, 2.0))}
SLIDES = (0.1, 0.25, 0.5, 1.0)  # m, each way
YAWS = (1.5, 3.0, 6.0)  # deg, each way
TILT = 2.0  # deg, each way about x and y
HALF_K = 6  # points per neighbouring ring


# ---- the floor rules --------------------------------------------------------------------------------------------
def rings_of(scan: Scan, points: np.ndarray) -> np.ndarray | None:
    """(N,) the ring (image row) of each of ``points`` (the scan's frame; -1 outside the rings), or None when the
    scan is no panorama or its rows are not rings."""
    if scan.kind is not ScanKind.PANORAMA:
        return None
    from rangereg.core.panorama import image_of

    img = image_of(scan)
    if not img.rings:
        return None
    row, _, _, ok = img.cells(points)
    return np.where(ok, row, -1)


def robust_e(d2: np.ndarray) -> float:
    """core.robust_error's E of squared distances (N,): mean of min(d^2, 2 median d^2)."""
    return float(np.mean(np.minimum(d2, 2.0 * np.median(d2)))) if len(d2) else 0.0


def plane_d2(q: np.ndarray, nbrs: np.ndarray) -> np.ndarray:
    """(Q,) squared distance of queries (Q, 3) to the plane fitted (PCA) to their neighbours (Q, k, 3)."""
    c = nbrs.mean(1)
    X = nbrs - c[:, None]
    _, vecs = np.linalg.eigh(np.einsum("qki,qkj->qij", X, X))
    return np.einsum("ij,ij->i", q - c, vecs[:, :, 0]) ** 2


def floor_parity(scan: Scan, n_points: int) -> float | None:
    ring = rings_of(scan, scan.points)
    if ring is None:
        return None
    even, odd = scan.points[(ring >= 0) & (ring % 2 == 0)], scan.points[(ring >= 0) & (ring % 2 == 1)]
    if len(even) < 3 or len(odd) < noise.NORMAL_NEIGHBOURS:
        return None
    rng = np.random.default_rng([len(scan.points), 1])  # a generator of its own: the pipeline's draws stay put
    q = even[rng.choice(len(even), min(n_points, len(even)), replace=False)]
    return noise._measure_planes(q, odd)


def floor_neighbours(scan: Scan, drawn, pick) -> float | None:
    ring_all = rings_of(scan, scan.points)
    if ring_all is None or pick is None:
        return None
    points, half = drawn
    q = points[half][pick]
    ring_q = rings_of(scan, q)
    trees = {}
    for r in np.unique(ring_all[ring_all >= 0]):
        sel = scan.points[ring_all == r]
        if len(sel) >= HALF_K:
            trees[int(r)] = (cKDTree(sel), sel)
    d2 = []
    for r in np.unique(ring_q[ring_q >= 0]):
        lo, hi = trees.get(int(r) - 1), trees.get(int(r) + 1)
        if lo is None or hi is None:
            continue
        qs = q[ring_q == r]
        nb = np.concatenate([t[1][t[0].query(qs, HALF_K)[1]] for t in (lo, hi)], axis=1)
        d2.append(plane_d2(qs, nb))
    return robust_e(np.concatenate(d2)) if d2 else None


def rule_floors(scan: Scan, drawn, pick, n_points: int) -> dict[str, float]:
    """Every rule's floor of ``scan`` (squared units) from the draws the pipeline makes (core.noise._draw)."""
    base = noise._measure(scan, drawn, pick)
    par = floor_parity(scan, n_points)
    nbr = floor_neighbours(scan, drawn, pick)
    par = base if par is None else par
    nbr = base if nbr is None else nbr
    return {"random": base, "parity": par, "neighbours": nbr, "max-neighbours": max(base, nbr),
            "max-parity": max(base, par)}


# ---- poses --------------------------------------------------------------------------------------------------------
def turned(T: np.ndarray, axis, deg: float) -> np.ndarray:
    """T turned by ``deg`` about ``axis`` (target frame) through the source sensor (T's translation)."""
    a = np.asarray(axis, dtype=np.float64)
    R = rotation_matrix(a / np.linalg.norm(a) * np.radians(deg))
    out = T.copy()
    out[:3, :3] = R @ T[:3, :3]
    return out


def wrong_poses(T: np.ndarray, road: np.ndarray) -> list[tuple[str, np.ndarray]]:
    out = []
    for d in SLIDES:
        for sgn in (1, -1):
            S = T.copy()
            S[:3, 3] += sgn * d * road
            out.append((f"slid {sgn * d:+g} m", S))
    for y in YAWS:
        for sgn in (1, -1):
            out.append((f"yawed {sgn * y:+g} deg", turned(T, (0, 0, 1), sgn * y)))
    for ax, name in (((1, 0, 0), "x"), ((0, 1, 0), "y")):
        for sgn in (1, -1):
            out.append((f"tilted {sgn * TILT:+g} deg about {name}", turned(T, ax, sgn * TILT)))
    return out


# ---- the pairs ---------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Case:
    family: str  # real, plain, biased, quiet+bias, layout plain, layout biased
    name: str
    source: Scan
    target: Scan
    T: np.ndarray
    road: np.ndarray  # unit (3,), target frame


def sim_case(family: str, scene: str, seed: int, lidar: ss.Spinning, label: str) -> Case:
    s, t = ss.lidar_pair(scene, seed, lidar)
    road = t.pose[:3, :3].T @ np.array([1.0, 0.0, 0.0])
    return Case(family, f"{scene}-{seed} {label}", s, t, invert(t.pose) @ s.pose, road)


def cases(smallest: bool = False):
    pairs = family_pairs("lidar", False, SHARED)
    if pairs:
        s, t, T = pairs[0].load()
        yield Case("real", pairs[0].name, s, t, T, T[:3, 3] / np.linalg.norm(T[:3, 3]))
    base = ss.Spinning()
    seeds = (0,) if smallest else (0, 1, 2)
    for scene in ("street", "room"):
        for seed in seeds:
            cal = replace(base, calibration_seed=seed, **BIAS)
            yield sim_case("plain", scene, seed, base, "32 x 1024")
            if smallest:  # a check that it runs: one simulated case a scene
                continue
            yield sim_case("biased", scene, seed, cal, "32 x 1024 biased")
            yield sim_case("quiet+bias", scene, seed, replace(cal, noise=0.003), "32 x 1024 quiet biased")
    if smallest:
        return
    for label, lidar in LAYOUTS.items():
        for scene in ("street", "room"):
            yield sim_case("layout plain", scene, 0, lidar, label)
            yield sim_case("layout biased", scene, 0, replace(lidar, **BIAS), label + " biased")


# ---- one case -----------------------------------------------------------------------------------------------------
def judge(case: Case) -> dict:
    """Per rule: the pair's floor, the truth's share and trust, the wrong poses' largest share and how many trusted."""
    s, t = for_search(case.source), for_search(case.target)
    config = Config(method="global", seed=0)
    setup = prepare_setup(s, t, Guess(case.T), config)
    cc, pc = config.candidates, config.problem
    n = len(setup.problem.points)
    rng = np.random.default_rng(config.seed)
    draws = [noise._draw(x, rng, n) for x in (s, t)]  # as core.global_search.setup draws the floors
    state = rng.bit_generator.state
    per_scan = [rule_floors(x, *d, n) for x, d in zip((s, t), draws)]
    poses = [("truth", case.T)] + wrong_poses(case.T, case.road)
    out = {"rings": [rings_of(x, x.points[:1]) is not None for x in (s, t)], "rules": {}}
    for rule in RULES:
        floor = float(np.mean([f[rule] for f in per_scan]))
        g = np.random.default_rng(config.seed)
        g.bit_generator.state = state
        basis = make_basis(s, t, setup.problem.surface, floor, g, cc, pc.frustum)
        thr = pair_threshold(floor, basis.angle_floor, cc.min_overlap, max_intrusion=max_intrusion_of(s, t))
        if rule == "random":  # the replay is the pipeline's own basis
            assert np.isclose(basis.cap, setup.basis.cap) and np.isclose(floor, setup.threshold.floor)
        rows = []
        for label, T in poses:
            sc = basis.evaluate(T[None])
            m = thr.misfit(basis, T, sc)
            rows.append((label, float(sc.inliers[0]), m, bool(thr.holds(basis, T, sc, m))))
        out["rules"][rule] = {"floor": floor, "truth": rows[0], "wrong": rows[1:]}
    # the truth's own distances: the source sample's median distance to the target surface, inside its frustum
    basis = setup.basis
    moved = basis.points @ case.T[:3, :3].T + case.T[:3, 3]
    inside = basis.target_frustum.contains(moved)
    _, d2 = setup.problem.surface.closest(moved[inside])
    out["truth_median_m"] = float(np.sqrt(np.median(d2)))
    return out


def objects() -> list[str]:
    """The non-LiDAR scans: whether a ring rule would apply to them (it must not)."""
    from rangereg.core.io import load_scan

    lines = []
    for folder, pattern in (("bunny", "bun*.ply"), ("kinect", "capture*.pcd")):
        for f in sorted((SHARED / folder).glob(pattern))[:6]:
            sc = load_scan(str(f))
            lines.append(f"{folder}/{f.name}: kind {sc.kind.value}, rings {rings_of(sc, sc.points[:1]) is not None}")
    s, t = ss.fragment_pair(0)
    for sc in (s, t):
        lines.append(f"sim fragment {sc.name}: kind {sc.kind.value}, rings {rings_of(sc, sc.points[:1]) is not None}")
    return lines


def passes(results: list[tuple[Case, dict]], rule: str, families=None) -> tuple[bool, list[str]]:
    """The decision's three conditions for ``rule`` over the cases of ``families`` (None: all); the failures."""
    bad = []
    for case, r in results:
        if families is not None and case.family not in families:
            continue
        x, base = r["rules"][rule], r["rules"]["random"]
        tw = [w[0] for w in x["wrong"] if w[3]]
        if tw:
            bad.append(f"{case.name}: trusted and wrong at {', '.join(tw)}")
        must = case.family in ("real", "biased", "quiet+bias", "layout biased") or base["truth"][3]
        if must and not x["truth"][3]:
            bad.append(f"{case.name}: truth not trusted")
    return not bad, bad


def profile() -> None:
    """The real pair along the road (module notes: added after the first results)."""
    from rangereg.core.register import register
    from rangereg.core.transforms import pose_error

    case = next(c for c in cases(True) if c.family == "real")
    s, t = for_search(case.source), for_search(case.target)
    found = register(case.source, case.target, Guess(np.eye(4)), Config(method="global", seed=0)).transform
    e_rot, e_trans = pose_error(found, case.T)
    print(f"the pipeline from the identity ends {e_rot:.3f} deg and {100 * e_trans:.1f} cm from relative.txt")
    config = Config(method="global", seed=0)
    setup = prepare_setup(s, t, Guess(case.T), config)
    n = len(setup.problem.points)
    rng = np.random.default_rng(config.seed)
    draws = [noise._draw(x, rng, n) for x in (s, t)]
    state = rng.bit_generator.state
    per_scan = [rule_floors(x, *d, n) for x, d in zip((s, t), draws)]
    steps = np.round(np.arange(-0.5, 0.501, 0.05), 2)
    print("| rule | from | " + " | ".join(f"{d:+.2f}" for d in steps) + " |")
    print("|---|---|" + "---|" * len(steps))
    for rule in ("random", "parity", "neighbours"):
        floor = float(np.mean([f[rule] for f in per_scan]))
        g = np.random.default_rng(config.seed)
        g.bit_generator.state = state
        basis = make_basis(s, t, setup.problem.surface, floor, g, config.candidates, config.problem.frustum)
        thr = pair_threshold(floor, basis.angle_floor, config.candidates.min_overlap,
                             max_intrusion=max_intrusion_of(s, t))
        for base, name in ((case.T, "relative.txt"), (found, "pipeline")):
            cells = []
            for d in steps:
                T = base.copy()
                T[:3, 3] += d * case.road
                sc = basis.evaluate(T[None])
                cells.append(f"{sc.inliers[0]:.2f}{' T' if thr.holds(basis, T, sc) else ''}")
            print(f"| {rule} | {name} | " + " | ".join(cells) + " |")
    print("(share of the basis sample matched; T: the test trusts the pose)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--smallest", action="store_true", help="the real pair and one plain street and room")
    ap.add_argument("--profile", action="store_true", help="only the real pair's share along the road")
    args = ap.parse_args()
    t0 = time.perf_counter()
    if args.profile:
        profile()
        return
    results = []
    print("| pair | rule | floor rms mm | truth median mm | share at truth | trusted at truth | largest wrong share "
          "| wrong trusted |")
    print("|---|---|---|---|---|---|---|---|")
    for case in cases(args.smallest):
        r = judge(case)
        results.append((case, r))
        for rule in RULES:
            x = r["rules"][rule]
            tw = [w[0] for w in x["wrong"] if w[3]]
            print(f"| {case.name} | {rule} | {1000 * np.sqrt(x['floor']):.1f} | {1000 * r['truth_median_m']:.1f} | "
                  f"{x['truth'][1]:.2f} (misfit {x['truth'][2]:.2f}) | {'yes' if x['truth'][3] else 'no'} | "
                  f"{max(w[1] for w in x['wrong']):.2f} | {len(tw)}/{len(x['wrong'])}"
                  + (f" ({', '.join(tw)})" if tw else "") + " |", flush=True)
    print()
    fams = list(dict.fromkeys(c.family for c, _ in results))
    print("| family | rule | pairs | truth trusted | truth share median (min) | wrong trusted | largest wrong share |")
    print("|---|---|---|---|---|---|---|")
    for fam in fams:
        sel = [r for c, r in results if c.family == fam]
        for rule in RULES:
            xs = [r["rules"][rule] for r in sel]
            sh = [x["truth"][1] for x in xs]
            print(f"| {fam} | {rule} | {len(xs)} | {sum(x['truth'][3] for x in xs)}/{len(xs)} | "
                  f"{np.median(sh):.2f} ({min(sh):.2f}) | {sum(w[3] for x in xs for w in x['wrong'])}/"
                  f"{sum(len(x['wrong']) for x in xs)} | {max(w[1] for x in xs for w in x['wrong']):.2f} |")
    print()
    for rule in RULES:
        ok, bad = passes(results, rule)
        print(f"{rule}: {'passes' if ok else 'fails'}" + "".join(f"\n  - {b}" for b in bad))
    print("\nwrong poses trusted beyond the random floor's (added after the first results):")
    for rule in RULES[1:]:
        extra = {}
        for case, r in results:
            base = {w[0] for w in r["rules"]["random"]["wrong"] if w[3]}
            n = sum(w[3] and w[0] not in base for w in r["rules"][rule]["wrong"])
            extra[case.family] = extra.get(case.family, 0) + n
        print(f"  {rule}: " + ", ".join(f"{f} +{n}" for f, n in extra.items()))
    chosen = next((r for r in PREFERENCE if passes(results, r)[0]), None)
    print(f"\nchosen: {chosen}")
    for fam in fams:
        rest = [f for f in fams if f != fam]
        pick = next((r for r in PREFERENCE if passes(results, r, rest)[0]), None)
        held = passes(results, pick, [fam])[0] if pick else False
        print(f"left out {fam}: chosen without it {pick}; {fam} under it: {'passes' if held else 'fails'}")
    print()
    for line in objects():
        print(line)
    print(f"\n{time.perf_counter() - t0:.0f} s, load {open('/proc/loadavg').read().split()[:3]}")


if __name__ == "__main__":
    main()
