"""A pair of 2,000,000-point scans: time and peak memory per stage, and the pose error.

    python benchmarks/large_pair.py [--points N] [--seed S] [--dir DIR] [--skip-cli] [--skip-stages] [--smallest]

Simulates (seeded) two dense scans of an asymmetric landscape with the range scanner of
core/simulate.py (true poses and a rough guess for the source in the JSON sidecars), writes them
as binary PLY to a temporary folder (or DIR), then
1. runs ``rangereg register SOURCE TARGET --json`` as a subprocess (the default method): wall time and
   peak memory of the whole command (imports included), and its pose error against the truth;
2. runs the paper's hybrid stage by stage in this process: read both files, the target's surface, the
   overlap cut (prepare), the threshold (noise floor), the search; for each, wall time and the
   process's peak resident memory during it (Linux: the high-water mark is reset before each stage).
Targets: <= 4 GB and <= 90 s from reading to result (60 s a stretch). ``--smallest``: 3,000 points a
scan, every step once (a check that the script runs, not a measurement).
Timings are noisy on a shared machine: the CPU time of each stage is printed beside its wall
time (Open3D's ray casts use every core, so there CPU time can exceed wall time).
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

from rangereg.core.io import load_scan, write_sidecar  # noqa: E402
from rangereg.core.ply import write_ply  # noqa: E402
from rangereg.core.transforms import invert, pose_error  # noqa: E402


def _reset_peak() -> bool:
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_gb() -> float:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1e6  # kB -> GB
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e6


class Stages:
    def __init__(self):
        self.rows = []

    def run(self, name, fn):
        resettable = _reset_peak()
        t0, c0 = time.perf_counter(), time.process_time()
        out = fn()
        dt, cpu = time.perf_counter() - t0, time.process_time() - c0
        self.rows.append((name, dt, _peak_gb(), resettable, cpu))
        print(f"  {name:10s} {dt:7.2f} s   cpu {cpu:7.2f} s   peak {self.rows[-1][2]:5.2f} GB", flush=True)
        return out


def generate(folder: Path, n_points: int, seed: int, mesh_n: int = 601) -> tuple[Path, Path]:
    from rangereg.core.simulate import make_large_pair

    t0 = time.perf_counter()
    target, source = make_large_pair(n_points, seed, mesh_n=mesh_n)
    paths = []
    for scan in (source, target):
        path = folder / f"{scan.name}.ply"
        write_ply(path, scan.points)
        write_sidecar(path, scan)
        paths.append(path)
    print(f"generated {len(source.points):,} + {len(target.points):,} points in {time.perf_counter() - t0:.1f} s "
          f"({sum(p.stat().st_size for p in paths) / 1e6:.0f} MB of binary PLY in {folder})", flush=True)
    return paths[0], paths[1]


def in_process(source_path: Path, target_path: Path, seed: int) -> None:
    from dataclasses import replace

    from rangereg.core.problem import prepare, relative_guess
    from rangereg.core.register import Config, estimate_threshold, register
    from rangereg.core.surface import Surface

    st = Stages()
    print("the hybrid's stages (in this process):")
    source, target = st.run("read", lambda: (load_scan(source_path), load_scan(target_path)))

    def surfaces():
        s = Surface.from_scan(target)
        s.closest(target.points[:1])  # builds the ray-casting scene
        return s

    surface = st.run("surfaces", surfaces)
    T_init = relative_guess(source, target)
    config = Config(method="hybrid", seed=seed)
    problem = st.run("overlap", lambda: prepare(source, target, T_init, config.problem, surface, seed=config.seed))
    threshold = st.run("threshold", lambda: estimate_threshold(problem, seed))
    res = st.run("search", lambda: register(source, target, T_init, replace(config, threshold=threshold),
                                            problem=problem))
    total, cpu = sum(r[1] for r in st.rows), sum(r[4] for r in st.rows)
    rot, tr = pose_error(res.transform, invert(target.pose) @ source.pose, source.points.mean(0))
    print(f"  {'total':10s} {total:7.2f} s   cpu {cpu:7.2f} s   peak {max(r[2] for r in st.rows):5.2f} GB"
          + ("" if all(r[3] for r in st.rows) else "  (peak not resettable here: cumulative)"))
    print(f"  result: {res!r}")
    print(f"  pose error vs truth: {rot:.3f} deg, {tr:.3f} {target.units} (at the source centroid)")


def cli(source_path: Path, target_path: Path, seed: int) -> None:
    cmd = [sys.executable, "-m", "rangereg.app.cli", "register", str(source_path), str(target_path),
           "--json", "--seed", str(seed)]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime
    peak, before = after.ru_maxrss, before.ru_maxrss
    print("rangereg register (a subprocess, imports included):")
    if proc.returncode != 0:
        print(f"  FAILED (exit {proc.returncode}): {proc.stderr.strip()[-2000:]}")
        return
    res = json.loads(proc.stdout)
    source, target = (json.loads(p.with_suffix(".json").read_text()) for p in (source_path, target_path))
    T_true = invert(np.array(target["pose"])) @ np.array(source["pose"])
    # the source centroid, from the file (the CLI does not report it)
    centroid = load_scan(source_path).points.mean(0)
    rot, tr = pose_error(np.array(res["transform"]), T_true, centroid)
    peak_note = f"{peak / 1e6:.2f} GB" if peak > before else f"<= {peak / 1e6:.2f} GB (an earlier child peaked higher)"
    print(f"  wall {wall:.1f} s (reported 'seconds' {res['seconds']:.1f} s, reading to result), cpu {cpu:.1f} s "
          f"(all threads), peak memory {peak_note}")
    print(f"  E {res['error']:.4g} (threshold {res['threshold']:.4g}), stopped: {res['stop_reason']}")
    ok = rot < 2.0 and tr < 2.0
    print(f"  pose error vs truth: {rot:.3f} deg, {tr:.3f} mm -> {'registered' if ok else 'NOT registered'} "
          "(success: < 2 deg and < 2 mm)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=2_000_000, help="points per scan (default 2,000,000)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--dir", help="write the scans here (default: a temporary folder, removed after)")
    ap.add_argument("--skip-cli", action="store_true", help="only the in-process stages")
    ap.add_argument("--skip-stages", action="store_true", help="only the CLI run")
    ap.add_argument("--smallest", action="store_true", help="3,000 points a scan: check the script runs")
    a = ap.parse_args()
    if a.smallest:
        a.points = 3000
    with tempfile.TemporaryDirectory(prefix="rangereg-large-") as tmp:
        folder = Path(a.dir) if a.dir else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        source_path, target_path = generate(folder, a.points, a.seed, 101 if a.smallest else 601)
        if not a.skip_cli:
            cli(source_path, target_path, a.seed)
        if not a.skip_stages:
            in_process(source_path, target_path, a.seed)


if __name__ == "__main__":
    main()
