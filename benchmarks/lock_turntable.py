"""What a turntable lock buys: the hybrid with and without it, from starts turned on the table.

    python benchmarks/lock_turntable.py [BUNNY_DIR] [--smallest]

For bun045 -> bun000 and bun090 -> bun000 the turntable axis is the screw axis of the ground-truth
transform (bun.conf; its pitch, the slide along the axis, is printed: 0.44 and 0.03 mm); each start
is the truth turned about that axis by the angles below, so the truth is on the locked set (the
overlap is then cut under a guess that is off by that angle). Prints, per start, the rotation error
(deg), the translation error at the scan's centroid (mm) and the time, locked (turntable: one free
angle) and unlocked (six). ``--smallest``: the bundled corner pair (its truth from the sidecars), one
start (a check that the script runs).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.core import Config, load_conf, load_scan, register  # noqa: E402
from rangereg.core.lock import Lock  # noqa: E402
from rangereg.core.transforms import invert, perturb, pose_error, to_params  # noqa: E402

ANGLES_DEG = (-30.0, -15.0, 15.0, 30.0)


def screw_axis(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(point (3,), unit direction (3,), pitch: the slide along the axis) of a rigid T with a rotation."""
    r = to_params(T)[3:]
    d = r / np.linalg.norm(r)
    t = T[:3, 3]
    p = np.linalg.lstsq(np.eye(3) - T[:3, :3], t - (t @ d) * d, rcond=None)[0]
    return p - (p @ d) * d, d, float(t @ d)


def pairs(bunny: Path, smallest: bool):
    """(source, target, T_target_source true) of each pair: bun045 and bun090 onto bun000 (the corner's)."""
    if smallest:
        target, source = (load_scan(ROOT / "assets" / "corner" / f"{n}.ply") for n in ("scan1", "scan2"))
        yield source, target, invert(target.pose) @ source.pose
        return
    poses = load_conf(bunny / "bun.conf")
    target = load_scan(bunny / "bun000.ply")
    for name in ("bun045", "bun090"):
        yield load_scan(bunny / f"{name}.ply"), target, invert(poses["bun000"]) @ poses[name]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--smallest", action="store_true", help="the corner pair, one start")
    a = ap.parse_args()
    for source, target, Tt in pairs(Path(a.bunny), a.smallest):
        name = source.name
        point, axis, pitch = screw_axis(Tt)
        lock = Lock(axis_point=tuple(point), axis_direction=tuple(axis))
        c = source.points.mean(0)
        mm = 1000.0 if target.units == "m" else 1.0  # the bunny is in metres, the corner in mm
        print(f"{name} -> {target.name}: axis through {np.round(point * mm, 1)} mm along {np.round(axis, 3)}, "
              f"pitch {pitch * mm:.3f} mm")
        for angle in ANGLES_DEG[2:3] if a.smallest else ANGLES_DEG:
            T0 = perturb(Tt, np.r_[0, 0, 0, np.radians(angle) * axis], point)
            row = [f"  start {angle:+5.0f} deg:"]
            for label, cfg in (("locked", Config(method="hybrid", lock=lock)), ("free", Config(method="hybrid"))):
                t0 = time.perf_counter()
                res = register(source, target, T0, cfg)
                rot, tr = pose_error(res.transform, Tt, c)
                row.append(f"{label} {rot:6.2f} deg {tr * mm:6.2f} mm {time.perf_counter() - t0:5.1f} s")
            print("  ".join(row), flush=True)


if __name__ == "__main__":
    main()
