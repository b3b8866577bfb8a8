"""The sensor sweep's simulated families on pairs it never ran: other seeds, the same rules.

    python benchmarks/held_out_sensors.py [--seeds 3-5] [--families sim-street,sim-room,sim-fragments] [--starts 2]
    python benchmarks/held_out_sensors.py --smallest   # one quick pair, one start a mode: a check that it runs

`rangereg bench --sweep` (app/sweep_sensors.py) runs each simulated family on the pairs of seeds 0-2, which the
engine was built and checked on. This runs the same families, modes and starts (identity; 5-60 deg / 0.1-1 m about
the sensor, ``--starts`` seeded starts a level; no guess) on the pairs of other seeds, peers left out. A seed moves
the sensors (the odometry step, the camera walk) and draws the noise; the street and the room are the same scenes
(core.scenes_sensor builds them unseeded), so this tests other viewpoints of them, not other places. Right: within 1
degree and 5 cm at the sensor, as the sweep judges.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

sys.path.insert(0, str(Path(__file__).resolve().parent))

import rangereg.app.sweep_sensors as S  # noqa: E402
from tsdf_modes import seed_range  # noqa: E402

SIMULATED = ("sim-street", "sim-room", "sim-fragments")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="3-5", help="scene seeds, e.g. 3-5 (the sweep's: 0-2)")
    ap.add_argument("--families", default=",".join(SIMULATED))
    ap.add_argument("--starts", type=int, default=2, help="seeded starts a sensor level (default 2)")
    ap.add_argument("--smallest", action="store_true", help="one quick pair, one start a mode")
    a = ap.parse_args()
    try:
        seeds = seed_range(a.seeds)
    except ValueError:
        ap.error("--seeds takes a seed or a range, e.g. 3-5")
    families = [f for f in a.families.split(",") if f]
    if not seeds or a.starts < 1 or not set(families) <= set(SIMULATED):
        ap.error(f"--seeds needs a seed, --starts >= 1, --families some of {', '.join(SIMULATED)}")
    if a.smallest:
        seeds, families, a.starts = seeds[:1], families[:1], 1
    S.PEERS = ()
    tasks = []
    for fam in families:
        for k in seeds:
            pair = S.SensorPair(fam, f"{fam}-{k}", seed=k, quick=a.smallest)
            for mode in S.MODES:
                levels = (S.LEVELS[1:2] if a.smallest else S.LEVELS) if mode == "sensor" else ((0.0, 0.0),)
                for start in range(a.starts if mode == "sensor" else 1):
                    tasks.extend(S.SensorTask(pair, mode, rot, trans, start) for rot, trans in levels)
    rows, t0 = [], time.time()
    for task in tasks:
        for r in S.run_task(task):
            rows.append(r)
            if not r["ok"]:
                print(f"  {'TRUSTED AND WRONG' if r['trusted'] else 'miss, doubted'}: {r['pair']} {r['mode']} "
                      f"{r['offset']:g} deg {r['shift']:g} m start {r['start']}: {r['rot_error']:.2f} deg, "
                      f"{r['trans_error'] * 100:.1f} cm", flush=True)
    print(S.sensor_table(rows, " / ".join(f"{x:.1f}" for x in os.getloadavg())))
    print(f"{len(rows)} runs in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
