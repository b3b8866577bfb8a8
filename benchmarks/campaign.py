"""A simulated turntable campaign merged with 1 worker and with N workers, side by side.

    python benchmarks/campaign.py                      # 24 scans, seed 0: 1 vs 2 workers, 3 runs each
    python benchmarks/campaign.py --scans 36 --workers 4 --pairs overlap
    python benchmarks/campaign.py --write DIR          # only write the campaign (PLY + .conf) into DIR
    python benchmarks/campaign.py --smallest           # 6 scans, ICP pairs, one run each: it runs

Two threadings, each the same in both modes: "equal" (``threads=1``: every task stream, i.e. the
serial process or each worker, one thread: the fair comparison, the speed-up the target is about)
and "default" (what ``rangereg merge`` does: the serial process keeps the libraries' defaults, all
cores for Open3D's ray casts; each of N local workers gets cores // N threads).

Prints, per run: the pairwise stage's wall time (overlaps + registrations: the part that runs as
tasks; the workers have imported the engine before it starts), the cluster's start (processes,
imports), the end-to-end time (cluster start and stop, pose graph, no fused model), and the load
average after the run. Then the medians and speed-ups, every scan's pose error against the truth
(target: <= 1 degree and <= 0.5 % of the object's size), and whether all runs' poses are bitwise
equal. Timings on a shared machine are noisy: the runs are interleaved (1, N, 1, N, ... for each
threading in turn) so that a burst of load from elsewhere hits every setting, and medians compared.
Every run starts from no built geometry, in this process as in fresh workers.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from app.distributed import TaskRunner, stderr_lines  # noqa: E402
from core.config import Config, ProblemConfig  # noqa: E402
from core.merge import PAIR_MODES, clear_geometry_cache, merge  # noqa: E402
from core.transforms import invert, pose_error  # noqa: E402
from core.turntable import TurntableConfig, make_campaign, write_campaign  # noqa: E402

ROT_TARGET, TRANS_TARGET = 1.0, 0.005  # degrees; fraction of the object's size


def run(camp, initial, workers: int, threads: int | None, pairs: str, quiet: bool, config=None) -> tuple:
    """One merge: (MergeResult, end-to-end seconds, cluster start seconds, CPU seconds of the merge in
    (this process, each worker)); CPU time, unlike wall time, barely depends on the machine's load."""
    clear_geometry_cache()
    t0 = time.perf_counter()
    with TaskRunner(workers, progress=None if quiet else stderr_lines, threads=threads) as runner:
        runner.start()  # the cluster's start counts end to end, not in the pairwise stage
        started = time.perf_counter() - t0
        cpu0, w0 = time.process_time(), runner.client.run(time.process_time) if runner.client else {}
        res = merge(camp.scans, initial, config, build_model=False, pairs=pairs, map_tasks=runner.map,
                    progress=None if quiet else stderr_lines)
        cpu1, w1 = time.process_time(), runner.client.run(time.process_time) if runner.client else {}
    cpu = (cpu1 - cpu0, tuple(w1[k] - w0[k] for k in sorted(w1)))
    return res, time.perf_counter() - t0, started, cpu


def errors(camp, poses) -> tuple[np.ndarray, np.ndarray]:
    ref = camp.scans[0].pose
    e = [pose_error(T, invert(ref) @ s.pose, s.points.mean(0)) for T, s in zip(poses, camp.scans)]
    return np.array([x[0] for x in e]), np.array([x[1] for x in e])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scans", type=int, default=24)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2, help="workers of the distributed run (default 2)")
    p.add_argument("--pairs", choices=PAIR_MODES, default="init")
    p.add_argument("--initial", choices=("perturbed", "chain"), default="perturbed")
    p.add_argument("--write", metavar="DIR", help="write the campaign into DIR and stop")
    p.add_argument("--repeat", type=int, default=3, help="runs per setting, interleaved; medians compared")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--smallest", action="store_true", help="6 scans, ICP pairs, one run per setting, one threading")
    a = p.parse_args()
    config = None  # merge's own
    if a.smallest:
        a.scans, a.repeat = 6, 1
        config = Config(method="icp", problem=ProblemConfig(rotation_uncertainty_deg=25.0))
    cfg = TurntableConfig(scans=a.scans)
    if a.write:
        camp = write_campaign(a.write, a.seed, cfg)
        print(f"{camp!r} -> {a.write}: scan*.ply, campaign.conf (truth), init/perturbed.conf, init/chain.conf")
        print(f"try: rangereg merge {a.write}/scan*.ply --init {a.write}/init/{a.initial}.conf --out model.ply")
        return 0
    camp = make_campaign(a.seed, cfg)
    initial = getattr(camp, a.initial)
    print(f"{camp!r}; initial poses: {a.initial}; pairs: {a.pairs}; {os.cpu_count()} cores, "
          f"load average before {os.getloadavg()[0]:.1f}")
    threadings = {"equal": 1} if a.smallest else {"equal": 1, "default": None}  # threads per task stream
    rows: dict[tuple, list] = {(t, w): [] for t in threadings for w in (1, a.workers)}
    for _ in range(a.repeat):
        for t, threads in threadings.items():
            for workers in (1, a.workers):
                res, wall, started, cpu = run(camp, initial, workers, threads, a.pairs, a.quiet, config)
                rows[t, workers].append((res, wall, started, os.getloadavg()[0], cpu))
    for (t, workers), runs in rows.items():
        print(f"{t} threading, {workers} worker(s), each run: pairwise stage "
              f"{', '.join(f'{r.pair_seconds:.1f}' for r, *_ in runs)} s; cluster start "
              f"{', '.join(f'{s:.1f}' for _, _, s, *_ in runs)} s; end to end "
              f"{', '.join(f'{w:.1f}' for _, w, *_ in runs)} s; load average after "
              f"{', '.join(f'{x:.1f}' for *_, x, _ in runs)}; CPU s (this process + each worker) "
              f"{', '.join(' + '.join(f'{c:.1f}' for c in (cpu[0], *cpu[1])) for *_, cpu in runs)}")
    first = rows["equal", 1][0][0]
    same = all(np.array_equal(x, y) for runs in rows.values() for r, *_ in runs for x, y in zip(first.poses, r.poses))
    print(f"\npairs: {len(first.pairs)} registered, {len(first.used)} used, "
          f"{sum(p.status == 'rejected' for p in first.pairs)} rejected by the pose graph, "
          f"{sum(p.status == 'dropped' for p in first.pairs)} dropped")
    loads = [x for runs in rows.values() for *_, x, _ in runs]
    print(f"medians of {a.repeat} interleaved runs each (load average after the runs {min(loads):.1f}-{max(loads):.1f}):")
    med = lambda t, w, f: float(np.median([f(*r) for r in rows[t, w]]))  # noqa: E731
    cols = {"pairwise stage (s)": lambda r, w, s, x, c: r.pair_seconds,
            "  of which overlaps (s)": lambda r, w, s, x, c: r.overlap_seconds,
            "cluster start (s)": lambda r, w, s, x, c: s,
            "end to end (s)": lambda r, w, s, x, c: w,
            "CPU, busiest process (s)": lambda r, w, s, x, c: max((c[0], *c[1])),
            "CPU, all processes (s)": lambda r, w, s, x, c: c[0] + sum(c[1])}
    for t, threads in threadings.items():
        each = "1 thread per task stream in both modes" if threads else \
            f"serial: library defaults; {a.workers} workers: {max(1, (os.cpu_count() or 1) // a.workers)} thread(s) each"
        print(f"{t} threading ({each}):")
        print(f"  {'':26s}{'1 worker':>12s}{f'{a.workers} workers':>12s}{'speed-up':>10s}")
        for name, f in cols.items():
            one, many = med(t, 1, f), med(t, a.workers, f)
            ratio = f"{one / many:9.2f}x" if "start" not in name and "all" not in name else ""
            print(f"  {name:26s}{one:12.1f}{many:12.1f}{ratio}")
    print(f"poses bitwise equal across all {sum(map(len, rows.values()))} runs: {same}")
    rot, tr = errors(camp, first.poses)
    size = camp.size
    print(f"\npose error vs the truth (object {size:.0f} mm; target <= {ROT_TARGET} deg, <= {TRANS_TARGET * size:.2f} mm):")
    for s, r, t in zip(camp.scans, rot, tr):
        print(f"  {s.name}: {r:6.3f} deg  {t:6.3f} mm  {'ok' if r <= ROT_TARGET and t <= TRANS_TARGET * size else 'MISSED'}")
    ok = bool(np.all(rot <= ROT_TARGET) and np.all(tr <= TRANS_TARGET * size))
    print(f"max {rot.max():.3f} deg, {tr.max():.3f} mm ({100 * tr.max() / size:.3f} % of size): "
          f"{'every scan within the target' if ok else 'TARGET MISSED'}")
    return 0 if ok and same else 1


if __name__ == "__main__":
    raise SystemExit(main())
