"""Evidence for the pair threshold (core/threshold.py, the pair threshold): on every shared pair (any .conf folder)
and the simulated scenes, where the truth and the nearest wrong minimum lie on the candidates' basis.

For each case: the pair's noise floor and angle floor; at the true pose, sqrt(the median matched d^2
over the floor), the median normal angle over the angle floor, their product (the misfit the threshold
bounds) and the matched share; then ICP minima (core.global_search.refinement.refine: ICP on the cut at the
start, then on the cut at the pose found) from N seeded starts 20-120 degrees and up to 30 % of the
size off and from the truth turned about each principal axis by 20-90 degrees; a minimum more than
the success bound off is wrong, and counted when at least the basis's minimum overlap (10 %) matches.
Printed: the truth's misfit, the nearest wrong minimum's, the leave-one-out factor (geometric mean of
the largest truth misfit and the smallest wrong one over the OTHER cases) and its spread, and per case
whether the threshold (with the factor left out for that case) lies between the two.

    python benchmarks/threshold_evidence.py [--starts 40] [--folder ../shared/data/bunny] [--smallest]
        [--kinds] [--constraint] [--rise] [--intrusion]

``--smallest``: the bowl alone, one random start and one turned truth (a check that the script runs).
``--kinds``: the other kinds too: simulated RGB-D fragments and LiDAR rooms and streets (core.scenes_sensor), the
shared LiDAR pair (truth relative.txt); a case whose surface or overlap this code cannot make is said, not hidden.
``--rise``: the evidence for core.threshold.MIN_RISE and MIN_STABLE_RISE: per case at the truth the constraint's ratio,
the score's rise when slid along the weakest motion (tried only below core.threshold.weak_below_of) and the same rise of
the points that pin that motion (core.threshold.stable_rise; tried where the first falls short).
``--intrusion``: the evidence for core.intrusion.MAX_INTRUSION: per fused room fragment pair (the sweep's, the walks and
the TSDF fragments of benchmarks/written_files.py) the intrusion at the truth and at every twin that passes each other
test (the truth turned about each room corner's diagonal and refined; ``--starts`` seeded starts too).
``--constraint``: the evidence for core.threshold.MIN_CONSTRAINT instead: per case the ratio of the matched
point-to-plane system at the truth and at the truth slid along the system's weakest motion by 1, 2 and 5 % of
the size (free cases: a corridor of planes, a fold of two planes, the wing), and the bound fitted leave-one-out.
On scans whose surface this code cannot make (a panorama before its surface exists), the system is built on the
target's nearest points instead of its surface (said in the row).
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.app.sweep import shared_pairs  # noqa: E402
from rangereg.core.candidates import CandidateConfig, make_basis  # noqa: E402
from rangereg.core.config import Config  # noqa: E402
from rangereg.core.global_search import refine  # noqa: E402
from rangereg.core.guess import Guess  # noqa: E402
from rangereg.core.intrusion import max_intrusion_of  # noqa: E402
from rangereg.core.io import load_scan  # noqa: E402
from rangereg.core.noise import noise_floor  # noqa: E402
from rangereg.core.simulate import SCENES, make_scene, true_transform  # noqa: E402
from rangereg.core.surface import Surface  # noqa: E402
from rangereg.core.threshold import FACTOR, MIN_TRUST_OVERLAP, pair_threshold  # noqa: E402
from rangereg.core.transforms import apply, invert, perturb, pose_error, random_perturbation  # noqa: E402


def cases(folder: Path | None):
    for s_path, t_path, _ in shared_pairs(folder) if folder is not None and folder.is_dir() else []:
        s, t = load_scan(s_path), load_scan(t_path)
        yield f"{s_path.stem}->{t_path.stem}", s, t, invert(t.pose) @ s.pose, 2.0, 0.002
    for i, name in enumerate(SCENES):
        t, s = make_scene(name, i)
        yield name, s, t, true_transform(s, t), 1.0, 0.01 * t.size


def kind_cases(data: Path):
    """The other kinds (module notes: --kinds): (name, source, target, T_target_source, ok_rot, ok_trans)."""
    from rangereg.core.scan import Scan, ScanKind
    from rangereg.core.scenes_sensor import fragment_pair, lidar_pair

    for k in range(2):
        s, t = fragment_pair(k)
        yield f"fragments-{k}", s, t, invert(t.pose) @ s.pose, 1.0, 0.05
    for scene in ("room", "street"):
        for k in range(2):
            s, t = lidar_pair(scene, k)
            yield f"lidar-{scene}-{k}", s, t, invert(t.pose) @ s.pose, 1.0, 0.05
    lidar = data / "lidar"
    if (lidar / "relative.txt").exists():
        import open3d as o3d

        def read(name):
            pts = np.asarray(o3d.io.read_point_cloud(str(lidar / name)).points, dtype=np.float64)
            return Scan(points=pts, viewpoint=np.zeros(3), name=name, units="m", kind=ScanKind.PANORAMA)

        yield ("lidar-shared", read("251371071.pcd"), read("251370668.pcd"), np.loadtxt(lidar / "relative.txt"),
               1.0, 0.05)


def free_cases():
    """Scenes that leave a motion free, at the truth: a corridor of planes (LiDAR), a fold of two planes."""
    from rangereg.core.scenes_sensor import join, lidar_pair, quad
    from rangereg.core.simulate import Scanner, look_at, scan_mesh

    for k in range(2):
        s, t = lidar_pair("corridor", k)
        yield f"lidar-corridor-{k}", s, t, invert(t.pose) @ s.pose, 1.0, 0.05
    L = 1200.0
    mesh = join([quad((0, 0, 0), (L, 0, 0), (L, L, 0), (0, L, 0)), quad((0, 0, 0), (0, 0, L), (L, 0, L), (L, 0, 0))])
    rng = np.random.default_rng(0)
    sc = Scanner(rows=85, cols=85, fov_deg=(52, 52))
    a = scan_mesh(*mesh, look_at((600, 1750, 1350), (600, 250, 300)), sc, rng, "a")
    b = scan_mesh(*mesh, look_at((750, 1700, 1300), (650, 300, 300)), sc, rng, "b")
    yield "fold", b, a, invert(a.pose) @ b.pose, 1.0, 0.01 * a.size


class _Nearest:
    """The target's points as a surface (closest = nearest point) and a frustum that holds everything: the
    system's stand-in where this code cannot make the target's surface."""

    def __init__(self, scan):
        self.scan = scan

    def closest(self, q):
        d, i = self.scan.tree.query(q)
        return self.scan.points[i], d * d

    def contains(self, q):
        return np.ones(len(q), dtype=bool)


def constraint_basis(s, t):
    """A basis for core.threshold.constraint on pair (s, t), and how its closest points were found."""
    from types import SimpleNamespace

    from rangereg.core.candidates import CAP_SPACINGS, CONSTRAINT_SAMPLE, pair_spacing

    try:
        basis = make_basis(s, t, Surface.from_scan(t), 0.0, np.random.default_rng(0))
        return basis, "surface"
    except Exception as exc:  # noqa: BLE001 - said in the row
        near = _Nearest(t)
        pts = s.points[np.sort(np.random.default_rng(0).choice(len(s.points), min(CONSTRAINT_SAMPLE, len(s.points)),
                                                                replace=False))]
        cap = (3 * CAP_SPACINGS * pair_spacing(s, t)) ** 2  # nearest points lie farther than a surface's
        return SimpleNamespace(constraint_points=pts, points=pts, surface=near, target_frustum=near, cap=cap,
                               target=t, _remembered=lambda what, T, f: f()), f"nearest points ({type(exc).__name__})"


def measure_constraint(name, s, t, T_true, free: bool) -> dict:
    from rangereg.core.threshold import constraint

    basis, how = constraint_basis(s, t)
    c = constraint(basis, T_true)
    slid = []
    for share in (0.01, 0.02, 0.05):
        d = c.weakest[:3] / (np.linalg.norm(c.weakest[:3]) or 1.0) * share * t.size
        T = T_true.copy()
        T[:3, 3] += d
        slid.append(constraint(basis, T).ratio)
    return {"case": name, "free": free, "truth": c.ratio, "slid": slid, "motion": c.free_motion, "how": how}


def constraint_main(a) -> int:
    from rangereg.core.threshold import MIN_CONSTRAINT

    rows = []
    pinned = list(cases(Path(a.folder))) + list(kind_cases(Path(a.folder).parent))
    for c in pinned:
        if c[0] == "wing":
            rows.append(measure_constraint(*c[:4], free=True))  # flat along its panel by design
        else:
            rows.append(measure_constraint(*c[:4], free=False))
        print_constraint(rows[-1])
    for c in free_cases():
        rows.append(measure_constraint(*c[:4], free=True))
        print_constraint(rows[-1])
    hi = lambda rs: max(max(r["truth"], *r["slid"]) for r in rs if r["free"])  # noqa: E731
    lo = lambda rs: min(r["truth"] for r in rs if not r["free"])  # noqa: E731
    print(f"\nhighest free ratio {hi(rows):.4f}, lowest pinned truth {lo(rows):.4f}: geometric mean "
          f"{np.sqrt(hi(rows) * lo(rows)):.4f} (core.threshold.MIN_CONSTRAINT = {MIN_CONSTRAINT:g})")
    print("leave-one-out:")
    for r in rows:
        others = [o for o in rows if o is not r]
        k = float(np.sqrt(hi(others) * lo(others)))
        value = max(r["truth"], *r["slid"]) if r["free"] else r["truth"]
        ok = value < k if r["free"] else value >= k
        print(f"  {r['case']:20s} {'free  ' if r['free'] else 'pinned'} {value:.4f} vs bound fitted without it "
              f"{k:.4f}: {'holds' if ok else 'FAILS'}")
    return 0


def rise_main(a) -> int:
    """The evidence for core.threshold.MIN_RISE: per case at the truth, on the basis the global method builds there
    (the search's thinned scans), the constraint's ratio and the score's rise along the weakest motion."""
    from rangereg.core.candidates import for_search
    from rangereg.core.config import Config
    from rangereg.core.global_search.setup import prepare_setup
    from rangereg.core.guess import Guess
    from rangereg.core.threshold import (
        MIN_CONSTRAINT,
        MIN_RISE,
        MIN_STABLE_RISE,
        constraint,
        score_rise,
        stable_rise,
        weak_below_of,
    )

    rows = []
    every = itertools.chain(cases(Path(a.folder)), kind_cases(Path(a.folder).parent), free_cases())
    for name, s, t, T, *_ in every:
        if a.cases and name not in a.cases.split(","):
            continue
        s, t = for_search(s), for_search(t)
        try:
            setup = prepare_setup(s, t, Guess(T), Config(method="global", seed=0))
        except Exception as exc:  # noqa: BLE001 - said in the row
            print(f"{name:20s} not measured: {type(exc).__name__}: {str(exc)[:120]}", flush=True)
            continue
        c = constraint(setup.basis, T)
        if not c.matched:
            print(f"{name:20s} too little matches to measure", flush=True)
            continue
        rise, stable = score_rise(setup.basis, T, c), stable_rise(setup.basis, T, c)
        tried = MIN_CONSTRAINT <= c.ratio < weak_below_of(t)
        rows.append((name, tried, rise))
        print(f"{name:20s} ratio {c.ratio:.4f} ({'tried' if tried else 'not tried'}) rise {rise:.3f} "
              f"stable rise {stable:.3f} (weakest: {c.free_motion})", flush=True)
    print(f"\nMIN_RISE = {MIN_RISE:g}: the truths tried must rise above it where the scene pins them (the bowl); "
          "truths of scans that overlap by a few per cent, and the trusted-and-wrong poses of the fused fragments "
          "(tests/test_constraint.py), do not")
    print(f"MIN_STABLE_RISE = {MIN_STABLE_RISE:g}: the same rise with each point weighted by what it pins of the weakest "
          "motion; free cases (the wing, the fold, the corridors) stay below it")
    return 0


def room_fragment_cases():
    """Fused fragments of the furnished room (core.scenes_sensor: the sweep's sim-fragments, the walks and the TSDF
    fragments of benchmarks/written_files.py, same seeds): (family, name, source, target). Each fragment carries its
    true pose in the room (``pose``), whose corners the twins turn about."""
    from rangereg.core import scenes_sensor as ss

    for seed in range(3):
        yield ("sim-fragments", f"sim-fragments-{seed}", *ss.fragment_pair(seed))
    cam = ss.DepthCamera(cols=240, rows=180)
    for frames, shared in ((15, 5), (30, 10)):
        for seed in range(4):
            yield (f"walk{frames}", f"walk{frames}-{seed}", *ss.fragment_pair(seed, frames, cam, shared))
    for seed in (11, 12, 13, 14):
        yield ("tsdf", f"tsdf-{seed}", *ss.tsdf_fragment_pair(seed))


def corner_turns() -> np.ndarray:
    """(16, 4, 4) T_world_world: the room turned a third of a turn either way about each corner's diagonal (the
    turn that lays a corner's floor on its wall: the twins of a room's corner)."""
    import inspect

    from rangereg.core.scenes_sensor import room_mesh
    from rangereg.core.transforms import rotation_matrix

    size = inspect.signature(room_mesh).parameters["size"].default  # the room every family is fused in
    out = []
    for corner in itertools.product(*[(0.0, x) for x in size]):
        c = np.array(corner)
        d = np.where(c > 0, -1.0, 1.0) / np.sqrt(3.0)
        for sign in (1, -1):
            W = np.eye(4)
            W[:3, :3] = rotation_matrix(d * sign * 2 * np.pi / 3)
            W[:3, 3] = c - W[:3, :3] @ c
            out.append(W)
    return np.array(out)


def intrusion_main(a: argparse.Namespace) -> int:
    """The evidence for core.intrusion (its module notes): per fused room fragment pair, on the basis the global
    method builds at the truth (the search's thinned scans), the intrusion at the truth and at every twin (the
    truth turned about a room corner's diagonal, refined as the pipeline refines, and the wrong minima of seeded
    starts) that passes every other test of the pair threshold: the poses it must reject. Then the bound, and the
    bound fitted with each family left out."""
    from dataclasses import replace

    from rangereg.core import intrusion as intrusion_module
    from rangereg.core.candidates import for_search
    from rangereg.core.global_search.setup import prepare_setup
    from rangereg.core.intrusion import METRES, intrusion

    rows = []
    for family, name, s0, t0 in room_fragment_cases():
        if a.cases and name not in a.cases.split(","):
            continue
        T_true = invert(t0.pose) @ s0.pose
        s, t = for_search(s0), for_search(t0)
        setup = prepare_setup(s, t, Guess(T_true), Config(method="global", seed=0))
        basis, thr = setup.basis, setup.threshold
        stated = Guess.identity(90.0, 0.3 * t.size)
        starts = [invert(t0.pose) @ W @ s0.pose for W in corner_turns()]
        starts += list(starts_from(T_true, s, np.random.default_rng(7), a.starts, t.size))[:a.starts]
        twins = []
        for T0 in starts:
            try:
                T, _ = refine(s, t, setup.surface, stated.at(T0), Config())
            except Exception:  # noqa: BLE001 - a start with no overlap at all is no minimum
                continue
            rot, trans = pose_error(T, T_true, s.centroid)
            if (rot >= 1.0 or trans >= 0.05) and replace(thr, max_intrusion=np.inf, slide_intrusion=np.inf).holds(basis, T):
                if not any(pose_error(T, o[1], s.centroid)[0] < 1.0 for o in twins):
                    twins.append((intrusion(basis, T), T, rot, trans))
        truth = intrusion(basis, T_true)
        rows.append((family, name, truth, [w[0] for w in twins]))
        print(f"{name:16s} truth {truth:.3f} | {len(twins)} twins pass every other test: "
              + (", ".join(f"{w[0]:.3f} ({w[2]:.0f} deg, {w[3]:.2f} m)" for w in twins) or "-"), flush=True)
    if rows:
        _intrusion_fit(rows)
    print("\nnot used to fit, at the truths (or the trusted poses):")
    for name, s0, t0, T in other_kind_cases(Path(a.folder).parent):
        s, t = for_search(s0), for_search(t0)
        setup = prepare_setup(s, t, Guess(T), Config(method="global", seed=0))
        x = intrusion(setup.basis, T)
        sizes = ", ".join(f"{scan.size * (METRES.get(scan.units) or np.nan):.2f} m" for scan in (s, t))
        every_size = intrusion_module.SCENE_METRES
        intrusion_module.SCENE_METRES = 0.0  # as if asked of every unstructured scan, whatever its size
        try:
            y = intrusion(prepare_setup(s, t, Guess(T), Config(method="global", seed=0)).basis, T)
        finally:
            intrusion_module.SCENE_METRES = every_size
        print(f"  {name:34s} {'not asked' if x is None else f'{x:.3f}'} (sizes {sizes}; asked of any size: "
              f"{y:.3f})", flush=True)
    return 0


def _intrusion_fit(rows: list) -> None:
    """Print the bound fitted on ``rows`` ((family, name, truth, twins)) and with each family left out."""
    from rangereg.core.intrusion import MAX_INTRUSION

    def bound(rs):
        hi, lo = max(r[2] for r in rs), min((w for r in rs for w in r[3]), default=np.inf)
        return hi, lo, float(np.sqrt(hi * lo))

    hi, lo, k = bound(rows)
    print(f"\nhighest truth {hi:.3f}, least twin {lo:.3f}: geometric mean {k:.3f} "
          f"(core.intrusion.MAX_INTRUSION = {MAX_INTRUSION:g})")
    for fam in dict.fromkeys(r[0] for r in rows):
        others = [r for r in rows if r[0] != fam]
        if not others:
            continue
        k = bound(others)[2]
        mine = [r for r in rows if r[0] == fam]
        ok = all(r[2] < k for r in mine) and all(w >= k for r in mine for w in r[3])
        print(f"  without {fam:14s} bound {k:.3f}: {fam}'s truths below and twins above it: {'holds' if ok else 'FAILS'}")


def other_kind_cases(data: Path):
    """(name, source, target, T_target_source) of other kinds: the shared Kinect frames read as unstructured (at the
    poses the pipeline trusts on them as captured), the shared LiDAR pair thinned on voxels (the assembly calls them
    unstructured), and fused fragments of the bunny (two scans merged, against a third; an object seen from outside)."""
    import open3d as o3d
    from rangereg.core.io import load_pair
    from rangereg.core.register import register
    from rangereg.core.scan import Scan, ScanKind

    kinect = sorted((data / "kinect").glob("capture*.pcd"))
    for a_, b_ in zip(kinect[1:], kinect[:-1]):
        s, t = load_pair(a_, b_)
        T = register(s, t, Guess.identity(), Config(method="global", seed=0)).transform
        su, tu = load_pair(a_, b_, kind="unstructured")
        yield f"kinect {a_.stem}->{b_.stem}", su, tu, T
    lidar = data / "lidar"
    if (lidar / "relative.txt").exists():
        from rangereg.core.io import read_raw

        T = np.loadtxt(lidar / "relative.txt")
        for v in (0.1, 0.25, 0.5):
            scans = []
            for name in ("251371071", "251370668"):
                p = read_raw(lidar / f"{name}.pcd").points
                p = p[np.all(np.isfinite(p), axis=1) & np.any(p != 0, axis=1)]
                p = np.asarray(o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(v).points)
                scans.append(Scan(points=p, viewpoint=np.zeros(3), name=name, units="m", kind=ScanKind.UNSTRUCTURED))
            yield f"lidar thinned at {v:g} m", scans[0], scans[1], T
    bunny = data / "bunny"
    if (bunny / "bun.conf").exists():
        world = {}
        for n in ("bun000", "bun045", "bun090", "bun315"):
            sc = load_scan(bunny / f"{n}.ply")
            world[n] = sc.points @ sc.pose[:3, :3].T + sc.pose[:3, 3]  # the poses of bun.conf

        def fused(*names):
            return Scan(points=np.concatenate([world[n] for n in names]), viewpoint=np.zeros(3), name="+".join(names),
                        units="m", kind=ScanKind.UNSTRUCTURED)

        for src, tgt in ((("bun000", "bun045"), ("bun090",)), (("bun090",), ("bun000", "bun315"))):
            yield f"bunny {'+'.join(src)} -> {'+'.join(tgt)}", fused(*src), fused(*tgt), np.eye(4)


def print_constraint(r: dict) -> None:
    print(f"{r['case']:20s} {'free  ' if r['free'] else 'pinned'} truth {r['truth']:.4f}  slid 1/2/5 % of the size "
          + " ".join(f"{x:.4f}" for x in r["slid"]) + f"  weakest: {r['motion']}  ({r['how']})", flush=True)


def starts_from(T_true: np.ndarray, s, rng: np.random.Generator, n: int, size: float):
    """N seeded starts 20-120 deg and up to 30 % of the size off; then the truth turned about each of the
    source's principal axes (through its centroid) by +-20, 35, 50, 70 and 90 deg, where a shape that is
    nearly symmetric (the bowl about its axis) has the twins that fit it best."""
    c_t = apply(T_true, s.centroid[None])[0]
    for _ in range(n):
        tr, r = random_perturbation(rng, rng.uniform(20, 120), rng.uniform(0.0, 0.3) * size)
        yield perturb(T_true, np.r_[tr, r], c_t)
    _, axes = np.linalg.eigh(np.cov((s.points - s.centroid).T))
    for axis in (T_true[:3, :3] @ axes).T:
        for deg in (20, 35, 50, 70, 90):
            for sign in (1, -1):
                yield perturb(T_true, np.r_[0, 0, 0, np.radians(sign * deg) * axis], c_t)


def measure(name, s, t, T_true, ok_rot, ok_trans, starts: int, config: CandidateConfig = CandidateConfig(),
            turned: int | None = None) -> dict:
    """``turned``: how many of the turned truths to try (None: all)."""
    surface = Surface.from_scan(t)
    rng = np.random.default_rng(0)
    floor = float(np.mean([noise_floor(x, rng, 300) for x in (s, t)]))
    basis = make_basis(s, t, surface, floor, rng, config)
    thr = pair_threshold(floor, basis.angle_floor, basis.min_overlap, max_intrusion=max_intrusion_of(s, t))

    def misfit(T: np.ndarray) -> tuple[float, float, float, float]:
        """(misfit, distance ratio, angle ratio, matched share) of pose T, whatever its overlap."""
        sc = basis.evaluate(T[None])
        return (thr.misfit(basis, T, sc), float(np.sqrt(sc.inlier_median[0] / floor)),
                basis.normal_angle(T) / basis.angle_floor, float(sc.inliers[0]))

    truth = misfit(T_true)
    rng = np.random.default_rng(7)
    wrong = []
    stated = Guess.identity(90.0, 0.3 * t.size)
    every = starts_from(T_true, s, rng, starts, t.size)
    for T0 in every if turned is None else itertools.islice(every, starts + turned):
        try:
            T, _ = refine(s, t, surface, stated.at(T0), Config(candidates=config))
        except Exception:  # noqa: BLE001 - a start with no overlap at all is no minimum
            continue
        rot, trans = pose_error(T, T_true, s.centroid)
        if rot >= ok_rot or trans >= ok_trans:
            m = misfit(T)
            if m[3] >= basis.min_overlap and basis.valid(basis.evaluate(T[None]))[0]:
                wrong.append((*m, rot, trans))
    near = min(wrong, default=(np.inf, np.nan, np.nan, 0.0, np.nan, np.nan))
    return {"case": name, "floor": floor, "angle_floor": basis.angle_floor, "truth": truth, "wrong": len(wrong),
            "near": near, "near_trusted": min((w for w in wrong if w[3] >= MIN_TRUST_OVERLAP),
                                                    default=(np.inf,))[0]}


AMBIGUOUS = {"wing": "E is flat along the panel by design (README): wrong minima match as well as the truth",
             "corner": "three planes: its twin turned 120 deg about the corner's diagonal fits at the noise level; "
                       "no test of one pose tells them apart (the fixed-basis score still ranks the truth first)"}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--starts", type=int, default=40)
    ap.add_argument("--folder", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--cases", help="only these cases, comma-separated (e.g. corner,bowl)")
    ap.add_argument("--neighbours", type=int, default=CandidateConfig().normal_neighbours,
                    help="points a normal is fitted to (core.noise.NORMAL_NEIGHBOURS by default)")
    ap.add_argument("--smallest", action="store_true", help="the bowl, one start and one turned truth")
    ap.add_argument("--kinds", action="store_true", help="the other kinds too (module notes)")
    ap.add_argument("--constraint", action="store_true", help="the evidence for MIN_CONSTRAINT (module notes)")
    ap.add_argument("--rise", action="store_true", help="the evidence for MIN_RISE (module notes)")
    ap.add_argument("--intrusion", action="store_true", help="the evidence for core.intrusion.MAX_INTRUSION")
    a = ap.parse_args()
    if a.intrusion:
        return intrusion_main(a)
    if a.constraint:
        return constraint_main(a)
    if a.rise:
        return rise_main(a)
    if a.smallest:
        a.cases, a.starts = "bowl", 1
    rows = []
    every = itertools.chain(cases(None if a.smallest else Path(a.folder)),
                            kind_cases(Path(a.folder).parent) if a.kinds else ())
    for c in every:
        if a.cases and c[0] not in a.cases.split(","):
            continue
        try:
            rows.append(measure(*c, starts=a.starts, config=CandidateConfig(normal_neighbours=a.neighbours),
                                turned=1 if a.smallest else None))
        except Exception as exc:  # noqa: BLE001 - a kind this code cannot yet make a surface or overlap for
            print(f"{c[0]:16s} not measured: {type(exc).__name__}: {str(exc)[:160]}", flush=True)
            continue
        r = rows[-1]
        m, d2, ang, share = r["truth"]
        w = r["near"]
        print(f"{r['case']:16s} floor {r['floor']:.3g}, angle floor {r['angle_floor']:.2f} deg | truth: misfit {m:.2f} "
              f"(distance {d2:.2f} x, angle {ang:.2f} x), {share:.2f} matched | {r['wrong']} wrong minima: nearest misfit "
              f"{w[0]:.2f} (distance {w[1]:.2f} x, angle {w[2]:.2f} x, {w[3]:.2f} matched, {w[4]:.1f} deg, {w[5]:.3g} off); "
              f"nearest with >= {MIN_TRUST_OVERLAP:g} matched: {r['near_trusted']:.2f}", flush=True)
    fit = [r for r in rows if r["case"] not in AMBIGUOUS]
    for name, why in AMBIGUOUS.items():
        print(f"{name}: left out of the fit ({why})")
    if not fit:
        return 0
    hi, lo = max(r["truth"][0] for r in fit), min(r["near"][0] for r in fit)
    print(f"\nall cases: largest truth misfit {hi:.2f}, nearest wrong {lo:.2f}, geometric mean {np.sqrt(hi * lo):.2f} "
          f"(core.threshold.FACTOR = {FACTOR:g})")
    print("leave-one-out factor (geometric mean of the other cases' largest truth misfit and smallest wrong one):")
    factors = []
    for r in fit:
        others = [o for o in fit if o is not r]
        if not others:
            break
        k = float(np.sqrt(max(o["truth"][0] for o in others) * min(o["near"][0] for o in others)))
        factors.append(k)
        t, w = r["truth"][0], r["near"][0]
        print(f"  {r['case']:16s} truth {t:.2f} < {FACTOR:g} < nearest wrong {w:.2f}: "
              f"{'holds' if t < FACTOR < w else 'FAILS'}; with the factor fitted without it ({k:.2f}): "
              f"{'holds' if t < k < w else 'FAILS'}")
    if factors:
        print(f"factor: spread {min(factors):.2f}-{max(factors):.2f} (inf: no wrong minimum in the other cases)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
