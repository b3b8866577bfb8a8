"""How long `rangereg register --json` takes, one process a run, on the sweep's starts (the target: a
median wall time <= 1 s on a 40k-point pair).

    python benchmarks/register_time.py [--starts 2] [--passes 2] [--smallest] [BUNNY_DIR]

For every shared bunny pair and every sweep offset (app.sweep: the same seeded starts and the same
stated uncertainty as `rangereg bench --sweep`), runs the CLI once per start and reads its own
`seconds` (reading both files to the result; `import_seconds`, the imports before, are reported
apart) and whether the pose lies within 2 degrees and 2 mm of the truth. Prints a row per run, then
per offset the median and range of each pass. Run it on a quiet machine: one run at a time.
``--smallest``: one run on the bundled corner pair at the first offset (a check that the script runs).
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

from app.sweep import SWEEP_LEVELS, SweepTask, _load_pair, _sweep_start, shared_pairs, told  # noqa: E402
from core.transforms import invert, pose_error  # noqa: E402


def one_run(s_path: Path, t_path: Path, rot: float, trans: float, k: int) -> tuple[float, float, bool]:
    """(seconds, import seconds, right) of one `rangereg register --json` from start ``k``."""
    task = SweepTask(str(s_path), str(t_path), rot, trans, k)
    s, t, _ = _load_pair(task)
    T0 = _sweep_start(task, s, t)
    r_unc, t_unc = told(rot, trans)
    cmd = [sys.executable, "-m", "app.cli", "register", str(s_path), str(t_path),
           "--init=" + " ".join(repr(float(v)) for v in T0.ravel()), "--rotation-uncertainty", str(r_unc),
           "--translation-uncertainty", str(t_unc), "--seed", str(k), "--json"]
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    if out.returncode != 0:
        raise SystemExit(f"rangereg register failed: {out.stderr.strip()}")
    d = json.loads(out.stdout)
    rot_err, trans_err = pose_error(np.array(d["transform"]), invert(t.pose) @ s.pose, s.centroid)
    return d["seconds"], d["import_seconds"], bool(rot_err < 2.0 and trans_err < 0.002)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--starts", type=int, default=2, help="starts per pair and offset (the sweep's first ones)")
    ap.add_argument("--passes", type=int, default=2, help="passes over every run, one after the other")
    ap.add_argument("--smallest", action="store_true", help="one run: the corner pair, the first offset")
    a = ap.parse_args()
    if a.starts < 1 or a.passes < 1:
        ap.error("--starts and --passes must be >= 1")
    levels = SWEEP_LEVELS
    if a.smallest:
        corner = ROOT / "assets" / "corner"
        pairs, levels, a.starts, a.passes = [(corner / "scan2.ply", corner / "scan1.ply", None)], levels[:1], 1, 1
    elif not Path(a.bunny).is_dir():
        raise SystemExit(f"no bunny scans in {a.bunny} (give the folder of bun*.ply and bun.conf)")
    else:
        pairs = shared_pairs(Path(a.bunny))
    passes = []
    for p in range(a.passes):
        print(f"pass {p + 1}: load average {os.getloadavg()[0]:.1f}", flush=True)
        rows = []
        for k in range(a.starts):
            for rot, trans in levels:
                for s_path, t_path, _ in pairs:
                    sec, imp, ok = one_run(s_path, t_path, rot, trans, k)
                    rows.append((rot, sec, imp, ok))
                    print(f"  {rot:5g} deg {s_path.stem}->{t_path.stem} start {k}: {sec:.3f} s "
                          f"(imports {imp:.2f} s apart) {'ok' if ok else 'WRONG'}", flush=True)
        passes.append(rows)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    print("\n| offset | runs a pass | right | median s, each pass (files -> result) | range |")
    print("|---|---|---|---|---|")
    for rot, trans in levels:
        sel = [[r for r in rows if r[0] == rot] for rows in passes]
        right = sum(r[3] for rows in sel for r in rows)
        med = " / ".join(f"{np.median([r[1] for r in rows]):.2f}" for rows in sel)
        lo, hi = min(r[1] for rows in sel for r in rows), max(r[1] for rows in sel for r in rows)
        print(f"| {rot:g} deg / {trans * 1000:g} mm | {len(sel[0])} | {right}/{sum(map(len, sel))} | {med} | "
              f"{lo:.2f}-{hi:.2f} |")
    every = [r for rows in passes for r in rows]
    print(f"\nall: median {np.median([r[1] for r in every]):.2f} s; imports (apart) median "
          f"{np.median([r[2] for r in every]):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
