"""``rangereg bench --sweep --families lidar,...``: the ``global`` pipeline against Open3D's pipelines and
KISS-Matcher on scans as LiDAR and RGB-D sensors take them, on the very same starts.

The rules, fixed before any result was looked at:

Families
    lidar       the shared spinning-LiDAR pair (../shared/data/lidar): 251371071 onto 251370668; the truth is
                relative.txt, which maps the source's points into the target's frame (T_target_source):
                applied so, the source's points lie a median 5.2 cm from the target's nearest (70 % within
                10 cm); applied the other way, 18.8 cm (33 %); and Open3D's point-to-plane ICP from the identity
                ends 1.5 cm and 0.03 deg from it
    kinect      the shared Kinect frames (../shared/data/kinect): no truth; frames i -> i+1, i+1 -> i+2 and
                i -> i+2 are registered alike and a run is right when the direct pose agrees with the
                chained one (T_i,i+2 against T_i,i+1 T_i+1,i+2) within the tolerance
    sim-street  simulated spinning LiDAR (32 rings x 1024 steps, 2 cm range noise, 60 m) in a street with
                buildings of varied setback, parked cars and poles, two poses 0.5-1 m apart (core.scenes_sensor)
    sim-room    the same LiDAR (1 cm noise, +-30 deg) in a furnished room, two poses 0.3-0.6 m apart
    sim-fragments  RGB-D fragments of the room: five depth frames of a hand-held camera each, fused in the
                first camera's frame and thinned at 1 cm (no single viewpoint), the second fragment's path
                starting where the first's ends
Modes (how a start is made and what the method is told)
    identity    T0 = identity (odometry: the scans as stored); told nothing (the defaults)
    sensor      the truth turned about the source sensor's origin by 5, 15, 30 or 60 deg on a seeded axis and
                shifted by 0.1, 0.25, 0.5 or 1 m; told max(offset, 15) deg and max(shift, 0.25) m
    no-guess    T0 = identity, told there is no guess (core.guess.Guess.none)
    (kinect: the starts perturb the identity instead of a truth)
Right: within 1 deg and 5 cm, the translation error measured at the source frame's origin (the sensor).
Peers, on the same starts, at the scene's voxel v (core.candidates.scene_voxel):
    open3d-icp     point-to-plane ICP from the start, clouds at v / 2, normals within 2 v, within 2 v, 60 iterations
    open3d-gicp    generalized ICP from the start, the same clouds and distance
    open3d-fpfh    FPFH (5 v, 100 neighbours) + RANSAC (mutual, 1.5 v, 100,000, 0.999) + point-to-plane ICP (v)
                   at v: start-free
    kiss-matcher   KISS-Matcher's estimate at voxel v (start-free), as it comes
A run that raises (a file refused) is a wrong pose, not trusted, its reason kept. Every family stays in the
table, whatever its figures.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rangereg.core.errors import InputError
from rangereg.core.global_search.stages import wait_ahead
from rangereg.core.guess import Guess
from rangereg.core.register import Config, register
from rangereg.core.scan import Scan
from rangereg.core.transforms import invert, pose_error, random_perturbation, rotation_matrix


def _shared() -> Path:
    """The shared data folder: ``shared/data`` beside the nearest folder above this file that holds one."""
    for up in Path(__file__).resolve().parents:
        if (up / "shared" / "data").is_dir():
            return up / "shared" / "data"
    return Path(__file__).resolve().parents[2] / "shared" / "data"


SHARED = _shared()
FAMILIES = ("lidar", "kinect", "sim-street", "sim-room", "sim-fragments")
MODES = ("identity", "sensor", "no-guess")
LEVELS = ((5.0, 0.1), (15.0, 0.25), (30.0, 0.5), (60.0, 1.0))
PEERS = ("open3d-icp", "open3d-gicp", "open3d-fpfh", "kiss-matcher")
START_FREE = ("open3d-fpfh", "kiss-matcher")
OK_ROT, OK_TRANS = 1.0, 0.05  # degrees, metres


# ---- the pairs ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorPair:
    """One pair of a family: how to make it (``seed`` of a simulated family, or the files), its name."""

    family: str
    name: str
    seed: int = 0
    files: tuple[str, ...] = ()
    quick: bool = False

    def load(self) -> tuple[Scan, Scan, np.ndarray | None]:
        """(source, target, T_target_source or None: no truth)."""
        from rangereg.core import scenes_sensor as ss

        lidar = ss.Spinning(rings=16, steps=512) if self.quick else ss.Spinning()
        if self.family == "sim-street":
            s, t = ss.lidar_pair("street", self.seed, lidar)
        elif self.family == "sim-room":
            s, t = ss.lidar_pair("room", self.seed, lidar)
        elif self.family == "sim-fragments":
            cam = ss.DepthCamera(cols=80, rows=60) if self.quick else ss.DepthCamera()
            s, t = ss.fragment_pair(self.seed, frames=3 if self.quick else 5, cam=cam)
        else:
            from rangereg.core.io import load_scan

            s, t = load_scan(self.files[0]), load_scan(self.files[1])
            if self.family == "lidar":
                return s, t, np.loadtxt(self.files[2])
            return s, t, None
        return s, t, invert(t.pose) @ s.pose


def family_pairs(family: str, quick: bool, data: Path = SHARED) -> list[SensorPair]:
    """The pairs of ``family`` (the shared ones only where their files are present)."""
    if family == "lidar":
        d = data / "lidar"
        files = (str(d / "251371071.pcd"), str(d / "251370668.pcd"), str(d / "relative.txt"))
        return [SensorPair(family, "251371071->251370668", files=files)] if all(map(Path.exists, map(Path, files))) else []
    if family == "kinect":
        frames = sorted((data / "kinect").glob("capture*.pcd"))
        triples = [frames[i:i + 3] for i in range(0, len(frames) - 2, 1)][:1 if quick else None]
        return [SensorPair(family, f"{a.stem}-{c.stem}", files=(str(a), str(b), str(c))) for a, b, c in triples]
    n = 1 if quick else 3
    return [SensorPair(family, f"{family}-{k}", seed=k, quick=quick) for k in range(n)]


# ---- starts -------------------------------------------------------------------------------------------------
def sensor_start(T_ref: np.ndarray, rot: float, trans: float, seed: int) -> np.ndarray:
    """T_ref turned by ``rot`` degrees about the source sensor's origin (a seeded axis) and shifted ``trans``."""
    rng = np.random.default_rng([int(rot), int(round(trans * 100)), seed])
    shift, r = random_perturbation(rng, rot, trans)
    T = T_ref.copy()
    T[:3, :3] = T_ref[:3, :3] @ rotation_matrix(r)
    T[:3, 3] += shift
    return T


def told(mode: str, rot: float, trans: float, T0: np.ndarray) -> Guess:
    """The guess the method is given at its start pose ``T0`` (module notes: modes)."""
    if mode == "no-guess":
        return Guess.none(T0)
    if mode == "sensor":
        return Guess(T0, max(rot, 15.0), max(trans, 0.25))
    return Guess(T0)


# ---- the peers ----------------------------------------------------------------------------------------------
def _cloud(scan: Scan, voxel: float):
    import open3d as o3d

    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points)).voxel_down_sample(voxel)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=2 * voxel, max_nn=30))
    return pcd


def peer(method: str, s: Scan, t: Scan, T0: np.ndarray, v: float, seed: int) -> np.ndarray:
    """T_target_source by ``method`` (module notes: peers) at the scene's voxel ``v``."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    if method in ("open3d-icp", "open3d-gicp"):
        src, tgt = _cloud(s, v / 2), _cloud(t, v / 2)
        est = reg.TransformationEstimationPointToPlane() if method == "open3d-icp" else \
            reg.TransformationEstimationForGeneralizedICP()
        fn = reg.registration_icp if method == "open3d-icp" else reg.registration_generalized_icp
        return np.asarray(fn(src, tgt, 2 * v, T0, est, reg.ICPConvergenceCriteria(max_iteration=60)).transformation)
    if method == "open3d-fpfh":
        o3d.utility.random.seed(seed)
        src, tgt = _cloud(s, v), _cloud(t, v)
        param = o3d.geometry.KDTreeSearchParamHybrid(radius=5 * v, max_nn=100)
        fs, ft = reg.compute_fpfh_feature(src, param), reg.compute_fpfh_feature(tgt, param)
        ransac = reg.registration_ransac_based_on_feature_matching(
            src, tgt, fs, ft, True, 1.5 * v, reg.TransformationEstimationPointToPoint(False), 3,
            [reg.CorrespondenceCheckerBasedOnEdgeLength(0.9), reg.CorrespondenceCheckerBasedOnDistance(1.5 * v)],
            reg.RANSACConvergenceCriteria(100000, 0.999))
        return np.asarray(reg.registration_icp(src, tgt, v, ransac.transformation,
                                               reg.TransformationEstimationPointToPlane()).transformation)
    from rangereg.core.kiss_matcher_candidates import kiss_available, kiss_candidates

    if not kiss_available():
        raise InputError("kiss-matcher is not installed")
    found = kiss_candidates(s, t, v, 1.0)
    if not found:
        raise InputError("KISS-Matcher found no pose")
    return found[0]


# ---- one task -----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorTask:
    pair: SensorPair
    mode: str
    rot: float
    trans: float
    start: int


def _judge(T: np.ndarray, T_true: np.ndarray) -> tuple[bool, float, float]:
    rot, tr = pose_error(T, T_true)  # at the source frame's origin: the sensor
    return bool(rot < OK_ROT and tr < OK_TRANS), rot, tr


def _ours(s, t, T0, task) -> tuple[np.ndarray | None, bool, str, float]:
    t0 = time.perf_counter()
    try:
        g = register(s, t, told(task.mode, task.rot, task.trans, T0), Config(method="global", seed=task.start))
        seconds = time.perf_counter() - t0
    except InputError as exc:
        return None, False, f"refused: {exc}", time.perf_counter() - t0
    except Exception as exc:  # noqa: BLE001 (a crash is a result of the sweep: kept, said, and the sweep goes on)
        return None, False, f"crashed: {type(exc).__name__}: {exc}", time.perf_counter() - t0
    finally:  # (after the seconds are taken) stages made ahead end before a peer runs: it uses Open3D's threads
        wait_ahead()
    return g.transform, bool(g.below_threshold), g.trust_text, seconds


def _starts(task: SensorTask, T_ref: np.ndarray) -> np.ndarray:
    return sensor_start(T_ref, task.rot, task.trans, task.start) if task.mode == "sensor" else np.eye(4)


def run_task(task: SensorTask) -> list[dict]:
    """Ours and every peer on one start (kinect: on the three pairs of a triple), each timed from the scans in
    memory to the pose (the load is timed once, apart)."""
    p = task.pair
    t0 = time.perf_counter()
    try:
        if p.family == "kinect":
            from rangereg.core.io import load_scan

            frames = [load_scan(f) for f in p.files]
        else:
            s, t, T_true = p.load()
    except InputError as exc:
        return [_row(task, m, False, np.nan, np.nan, 0.0, False if m == "global" else None, f"refused: {exc}")
                for m in ("global",) + PEERS]
    load_s = time.perf_counter() - t0
    rows = []
    methods = ("global",) + tuple(m for m in PEERS if m not in START_FREE or task.mode == "identity")
    for m in methods:
        if p.family == "kinect":
            rows.append(_chain(task, m, frames, load_s))
            continue
        T0 = _starts(task, T_true)
        if m == "global":
            T, trusted, why, sec = _ours(s, t, T0, task)
        else:
            t1, trusted, why = time.perf_counter(), None, ""
            from rangereg.core.candidates import scene_voxel

            try:
                T = peer(m, s, t, T0, scene_voxel(s, t), task.start)
            except Exception as exc:  # noqa: BLE001 (a peer that fails is a wrong pose)
                T, why = None, str(exc)
            sec = time.perf_counter() - t1
        ok, rot, tr = _judge(T, T_true) if T is not None else (False, np.nan, np.nan)
        rows.append(_row(task, m, ok, rot, tr, sec, trusted, why, load_s))
    return rows


def _chain(task: SensorTask, method: str, frames: list[Scan], load_s: float) -> dict:
    """The triple's three pairs by ``method``; right when T_02 agrees with T_01 T_12; trusted when all three are."""
    from rangereg.core.candidates import scene_voxel

    poses, trust, why, sec = [], [], "", 0.0
    for i, j in ((0, 1), (1, 2), (0, 2)):  # source frame j onto target frame i: T_i_j
        s, t = frames[j], frames[i]
        T0 = _starts(task, np.eye(4))
        if method == "global":
            T, trusted, w, dt = _ours(s, t, T0, task)
            trust.append(trusted)
            why = why or (w if not trusted else "")
        else:
            t1 = time.perf_counter()
            try:
                T = peer(method, s, t, T0, scene_voxel(s, t), task.start)
            except Exception as exc:  # noqa: BLE001 (a peer that fails is a wrong pose)
                T, why = None, str(exc)
            dt = time.perf_counter() - t1
        sec += dt
        poses.append(T)
    if any(T is None for T in poses):
        ok, rot, tr = False, np.nan, np.nan
    else:
        ok, rot, tr = _judge(poses[2], poses[0] @ poses[1])
    return _row(task, method, ok, rot, tr, sec / 3, all(trust) if method == "global" else None, why, load_s)


def _row(task, method, ok, rot, tr, sec, trusted, why="", load_s=0.0) -> dict:
    return {"family": task.pair.family, "pair": task.pair.name, "mode": task.mode, "offset": task.rot,
            "shift": task.trans, "start": task.start, "method": method, "ok": bool(ok), "rot_error": rot,
            "trans_error": tr, "seconds": sec, "load_seconds": load_s, "trusted": trusted, "why": why}


def sensor_tasks(families, modes, quick: bool, runs: int, data: Path = SHARED) -> list[SensorTask]:
    levels = LEVELS[1:2] if quick else LEVELS
    out = []
    for family in families:
        for pair in family_pairs(family, quick, data):
            for mode in modes:
                for k in range(1 if mode != "sensor" else runs):
                    for rot, trans in (levels if mode == "sensor" else ((0.0, 0.0),)):
                        out.append(SensorTask(pair, mode, rot, trans, k))
    return out


def sensor_table(rows: list[dict], load: str = "") -> str:
    """Per family and mode: ours (right, trusted-and-wrong, trusted-and-right, median s) beside each peer (right,
    median s)."""
    head = ("| family | mode | runs | global: right | trusted and wrong | trusted and right | median s | "
            + " | ".join(PEERS) + " |")
    lines = [head, "|" + "---|" * (7 + len(PEERS))]
    keys = sorted({(r["family"], r["mode"]) for r in rows}, key=lambda k: (FAMILIES.index(k[0]), MODES.index(k[1])))
    for fam, mode in keys:
        sel = [r for r in rows if (r["family"], r["mode"]) == (fam, mode)]
        g = [r for r in sel if r["method"] == "global"]
        k = sum(r["ok"] for r in g)
        tw = sum(bool(r["trusted"]) and not r["ok"] for r in g)
        tr = sum(bool(r["trusted"]) and r["ok"] for r in g)
        cells = []
        for m in PEERS:
            ps = [r for r in rows if r["family"] == fam and r["method"] == m
                  and r["mode"] == ("identity" if m in START_FREE else mode)]
            cells.append(f"{sum(r['ok'] for r in ps)}/{len(ps)}, {np.median([r['seconds'] for r in ps]):.2f} s"
                         if ps else "-")
        lines.append(f"| {fam} | {mode} | {len(g)} | {k}/{len(g)} | {tw} | {tr} | "
                     f"{np.median([r['seconds'] for r in g]):.2f} | " + " | ".join(cells) + " |")
    reasons = sorted({f"{r['family']}: {r['why'][:160]}" for r in rows
                      if r["method"] == "global" and r["why"].startswith(("refused", "crashed"))} if rows else [])
    lines += ["", "start-free peers (open3d-fpfh, kiss-matcher) run once per start of the identity mode and stand "
              "for every mode" + (f"; load average {load}" if load else "")]
    lines += [f"- {r}" for r in reasons]
    return "\n".join(lines)


def sweep_sensors(families, modes, quick: bool, runs: int, say=sys.stderr.write) -> tuple[list[dict], str]:
    """Every task in turn (rows, the table)."""
    import os

    rows = []
    for task in sensor_tasks(families, modes, quick, runs):
        for r in run_task(task):
            rows.append(r)
            say(f"  {r['family']:13s} {r['mode']:8s} {r['offset']:4g} deg {r['pair']:24s} {r['method']:13s} "
                f"{'ok ' if r['ok'] else 'NO '} {r['rot_error']:7.2f} deg {r['trans_error']:7.3f} m "
                f"{r['seconds']:6.2f} s" + (f" trust={r['trusted']}" if r["method"] == "global" else "") + "\n")
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    return rows, sensor_table(rows, load)
