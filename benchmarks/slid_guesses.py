"""Guesses slid along the free motion: a hunt for poses trusted and wrong that the sensor sweep's starts do not make.

    python benchmarks/slid_guesses.py [--families sim-room,sim-street,sim-fragments,lidar,corridor,dense-fragments]
    python benchmarks/slid_guesses.py --smallest   # one small room pair, one slide: a check that it runs

The rules, fixed before any result was seen (2026-12-06): for each pair with a truth (app/sweep_sensors.py's
families; "corridor": core.scenes_sensor's corridor of a road and two plain walls, seeds 0 and 1, free along
itself; "dense-fragments": benchmarks/sensor_time.py's 300k-point fragments of the room, seed 0), the constraint's
weakest translation at the truth on the global method's basis (core.threshold.constraint), and guesses = the truth
slid along it by 5, 10, 20 and 30 % of the target's size, both ways, given as ``Guess(T0)`` (the default stated
uncertainty: what a user with a poor odometry guess would say). Right: 1 deg and 5 cm at the sensor. Printed per
run: right or wrong, the errors, trusted or not, the constraint ratio, seconds; per family the count of poses
trusted and wrong (defects) and of right ones. A scene free along itself (the corridor) has no right pose to find:
there every trusted pose is a defect.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

SHARES = (0.05, 0.1, 0.2, 0.3)
FAMILIES = ("sim-room", "sim-street", "sim-fragments", "lidar", "corridor", "dense-fragments")


def pairs(family: str, smallest: bool):
    """(name, source, target, T_target_source) of ``family``."""
    from rangereg.app.sweep_sensors import family_pairs
    from rangereg.core import scenes_sensor as ss
    from rangereg.core.transforms import invert

    if family == "corridor":
        for k in range(2):
            s, t = ss.lidar_pair("corridor", k)
            yield f"corridor-{k}", s, t, invert(t.pose) @ s.pose
    elif family == "dense-fragments":
        s, t = ss.fragment_pair(0, frames=5, cam=ss.DepthCamera(cols=360, rows=270))
        yield "dense-fragments-0", s, t, invert(t.pose) @ s.pose
    else:
        for p in family_pairs(family, smallest)[:1 if smallest else None]:
            s, t, T = p.load()
            if T is not None:
                yield p.name, s, t, T


def weakest_translation(s, t, T: np.ndarray) -> np.ndarray:
    """(3,) unit: the translation the matched overlap pins least at pose T (target frame)."""
    from rangereg.core.candidates import for_search
    from rangereg.core.config import Config
    from rangereg.core.global_search.setup import prepare_setup
    from rangereg.core.guess import Guess
    from rangereg.core.threshold import constraint

    setup = prepare_setup(for_search(s), for_search(t), Guess(T), Config(method="global", seed=0))
    d = constraint(setup.basis, T).weakest[:3]
    return d / np.linalg.norm(d)


def main() -> int:
    from rangereg.app.sweep_sensors import OK_ROT, OK_TRANS
    from rangereg.core.guess import Guess
    from rangereg.core.register import Config, register
    from rangereg.core.transforms import pose_error

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--families", default=",".join(FAMILIES))
    p.add_argument("--smallest", action="store_true", help="one small room pair, one slide")
    a = p.parse_args()
    families = ["sim-room"] if a.smallest else a.families.split(",")
    for family in families:
        if family not in FAMILIES:
            print(f"unknown family {family!r}; choose from {', '.join(FAMILIES)}", file=sys.stderr)
            return 2
    for family in families:
        defects = right = runs = 0
        for name, s, t, T in pairs(family, a.smallest):
            along = weakest_translation(s, t, T)
            for share in SHARES[:1] if a.smallest else SHARES:
                for sign in (1, -1)[:1 if a.smallest else 2]:
                    T0 = T.copy()
                    T0[:3, 3] += sign * share * t.size * along
                    res = register(s, t, Guess(T0), Config(method="global", seed=0))
                    rot, move = pose_error(res.transform, T)
                    ok = rot < OK_ROT and move < OK_TRANS and family != "corridor"
                    runs, right = runs + 1, right + ok
                    defects += bool(res.trusted and not ok)
                    c = res.verdict.constraint
                    print(f"{name} slid {sign * share * t.size:+.2f} {s.units}: {'right' if ok else 'WRONG'} "
                          f"{rot:.3f} deg / {move:.3f} {s.units}, {'trusted' if res.trusted else 'not trusted'}, ratio "
                          f"{'-' if c is None else f'{c.ratio:.4f}'}, {res.seconds:.1f} s"
                          f"{'  <- trusted and wrong' if res.trusted and not ok else ''}", flush=True)
        print(f"{family}: {runs} runs, {right} right, {defects} trusted and wrong", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
