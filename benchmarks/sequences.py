"""Sequences of spinning-LiDAR frames and of depth frames merged as odometry plus loop closure (`rangereg merge --pairs
sequence`, core.merge_sequence), beside Open3D's point-to-plane ICP chained frame to frame from the identity.

    python benchmarks/sequences.py [--seeds 2] [--scenes street,room,rgbd] [--steps 0.5,1,2]
    python benchmarks/sequences.py --smallest   # a street of 3 small frames: a check that it runs

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
- rgbd (added the same day, before its first run): a depth camera (320 x 240, core.scenes_sensor.DepthCamera's
  noise) carried round the room's ellipse at 1.4 m, looking along its path 10 degrees down, 16 frames; steps 0.1,
  0.2 and 0.4 m (a hand-held camera's keyframes). Each frame goes through the assembly as an organised PCD would
  (its grid with NaN cells, PCL's default VIEWPOINT), as the shared Kinect frames do.
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
RGBD_FRAMES = 16


def street_path(rng: np.random.Generator, step: float, frames: int = STREET_FRAMES) -> list[np.ndarray]:
    x, y, yaw = rng.uniform(-20, -10), rng.uniform(-1.0, 1.0), rng.uniform(-3, 3)
    poses = []
    for _ in range(frames):
        poses.append(pose_at(x, y, 1.8 + rng.normal(0, 0.01), yaw))
        x += step * rng.uniform(0.9, 1.1)
        y += rng.normal(0, 0.1)
        yaw += rng.normal(0, 2.0)
    return poses


def room_path(rng: np.random.Generator, step: float, frames: int | None = None) -> list[tuple[float, float, float]]:
    """(x, y, heading in degrees) along the room's ellipse: once round in steps of about ``step`` m, or ``frames``
    steps of ``step`` m."""
    (cx, cy), (a, b) = ROOM_CENTRE, ROOM_RADII
    t = np.linspace(0, 2 * np.pi, 4001)
    xy = np.c_[cx + a * np.cos(t), cy + b * np.sin(t)]
    arc = np.r_[0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
    n = int(np.ceil(arc[-1] / step))
    spacing = arc[-1] / n if frames is None else step
    s0 = rng.uniform(0, arc[-1])
    out = []
    for k in range(n if frames is None else frames):
        s = (s0 + k * spacing) % arc[-1]
        i = min(max(int(np.searchsorted(arc, s)), 1), len(t) - 1)
        heading = np.degrees(np.arctan2(*(xy[i] - xy[i - 1])[::-1]))
        out.append((xy[i, 0], xy[i, 1], heading + rng.uniform(-5, 5)))
    return out


def depth_scan(mesh, T_world_camera: np.ndarray, cam, rng: np.random.Generator, name: str):
    """One depth frame through the assembly as an organised PCD holds it: its (rows, cols) grid, NaN where the camera
    measured nothing, PCL's default VIEWPOINT."""
    from rangereg.core.assemble import RawScan, assemble
    from rangereg.core.scenes_sensor import _pixel_rays, depth_image

    depth = depth_image(mesh, T_world_camera, cam, rng).ravel()
    points = _pixel_rays(cam) * depth[:, None]
    grid = np.where(np.isfinite(depth), np.arange(len(depth)), -1).reshape(cam.rows, cam.cols)
    return assemble(RawScan(points=points, what=name, name=name, grid=grid, viewpoint=np.zeros(3),
                            viewpoint_default=True, viewpoint_pose=True, units="m"))


def frames(scene: str, step: float, seed: int, smallest: bool = False):
    """(scans, T_world_sensor per scan) of one drive (module notes); ``smallest``: a street of 3 frames of a 16 x 512
    LiDAR (a check that it runs)."""
    rng = np.random.default_rng(seed)
    if scene == "street" and smallest:
        mesh, lidar, poses = street_mesh(), Spinning(rings=16, steps=512), street_path(rng, step, 3)
    elif scene == "street":
        mesh, lidar, poses = street_mesh(), Spinning(), street_path(rng, step)
    elif scene == "room":
        mesh, poses = room_mesh(), [pose_at(x, y, 1.2, h) for x, y, h in room_path(rng, step)]
        lidar = replace(Spinning(), elevation_deg=(-30.0, 30.0), noise=min(Spinning().noise, 0.01), min_range=0.3)
    else:
        from rangereg.core.scenes_sensor import DepthCamera, look_from

        mesh, cam = room_mesh(), DepthCamera(cols=320, rows=240)
        poses = []
        for x, y, h in room_path(rng, step, RGBD_FRAMES):
            eye = np.r_[x, y, 1.4]
            poses.append(look_from(eye, eye + np.r_[np.cos(np.radians(h)), np.sin(np.radians(h)), -np.tan(np.radians(10.0))]))
        return [depth_scan(mesh, T, cam, rng, f"{scene}-{k}") for k, T in enumerate(poses)], poses
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
    ap.add_argument("--scenes", default="street,room,rgbd")
    ap.add_argument("--steps", default="", help="steps in m (default: the scene's three)")
    ap.add_argument("--smallest", action="store_true", help="one street of 3 frames: a check that it runs")
    a = ap.parse_args()
    if a.smallest:
        a.seeds, a.scenes, a.steps = 1, "street", "1"
    default_steps = {"street": (0.5, 1.0, 2.0), "room": (0.25, 0.5, 1.0), "rgbd": (0.1, 0.2, 0.4)}
    rows = []
    print(f"load {os.getloadavg()[0]:.1f}", flush=True)
    for scene in a.scenes.split(","):
        steps = tuple(float(s) for s in a.steps.split(",")) if a.steps else default_steps[scene]
        for step in steps:
            for seed in range(a.seeds):
                scans, truth = frames(scene, step, seed, a.smallest)
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
