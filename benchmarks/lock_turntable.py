"""What a turntable lock buys: the hybrid with and without it, from starts turned on the table.

    python benchmarks/lock_turntable.py [BUNNY_DIR]

For bun045 -> bun000 and bun090 -> bun000 the turntable axis is the screw axis of the ground-truth
transform (bun.conf; its pitch, the slide along the axis, is printed: 0.44 and 0.03 mm); each start
is the truth turned about that axis by the angles below, so the truth is on the locked set (the
overlap is then cut under a guess that is off by that angle). Prints, per start, the rotation error
(deg), the translation error at the scan's centroid (mm) and the time, locked (turntable: one free
angle) and unlocked (six).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from core import Config, load_conf, load_scan, register  # noqa: E402
from core.lock import Lock  # noqa: E402
from core.transforms import invert, perturb, pose_error, to_params  # noqa: E402

ANGLES_DEG = (-30.0, -15.0, 15.0, 30.0)


def screw_axis(T: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(point (3,), unit direction (3,), pitch: the slide along the axis) of a rigid T with a rotation."""
    r = to_params(T)[3:]
    d = r / np.linalg.norm(r)
    t = T[:3, 3]
    p = np.linalg.lstsq(np.eye(3) - T[:3, :3], t - (t @ d) * d, rcond=None)[0]
    return p - (p @ d) * d, d, float(t @ d)


def main(bunny: Path) -> None:
    poses = load_conf(bunny / "bun.conf")
    target = load_scan(bunny / "bun000.ply")
    for name in ("bun045", "bun090"):
        source = load_scan(bunny / f"{name}.ply")
        Tt = invert(poses["bun000"]) @ poses[name]
        point, axis, pitch = screw_axis(Tt)
        lock = Lock(axis_point=tuple(point), axis_direction=tuple(axis))
        c = source.points.mean(0)
        print(f"{name} -> bun000: axis through {np.round(point * 1000, 1)} mm along {np.round(axis, 3)}, "
              f"pitch {pitch * 1000:.3f} mm")
        for angle in ANGLES_DEG:
            T0 = perturb(Tt, np.r_[0, 0, 0, np.radians(angle) * axis], point)
            row = [f"  start {angle:+5.0f} deg:"]
            for label, cfg in (("locked", Config(method="hybrid", lock=lock)), ("free", Config(method="hybrid"))):
                t0 = time.perf_counter()
                res = register(source, target, T0, cfg)
                rot, tr = pose_error(res.transform, Tt, c)
                row.append(f"{label} {rot:6.2f} deg {tr * 1000:6.2f} mm {time.perf_counter() - t0:5.1f} s")
            print("  ".join(row), flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "data" / "bunny")
