"""``rangereg bench --sweep``: the ``global`` pipeline against Open3D's pipelines on the very same starts,
with starts made the way users' guesses are wrong and the method told only what a user would know.

Families of pairs (every pair named in a .conf of the folder that overlaps by MIN_PAIR_OVERLAP both ways
at the truth):
    whole       the shared scans as they are
    crop-whole  a crop of one scan (app.crops: a seeded window of its range grid holding 25-60 % of its
                points, the same viewpoint and truth) onto another whole scan
    crop-crop   crops of two scans
Modes (how a start is made from the truth, and what the method is told):
    origin      rotated by the offset about the source scan frame's origin (where a 4x4 --init's rotation
                acts; 0.1 m from the bunny's centroid) on a seeded random axis, plus the shift; told the
                rotation (``--rotation-uncertainty max(offset, 15)``) and nothing about translation
    turntable   rotated about the vertical axis through the object (Stanford's turntable: world y; every
                bun.conf rotation axis lies within 1.5 deg of it), either way, plus the shift; told the
                rotation only
    centroid    rotated about the source's centroid, plus the shift; told max(offset, 15) deg (180 from 90
                up) and max(shift, 25 mm)
    no-guess    no --init (the scans as stored, up to 90 deg apart here) and no flags: no guess at all
Sensor families (LiDAR, Kinect, simulated streets, rooms and RGB-D fragments): app.sweep_sensors, its own
modes and rules (``--families lidar,kinect,sim-street,sim-room,sim-fragments``).
Offsets 5, 15, 30, 60, 90 and 180 deg with shifts of 10, 25, 50, 75, 75 and 75 mm. Success: < 2 deg and
< 2 mm at the source centroid. Each side is timed from reading the two files to the pose (ours with our
reader, the peers with Open3D's). The peers' parameters, fixed before we measured ourselves (Open3D's
documented recipes scaled by the target's point spacing):
    open3d-icp            point-to-plane ICP from the start within 5 voxels, 100 iterations, on clouds
                          voxel-downsampled at 2 spacings (normals within 4 voxels, 30 neighbours)
    open3d-fpfh           FPFH (5 voxels, 100 neighbours) + RANSAC on mutual matches (1.5 voxels, 3 points,
                          edge length 0.9, 100,000 iterations, 0.999) + point-to-plane ICP within 2 voxels,
                          voxel 2 spacings (~1 mm on the bunny)
    open3d-fpfh-tutorial  the same at the tutorial's scale: voxel 8 spacings (~4 mm on the bunny), normals
                          within 2 voxels, refined by point-to-plane ICP within 0.4 voxel on the full clouds
The FPFH peers ignore the start (features are invariant to it): they run once per pair and start, in
the origin mode and the no-guess mode, and stand for every mode.
The tasks (one start of one pair in one mode at one level) are independent and go through
app.distributed's ``map_tasks``: ``--workers 1`` (default) a plain loop, ``--workers N`` a local Dask
cluster, ``--scheduler tcp://HOST:PORT`` an existing one.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rangereg.app.crops import crop
from rangereg.app.distributed import map_tasks, stderr_lines
from rangereg.core.errors import InputError
from rangereg.core.guess import Guess
from rangereg.core.register import Config, register
from rangereg.core.scan import Scan
from rangereg.core.transforms import invert, perturb, pose_error, random_perturbation, rotation_matrix

SWEEP_LEVELS = ((5.0, 0.010), (15.0, 0.025), (30.0, 0.050), (60.0, 0.075), (90.0, 0.075), (180.0, 0.075))
MODES = ("origin", "turntable", "centroid", "no-guess")
FAMILIES = ("whole", "crop-whole", "crop-crop")
PEERS = ("open3d-icp", "open3d-fpfh", "open3d-fpfh-tutorial")
START_FREE = ("open3d-fpfh", "open3d-fpfh-tutorial")
MIN_PAIR_OVERLAP = 0.2  # a pair is kept when this share of each scan's sample matches the other at the truth
# (measured, 160-point samples: bun090->bun000 0.29, bun315->bun090 0.10-0.15)
CROPS_PER_SCAN = 2  # crops 0 and 1 of every scan (app.crops' seeded rule)
TURNTABLE_AXIS = np.array([0.0, 1.0, 0.0])  # world (the .conf's frame) vertical
OK_ROT, OK_TRANS = 2.0, 0.002  # degrees, metres


# ---- the peers: Open3D's well-known pipelines ----------------------------------------------------------
def _o3d_cloud(scan: Scan, voxel: float | None, normal_radius: float):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points))
    if voxel is not None:
        pcd = pcd.voxel_down_sample(voxel)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=normal_radius, max_nn=30))
    pcd.orient_normals_towards_camera_location(scan.viewpoint)
    return pcd


def open3d_icp(source: Scan, target: Scan, T0: np.ndarray, voxel: float) -> np.ndarray:
    import open3d as o3d

    reg = o3d.pipelines.registration
    src, tgt = _o3d_cloud(source, voxel, 4 * voxel), _o3d_cloud(target, voxel, 4 * voxel)
    return np.asarray(reg.registration_icp(src, tgt, 5 * voxel, T0, reg.TransformationEstimationPointToPlane(),
                                           reg.ICPConvergenceCriteria(max_iteration=100)).transformation)


def open3d_fpfh(source: Scan, target: Scan, T0: np.ndarray, voxel: float, seed: int, tutorial: bool = False) -> np.ndarray:
    """Global FPFH + RANSAC on the source placed by the start (features do not use T0), then ICP
    (module notes: the two scales)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    o3d.utility.random.seed(seed)
    normal = 2 * voxel if tutorial else 4 * voxel
    src, tgt = _o3d_cloud(source, voxel, normal), _o3d_cloud(target, voxel, normal)
    src.transform(T0)
    param = o3d.geometry.KDTreeSearchParamHybrid(radius=5 * voxel, max_nn=100)
    fs, ft = reg.compute_fpfh_feature(src, param), reg.compute_fpfh_feature(tgt, param)
    dist = 1.5 * voxel
    ransac = reg.registration_ransac_based_on_feature_matching(
        src, tgt, fs, ft, True, dist, reg.TransformationEstimationPointToPoint(False), 3,
        [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(dist)],
        reg.RANSACConvergenceCriteria(100000, 0.999))
    if tutorial:  # the tutorial refines on the full clouds within 0.4 voxel
        spacing = target.spacing
        src, tgt = _o3d_cloud(source, None, 2 * voxel), _o3d_cloud(target, None, 2 * voxel)
        src.transform(T0)
        fine = reg.registration_icp(src, tgt, max(0.4 * voxel, spacing), ransac.transformation,
                                    reg.TransformationEstimationPointToPlane())
    else:
        fine = reg.registration_icp(src, tgt, 2 * voxel, ransac.transformation, reg.TransformationEstimationPointToPlane())
    return np.asarray(fine.transformation) @ T0


# ---- the pairs: whole scans and crops -------------------------------------------------------------------
@dataclass(frozen=True)
class View:
    """A scan file, or crop ``crop`` of it (app.crops)."""

    path: str
    crop: int | None = None

    @property
    def name(self) -> str:
        return Path(self.path).stem + ("" if self.crop is None else f"-crop{self.crop}")

    def load(self) -> Scan:
        from rangereg.core.io import load_scan

        scan = load_scan(self.path)
        return scan if self.crop is None else crop(scan, self.crop)


def pair_overlap(source: Scan, target: Scan, T: np.ndarray) -> float:
    """The smaller share, both ways, of a 160-point sample that matches the other scan at pose T."""
    from rangereg.core.candidates import make_basis
    from rangereg.core.surface import Surface

    share = []
    for a, b, Tab in ((source, target, T), (target, source, invert(T))):
        basis = make_basis(a, b, Surface.from_scan(b), 0.0, np.random.default_rng(0))
        share.append(float(basis.evaluate(Tab[None]).inliers[0]))
    return min(share)


def sweep_pairs(folder: Path, families: tuple[str, ...] = FAMILIES) -> list[tuple[str, View, View, float]]:
    """(family, source view, target view, overlap) for every pair of views of the scans named in a .conf in
    ``folder`` that overlaps by MIN_PAIR_OVERLAP both ways at the truth; never two views of one scan. A
    whole pair's target is the scan named first in the .conf; a crop-whole pair's source is the crop."""
    from rangereg.core.io import load_conf, load_scan

    out = []
    for conf in sorted(folder.glob("*.conf")):
        poses = load_conf(conf)
        names = [n for n in poses if (folder / f"{n}.ply").exists()]
        whole = {n: load_scan(folder / f"{n}.ply") for n in names}
        crops = {(n, k): crop(whole[n], k) for n in names for k in range(CROPS_PER_SCAN)}
        view = {n: View(str(folder / f"{n}.ply")) for n in names}
        candidates = []
        for i, t in enumerate(names):
            for s in names[i + 1:]:
                candidates.append(("whole", view[s], view[t], whole[s], whole[t], s, t))
        for (s, k) in crops:
            for t in names:
                if t != s:
                    candidates.append(("crop-whole", View(view[s].path, k), view[t], crops[(s, k)], whole[t], s, t))
        for i, (s, k) in enumerate(crops):
            for (t, m) in list(crops)[i + 1:]:
                if t != s:
                    candidates.append(("crop-crop", View(view[s].path, k), View(view[t].path, m), crops[(s, k)],
                                       crops[(t, m)], s, t))
        for family, vs, vt, ss, st, s, t in candidates:
            if family not in families:
                continue
            share = pair_overlap(ss, st, invert(poses[t]) @ poses[s])
            if share >= MIN_PAIR_OVERLAP:
                out.append((family, vs, vt, share))
    return out


def shared_pairs(folder: Path) -> list[tuple[Path, Path, float]]:
    """(source file, target file, overlap) of every whole pair (:func:`sweep_pairs`)."""
    return [(Path(s.path), Path(t.path), o) for _, s, t, o in sweep_pairs(folder, ("whole",))]


# ---- one task: one start of one pair in one mode at one level -------------------------------------------
@dataclass(frozen=True)
class SweepTask:
    family: str
    source: View
    target: View
    mode: str
    rot: float
    trans: float
    start: int  # index of the seeded start

    @property
    def pair(self) -> str:
        return f"{self.source.name}->{self.target.name}"


def start_pose(task: SweepTask, s: Scan, t: Scan) -> np.ndarray:
    """The start of ``task`` (module notes: modes), T_target_source."""
    T_true = invert(t.pose) @ s.pose
    if task.mode == "no-guess":
        return np.eye(4)
    rng = np.random.default_rng([int(task.rot), task.start, MODES.index(task.mode)])
    shift, r = random_perturbation(rng, task.rot, task.trans)
    c_t = T_true[:3, :3] @ s.centroid + T_true[:3, 3]  # the source centroid in the target frame at the truth
    if task.mode == "centroid":
        return perturb(T_true, np.r_[shift, r], c_t)
    if task.mode == "turntable":
        axis = t.pose[:3, :3].T @ TURNTABLE_AXIS  # world vertical in the target's frame
        return perturb(T_true, np.r_[shift, axis * np.radians(task.rot) * np.sign(r[0] or 1.0)], c_t)
    T = T_true.copy()  # origin: about the source frame's origin, where a 4x4's rotation acts
    T[:3, :3] = T_true[:3, :3] @ rotation_matrix(r)
    T[:3, 3] += shift
    return T


def told(task: SweepTask, T0: np.ndarray | None = None) -> Guess:
    """The guess the method is given for ``task`` at its start pose ``T0`` (None: the identity; module notes:
    modes); never the true error."""
    T0 = np.eye(4) if T0 is None else T0
    if task.mode == "no-guess":
        return Guess.none(T0)
    if task.mode == "centroid":
        return Guess(T0, 180.0 if task.rot >= 90 else max(task.rot, 15.0), max(task.trans, 0.025))
    return Guess(T0, max(task.rot, 15.0))  # the rotation only


def run_sweep_task(task: SweepTask) -> list[dict]:
    """Every method on one start, each timed from reading the files to the pose."""
    t0 = time.perf_counter()
    s, t = task.source.load(), task.target.load()
    load_s = time.perf_counter() - t0
    T_true = invert(t.pose) @ s.pose
    T0 = start_pose(task, s, t)
    out = []

    def row(method, T, seconds, **extra):
        rot, tr = pose_error(T, T_true, s.centroid)
        out.append({"family": task.family, "mode": task.mode, "offset": task.rot, "shift": task.trans,
                    "pair": task.pair, "method": method, "start": task.start,
                    "ok": bool(rot < OK_ROT and tr < OK_TRANS), "rot_error": rot, "trans_error": tr,
                    "seconds": seconds, **extra})

    t0 = time.perf_counter()
    g = register(s, t, told(task, T0), Config(method="global", seed=task.start))
    row("global", g.transform, load_s + time.perf_counter() - t0, load_seconds=load_s, trusted=g.below_threshold,
        within_region=g.within_region, stop=g.stop_reason.name, cut=g.cut)
    for method in PEERS:
        if method in START_FREE and task.mode not in ("origin", "no-guess"):
            continue
        import open3d as o3d

        t0 = time.perf_counter()
        for v in (task.source, task.target):  # the peers read the files with Open3D's own reader
            o3d.io.read_point_cloud(v.path)
        src, tgt = (s, t)  # a crop is a window of the file just read
        if method == "open3d-icp":
            T = open3d_icp(src, tgt, T0, 2.0 * t.spacing)
        else:
            tutorial = method == "open3d-fpfh-tutorial"
            T = open3d_fpfh(src, tgt, T0, (8.0 if tutorial else 2.0) * t.spacing, task.start, tutorial)
        row(method, T, time.perf_counter() - t0)
    return out


def sweep_one(task: SweepTask) -> list[dict]:
    """:func:`run_sweep_task` with a line per method on stderr (a worker's own, on a cluster)."""
    rows = run_sweep_task(task)
    for r in rows:
        sys.stderr.write(f"  {r['family']:10s} {r['mode']:9s} {r['offset']:5g} deg {r['pair']:22s} {r['method']:20s} "
                         f"start {r['start']:2d} {'ok ' if r['ok'] else 'NO '} {r['rot_error']:7.2f} deg "
                         f"{r['seconds']:6.2f} s" + (f" trust={r['trusted']}" if r["method"] == "global" else "") + "\n")
    sys.stderr.flush()
    return rows


# ---- the table ------------------------------------------------------------------------------------------
def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate k / n."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    d = 1 + z * z / n
    c = (p + z * z / (2 * n)) / d
    h = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / d
    return max(0.0, c - h), min(1.0, c + h)


def sweep_table(rows: list[dict]) -> str:
    """Per family, mode and offset: our success with its interval, trust, seconds; the peers' success."""
    lines = ["| family | mode | offset | global: right | 95 % | trusted -> right | wrong, flagged | right, doubted | "
             "s median / p90 / max | " + " | ".join(PEERS) + " |",
             "|---|---|---|---|---|---|---|---|---|" + "---|" * len(PEERS)]
    keys = dict.fromkeys((r["family"], r["mode"], r["offset"]) for r in rows)
    for family, mode, off in keys:
        sel = [r for r in rows if (r["family"], r["mode"], r["offset"]) == (family, mode, off)]
        g = [r for r in sel if r["method"] == "global"]
        k, n = sum(r["ok"] for r in g), len(g)
        lo, hi = wilson(k, n)
        trusted = [r for r in g if r["trusted"]]
        wrong = [r for r in g if not r["ok"]]
        right = [r for r in g if r["ok"]]
        sec = [r["seconds"] for r in g]
        peers = []
        for p in PEERS:
            free = p in START_FREE and mode not in ("origin", "no-guess")
            ps = [r for r in rows if r["method"] == p and r["family"] == family and r["offset"] == off
                  and r["mode"] == ("origin" if free else mode)]
            peers.append(f"{sum(r['ok'] for r in ps) / len(ps):.0%}" if ps else "-")
        off_text = "-" if mode == "no-guess" else f"{off:g} deg"
        lines.append(f"| {family} | {mode} | {off_text} | {k}/{n} = {k / max(n, 1):.0%} | {lo:.0%}-{hi:.0%} | "
                     f"{sum(r['ok'] for r in trusted)}/{len(trusted)} | {sum(not r['trusted'] for r in wrong)}/{len(wrong)} | "
                     f"{sum(not r['trusted'] for r in right)}/{len(right)} | "
                     f"{np.median(sec):.2f} / {np.percentile(sec, 90):.2f} / {max(sec):.2f} | " + " | ".join(peers) + " |")
    g = [r for r in rows if r["method"] == "global"]
    lines += ["", f"all {len(g)} runs: right {sum(r['ok'] for r in g)}; trusted {sum(r['trusted'] for r in g)}, of them "
              f"right {sum(r['ok'] and r['trusted'] for r in g)}; right but beyond the stated region "
              f"{sum(r['ok'] and r['within_region'] is False for r in g)}; median load (our reader, both files) "
              f"{np.median([r['load_seconds'] for r in g]):.2f} s."]
    return "\n".join(lines)


def sweep_tasks(pairs, modes: tuple[str, ...], levels, runs: int) -> list[SweepTask]:
    """Start k of every family, mode, level and pair before start k + 1: a partial run covers them alike.
    The no-guess mode has one level (there is no offset: the scans as stored)."""
    tasks = []
    for k in range(runs):
        for mode in modes:
            for rot, trans in (levels[:1] if mode == "no-guess" else levels):
                for family, s, t, _ in pairs:
                    tasks.append(SweepTask(family, s, t, mode, 0.0 if mode == "no-guess" else rot,
                                           0.0 if mode == "no-guess" else trans, k))
    return tasks


def _choice(text: str | None, allowed: tuple[str, ...], flag: str) -> tuple[str, ...]:
    if text is None:
        return allowed
    chosen = tuple(x.strip() for x in text.split(",") if x.strip())
    bad = [x for x in chosen if x not in allowed]
    if bad or not chosen:
        raise InputError(f"{flag}: choose from {', '.join(allowed)} (comma-separated), got {text!r}")
    return chosen


def sweep(a) -> int:
    runs = a.runs or (2 if a.quick else 10)
    from rangereg.app import sweep_sensors as sensors

    families = _choice(getattr(a, "families", None), FAMILIES + sensors.FAMILIES, "--families")
    if set(families) & set(sensors.FAMILIES):  # the sensor families (app.sweep_sensors: their own modes)
        if set(families) - set(sensors.FAMILIES):
            raise InputError(f"--families: the object families ({', '.join(FAMILIES)}) and the sensor families "
                             f"({', '.join(sensors.FAMILIES)}) run apart")
        modes = _choice(getattr(a, "modes", None), sensors.MODES, "--modes")
        rows, table = sensors.sweep_sensors(families, modes, a.quick, a.runs or (1 if a.quick else 2))
        print(table)
        if a.json:
            Path(a.json).write_text(json.dumps(rows, indent=1, default=float) + "\n")
        return 0
    folder = Path(a.bunny)
    if not folder.is_dir():
        raise InputError(f"--sweep needs a folder of scans with a .conf; {folder} is absent")
    modes = _choice(getattr(a, "modes", None), MODES, "--modes")
    pairs = sweep_pairs(folder, families)
    if not pairs:
        raise InputError(f"{folder}: no pair of scans named in a .conf overlaps by {MIN_PAIR_OVERLAP:.0%} at the truth")
    sys.stderr.write(f"{len(pairs)} pairs: " + ", ".join(f"{f} {s.name}->{t.name} ({o:.0%})" for f, s, t, o in pairs)
                     + "\n")
    levels = SWEEP_LEVELS[:2] if a.quick else SWEEP_LEVELS
    tasks = sweep_tasks(pairs, modes, levels, runs)
    rows = [r for rs in map_tasks(sweep_one, tasks, workers=a.workers, scheduler=a.scheduler, progress=stderr_lines)
            for r in rs]
    print(sweep_table(rows))
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0
