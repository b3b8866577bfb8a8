"""Sequences of spinning-LiDAR frames merged as odometry plus loop closure (`rangereg merge --pairs sequence`,
core.merge_sequence), beside Open3D's point-to-plane ICP chained frame to frame from the identity.

    python benchmarks/sequences.py [--seeds 2] [--scenes street,room] [--steps 0.5,1,2]

Rules (fixed on 2026-12-06 before any result was seen). The merge's sequence step was measured before on a street
of 8 frames 0.5 m apart and on the five shared Kinect frames only; at steps of 1 m or more single pairs of a street
or room slid along it, trusted, before the walk along the free motion was added, and sequences were not measured
again. Here, with no initial poses (frames in capture order, each from the identity, as a user drops a drive's
frames on the merge):

- street: the sweep's street (core.scenes_sensor.street_mesh) and LiDAR (32 rings), 10 frames driven along it,
  each step the given length +-10 %, the lateral position a random walk of 0.1 m a frame and the heading one of 2
  degrees a frame; steps 0.5, 1 and 2 m (5, 10 and 20 m/s at 10 Hz).
- room: the sweep's room (core.scenes_sensor.room_mesh, 7 x 5 m) and its LiDAR settings, a robot driving once
  round an ellipse (radii 1.5 and 0.9 m about the room's middle), heading along its path +-5 degrees, the sensor
  1.2 m up; steps 0.25, 0.5 and 1 m (31, 16 and 8 frames; at 1 m the heading turns ~45 degrees a frame). The
  path closes on itself, so the loop closure has a loop to close.
- seeds 0 .. --seeds - 1; every frame's pose judged in the reference frame the merge reports (the first frame
  unless its group is not the largest): right within 1 degree and 5 cm at the frame's sensor; placed and not
  right is placed wrong; the worst placed error is printed. Loops: how many the graph closed and the largest
  closing residual after its optimisation.
- The peer: Open3D point-to-plane ICP from the identity between consecutive frames (app.sweep_sensors.peer at the
  scene's voxel), chained: what a user without a loop closer gets. Its frames judged the same way, against the
  first frame.

Seconds are the merge's from scans in memory to poses (no model built), on this machine at the load printed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from dataclasses import replace

import numpy as np
from rangereg.core.candidates import scene_voxel
from rangereg.core.merge import merge
from rangereg.core.scenes_sensor import Spinning, pose_at, room_mesh, spin_scan, street_mesh
from rangereg.core.transforms import invert, pose_error

OK_ROT, OK_TRANS = 1.0, 0.05
STREET_FRAMES = 10
ROOM_CENTRE, ROOM_RADII = (3.5, 2.5), (1.5, 0.9)


def street_path(rng: np.random.Generator, step: float) -> list[np.ndarray]:
    x, y, yaw = rng.uniform(-20, -10), rng.uniform(-1.0, 1.0), rng.uniform(-3, 3)
    poses = []
    for _ in range(STREET_FRAMES):
        poses.append(pose_at(x, y, 1.8 + rng.normal(0, 0.01), yaw))
        x += step * rng.uniform(0.9, 1.1)
        y += rng.normal(0, 0.1)
        yaw += rng.normal(0, 2.0)
    return poses


def room_path(rng: np.random.Generator, step: float) -> list[np.ndarray]:
    (cx, cy), (a, b) = ROOM_CENTRE, ROOM_RADII
    t = np.linspace(0, 2 * np.pi, 4001)
    xy = np.c_[cx + a * np.cos(t), cy + b * np.sin(t)]
    arc = np.r_[0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    n = int(np.ceil(arc[-1] / step))
    s0 = rng.uniform(0, arc[-1])
    poses = []
    for k in range(n):
        s = (s0 + k * arc[-1] / n) % arc[-1]
        i = int(np.searchsorted(arc, s))
        i = min(max(i, 1), len(t) - 1)
        heading = np.degrees(np.arctan2(*(xy[i] - xy[i - 1])[::-1]))
        poses.append(pose_at(xy[i, 0], xy[i, 1], 1.2, heading + rng.uniform(-5, 5)))
    return poses


def frames(scene: str, step: float, seed: int):
    rng = np.random.default_rng(seed)
    if scene == "street":
        mesh, lidar, poses = street_mesh(), Spinning(), street_path(rng, step)
    else:
        mesh, poses = room_mesh(), room_path(rng, step)
        lidar = replace(Spinning(), elevation_deg=(-30.0, 30.0), noise=min(Spinning().noise, 0.01), min_range=0.3)
    return [spin_scan(mesh, T, lidar, rng, name=f"{scene}-{k}") for k, T in enumerate(poses)], poses


def judge(found: list, truth: list[np.ndarray], ref: int) -> tuple[int, int, int, float, float]:
    """(right, placed wrong, not placed, worst degrees, worst m) of poses T_ref_k against the truth."""
    right = wrong = missing = 0
    worst = (0.0, 0.0)
    for k, P in enumerate(found):
        if P is None:
            missing += 1
            continue
        rot, tr = pose_error(P, invert(truth[ref]) @ truth[k])
        worst = max(worst, (rot, tr))
        if rot < OK_ROT and tr < OK_TRANS:
            right += 1
        else:
            wrong += 1
    return right, wrong, missing, worst[0], worst[1]


def chained_icp(scans, voxel: float) -> list[np.ndarray]:
    from rangereg.app.sweep_sensors import peer

    poses = [np.eye(4)]
    for k in range(1, len(scans)):
        poses.append(poses[-1] @ peer("open3d-icp", scans[k], scans[k - 1], np.eye(4), voxel, 0))
    return poses


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--scenes", default="street,room")
    ap.add_argument("--steps", default="", help="steps in m (default: the scene's three)")
    a = ap.parse_args()
    default_steps = {"street": (0.5, 1.0, 2.0), "room": (0.25, 0.5, 1.0)}
    rows = []
    print(f"load {os.getloadavg()[0]:.1f}", flush=True)
    for scene in a.scenes.split(","):
        steps = tuple(float(s) for s in a.steps.split(",")) if a.steps else default_steps[scene]
        for step in steps:
            for seed in range(a.seeds):
                scans, truth = frames(scene, step, seed)
                t0 = time.perf_counter()
                res = merge(scans, pairs="sequence", build_model=False)
                sec = time.perf_counter() - t0
                ours = judge(res.poses, truth, res.reference)
                after = max((r.after for r in res.rings), default=(0.0, 0.0))
                icp = judge(chained_icp(scans, scene_voxel(scans[1], scans[0])), truth, 0)
                rows.append((scene, step, seed, len(scans), ours, icp, sec, len(res.rings)))
                print(f"  {scene} step {step:g} m seed {seed}, {len(scans)} frames: ours {ours[0]} right / {ours[1]} "
                      f"wrong / {ours[2]} not placed, worst {ours[3]:.3f} deg / {100 * ours[4]:.1f} cm, "
                      f"{len(res.rings)} loops (largest residual after {after[0]:.3f} deg / {100 * after[1]:.1f} cm), "
                      f"{sec:.1f} s ({res.registrations} registrations); chained ICP {icp[0]} right, worst "
                      f"{icp[3]:.2f} deg / {100 * icp[4]:.1f} cm", flush=True)
    print(f"\nload {os.getloadavg()[0]:.1f}\n")
    print("| scene | step m | frames | right / placed wrong / not placed | worst placed | loops | s | "
          "chained Open3D ICP right | its worst |")
    print("|---|---|---|---|---|---|---|---|---|")
    for scene, step, seed, n, o, i, sec, loops in rows:
        print(f"| {scene} {seed} | {step:g} | {n} | {o[0]} / {o[1]} / {o[2]} | {o[3]:.3f} deg / {100 * o[4]:.1f} cm | "
              f"{loops} | {sec:.1f} | {i[0]} | {i[3]:.2f} deg / {100 * i[4]:.1f} cm |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
