"""Files to pose on sensor scans: `rangereg register --json`, one whole process a run, as a user runs it.

    python benchmarks/sensor_time.py [--runs 3] [--pairs lidar,kinect,fragments] [--data ../shared/data]
    python benchmarks/sensor_time.py --smallest   # one run on a small simulated fragment pair: a check it runs

Pairs (no `--init`, no flag: the identity and no stated uncertainty, so the global method's no-guess search):

- lidar: the shared spinning-LiDAR frames (../shared/data/lidar, 69k points each), 251371071 onto 251370668;
  right within 1 degree and 5 cm (at the sensor) of relative.txt (T_target_source);
- kinect: the shared Kinect frames capture0002 onto capture0001 (640 x 480 organised PCD, ~250k points each);
  no truth: the pose is printed and said trusted or not;
- fragments: two simulated RGB-D fragments of the room (core.scenes_sensor.fragment_pair, seed 0, five
  360 x 270 depth frames each, ~280-300k points), written as PLY with their JSON sidecars (poses: the truth);
  right within 1 degree and 5 cm.

Per run: the process's wall seconds (start to exit: imports, reading, registering, printing), the CLI's own
`seconds` (reading both files to the result) and `import_seconds`, and the CPU seconds (user + sys) of the
process and its children (KISS-Matcher's child process included), which a loaded machine inflates far less
than the wall seconds. Medians over ``--runs``, with the load average before and after each pair.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

OK_ROT, OK_TRANS = 1.0, 0.05  # degrees, metres (at the sensor: the source frame's origin)


def one_run(source: str, target: str) -> dict:
    """One whole `rangereg register --json` process: its wall, CPU and own seconds and its result."""
    cmd = [sys.executable, "-m", "rangereg.app.cli", "register", source, target, "--json"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)})
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if out.returncode != 0:
        raise SystemExit(f"rangereg register failed: {out.stderr.strip()}")
    d = json.loads(out.stdout)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return {"wall": wall, "cpu": cpu, "seconds": d["seconds"], "import_seconds": d["import_seconds"],
            "T": np.array(d["transform"]), "trusted": bool(d["below_threshold"]), "found_by": d.get("found_by", "")}


def fragment_files(folder: Path, small: bool = False) -> tuple[str, str, np.ndarray]:
    """The simulated fragment pair written to ``folder``: (source path, target path, T_target_source)."""
    from rangereg.core.io import save_scan
    from rangereg.core.scenes_sensor import DepthCamera, fragment_pair
    from rangereg.core.transforms import invert

    cam = DepthCamera(cols=80, rows=60) if small else DepthCamera(cols=360, rows=270)
    s, t = fragment_pair(0, frames=3 if small else 5, cam=cam)
    paths = [folder / f"{scan.name}.ply" for scan in (s, t)]
    for p, scan in zip(paths, (s, t)):
        save_scan(p, scan)
    return str(paths[0]), str(paths[1]), invert(t.pose) @ s.pose


def pairs(names: list[str], tmp: Path, shared: Path, small: bool = False) -> list[tuple[str, str, str, np.ndarray | None]]:
    if small:  # a check that the script runs: one small simulated fragment pair
        return [("fragments", *fragment_files(tmp, small=True))]
    out = []
    if "lidar" in names and (shared / "lidar").is_dir():
        d = shared / "lidar"
        out.append(("lidar", str(d / "251371071.pcd"), str(d / "251370668.pcd"), np.loadtxt(d / "relative.txt")))
    if "kinect" in names and (shared / "kinect").is_dir():
        d = shared / "kinect"
        out.append(("kinect", str(d / "capture0002.pcd"), str(d / "capture0001.pcd"), None))
    if "fragments" in names:
        out.append(("fragments", *fragment_files(tmp)))
    return out


def points_in(path: str) -> int:
    from rangereg.core.io import load_scan

    return len(load_scan(path).points)


def main() -> int:
    from rangereg.core.transforms import pose_error

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="whole-process runs per pair (default 3)")
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "data"), help="the shared data folder (lidar/, kinect/)")
    ap.add_argument("--pairs", default="lidar,kinect,fragments", help="comma-separated of lidar, kinect, fragments")
    ap.add_argument("--smallest", action="store_true", help="one run on a small simulated fragment pair: a check it runs")
    a = ap.parse_args()
    if a.smallest:
        a.runs = 1
    if a.runs < 1:
        ap.error("--runs must be >= 1")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, src, tgt, T_true in pairs([p for p in a.pairs.split(",") if p], Path(tmp), Path(a.data), a.smallest):
            n = (points_in(src), points_in(tgt))
            load = os.getloadavg()[0]
            runs = [one_run(src, tgt) for _ in range(a.runs)]
            load_after = os.getloadavg()[0]
            for r in runs:
                verdict = ""
                if T_true is not None:
                    rot, tr = pose_error(r["T"], T_true)
                    verdict = f"{'right' if rot < OK_ROT and tr < OK_TRANS else 'WRONG'} ({rot:.2f} deg, {tr * 100:.1f} cm)"
                print(f"  {name:9s} wall {r['wall']:.2f} s  cpu {r['cpu']:.2f} s  files->pose {r['seconds']:.2f} s  "
                      f"imports {r['import_seconds']:.2f} s  {verdict} {'trusted' if r['trusted'] else 'NOT trusted'}"
                      f"  [{r['found_by']}]", flush=True)
            med = {k: float(np.median([r[k] for r in runs])) for k in ("wall", "cpu", "seconds")}
            rows.append((name, n, a.runs, med, load, load_after))
    print("\n| pair | points (source, target) | runs | process wall s | CPU s (user+sys) | files->pose s (CLI) "
          "| load before / after |")
    print("|---|---|---|---|---|---|---|")
    for name, n, k, med, l0, l1 in rows:
        print(f"| {name} | {n[0]:,}, {n[1]:,} | {k} | {med['wall']:.2f} | {med['cpu']:.2f} | {med['seconds']:.2f} | "
              f"{l0:.1f} / {l1:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
