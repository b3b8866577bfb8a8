"""How long `rangereg register --json` takes, one process a run, on the sweep's starts: its own `seconds`
(reading both files to the result; `import_seconds`, the imports before, reported apart), median, p90 and
max per mode and offset, and whether the pose lies within 2 degrees and 2 mm of the truth.

    python benchmarks/register_time.py [--starts 2] [--passes 1] [--modes origin,no-guess] [BUNNY_DIR]
    python benchmarks/register_time.py --unregistrable   # pairs no rigid pose registers: what "not trusted" costs
    python benchmarks/register_time.py --smallest        # one run on the bundled corner pair: a check it runs

For every shared bunny pair (app.sweep's whole family) and every sweep offset, each mode's start (app.sweep:
the same seeded starts) is given to the CLI as a user would give it: the start as `--init` and the stated
rotation (`--rotation-uncertainty`, plus `--translation-uncertainty` in the centroid mode); in the no-guess
mode no `--init` and no flag at all. ``--unregistrable``: each shared pair with its source mirrored (x -> -x:
no rigid motion lays a mirror image on its original), no guess, so nothing is trusted and every stage and
the bounded fallback run: the time a run takes to say "not trusted". Run it on a quiet machine: one run at
a time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.app.sweep import MODES, SWEEP_LEVELS, SweepTask, View, start_pose, sweep_pairs, sweep_tasks, told  # noqa: E402
from rangereg.core.transforms import invert, pose_error  # noqa: E402


def flags(task: SweepTask, T0: np.ndarray) -> list[str]:
    """What a user tells the CLI in ``task``'s mode (app.sweep.told, in flags)."""
    if task.mode == "no-guess":
        return []
    guess = told(task, T0)
    out = ["--init=" + " ".join(repr(float(v)) for v in T0.ravel()), "--rotation-uncertainty",
           repr(guess.rotation_deg)]
    return out + (["--translation-uncertainty", repr(guess.translation)] if guess.translation is not None else [])


def one_run(task: SweepTask) -> dict:
    """One `rangereg register --json` of ``task``: seconds, import seconds, right or not, trusted or not."""
    s, t = task.source.load(), task.target.load()
    T0 = start_pose(task, s, t)
    cmd = [sys.executable, "-m", "rangereg.app.cli", "register", task.source.path, task.target.path, *flags(task, T0),
           "--seed", str(task.start), "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if out.returncode != 0:
        raise SystemExit(f"rangereg register failed: {out.stderr.strip()}")
    d = json.loads(out.stdout)
    rot_err, trans_err = pose_error(np.array(d["transform"]), invert(t.pose) @ s.pose, s.centroid)
    ok_trans = 2.0 if t.units == "mm" else 0.002  # 2 mm
    return {"mode": task.mode, "offset": task.rot, "pair": task.pair, "start": task.start, "seconds": d["seconds"],
            "import_seconds": d["import_seconds"], "right": bool(rot_err < 2.0 and trans_err < ok_trans),
            "trusted": bool(d["below_threshold"])}


def unregistrable_runs(folder: Path, starts: int) -> list[dict]:
    """Each whole pair's source mirrored, registered with no guess (module notes): seconds and trust."""
    import tempfile
    from dataclasses import replace

    from rangereg.core.io import load_scan, save_scan

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for _, s_view, t_view, _ in sweep_pairs(folder, ("whole",)):
            src = load_scan(s_view.path)
            mirrored = Path(tmp) / f"{Path(s_view.path).stem}-mirrored.ply"
            save_scan(mirrored, replace(src, points=src.points * [-1.0, 1.0, 1.0], viewpoint=src.viewpoint * [-1.0, 1.0, 1.0],
                                        pose=None, guess=None, faces=None))
            for k in range(starts):
                cmd = [sys.executable, "-m", "rangereg.app.cli", "register", str(mirrored), t_view.path,
                       "--seed", str(k), "--json"]
                out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT,
                                     env={**os.environ, "PYTHONPATH": str(ROOT)})
                if out.returncode != 0:
                    raise SystemExit(f"rangereg register failed: {out.stderr.strip()}")
                d = json.loads(out.stdout)
                rows.append({"mode": "unregistrable", "offset": 0.0, "pair": f"{mirrored.stem}->{t_view.name}",
                             "start": k, "seconds": d["seconds"], "import_seconds": d["import_seconds"], "right": False,
                             "trusted": bool(d["below_threshold"])})
                print(f"  mirrored {mirrored.stem}->{t_view.name} start {k}: {d['seconds']:.3f} s "
                      f"{'TRUSTED' if d['below_threshold'] else 'not trusted'} ({d['stop_reason']})", flush=True)
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--starts", type=int, default=2, help="starts per pair, mode and offset (the sweep's first ones)")
    ap.add_argument("--passes", type=int, default=1, help="passes over every run, one after the other")
    ap.add_argument("--modes", default="origin,no-guess", help=f"comma-separated of {', '.join(MODES)}")
    ap.add_argument("--smallest", action="store_true", help="one run: the bundled corner pair, 5 deg, origin mode")
    ap.add_argument("--unregistrable", action="store_true", help="the mirrored pairs only (module notes)")
    a = ap.parse_args()
    if a.starts < 1 or a.passes < 1:
        ap.error("--starts and --passes must be >= 1")
    modes = tuple(m for m in a.modes.split(",") if m)
    if not modes or any(m not in MODES for m in modes):
        ap.error(f"--modes: choose from {', '.join(MODES)}")
    if a.smallest:
        corner = ROOT / "assets" / "corner"
        tasks = [SweepTask("whole", View(str(corner / "scan2.ply")), View(str(corner / "scan1.ply")), "origin", 5.0, 10.0, 0)]
    elif not Path(a.bunny).is_dir():
        raise SystemExit(f"no bunny scans in {a.bunny} (give the folder of bun*.ply and bun.conf)")
    else:
        tasks = sweep_tasks(sweep_pairs(Path(a.bunny), ("whole",)), modes, SWEEP_LEVELS, a.starts)
    rows = []
    for p in range(a.passes):
        print(f"pass {p + 1}: load average {os.getloadavg()[0]:.1f}", flush=True)
        if a.unregistrable:
            rows += unregistrable_runs(Path(a.bunny), a.starts)
            continue
        for task in tasks:
            r = one_run(task)
            rows.append(r)
            print(f"  {task.mode:9s} {task.rot:5g} deg {task.pair:16s} start {task.start}: {r['seconds']:.3f} s "
                  f"(imports {r['import_seconds']:.2f} s apart) {'ok' if r['right'] else 'WRONG'}"
                  f"{'' if r['trusted'] else ' (not trusted)'}", flush=True)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    print("\n| mode | offset | runs | right | trusted | seconds median / p90 / max (files -> result) |")
    print("|---|---|---|---|---|---|")
    for key in dict.fromkeys((r["mode"], r["offset"]) for r in rows):
        sel = [r for r in rows if (r["mode"], r["offset"]) == key]
        sec = [r["seconds"] for r in sel]
        print(f"| {key[0]} | {'-' if key[0] in ('no-guess', 'unregistrable') else f'{key[1]:g} deg'} | {len(sel)} | "
              f"{sum(r['right'] for r in sel)} | {sum(r['trusted'] for r in sel)} | "
              f"{np.median(sec):.2f} / {np.percentile(sec, 90):.2f} / {max(sec):.2f} |")
    sec = [r["seconds"] for r in rows]
    print(f"\nall {len(rows)}: median {np.median(sec):.2f} s, p90 {np.percentile(sec, 90):.2f}, max {max(sec):.2f}; "
          f"imports (apart) median {np.median([r['import_seconds'] for r in rows]):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
