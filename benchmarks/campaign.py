"""A simulated turntable campaign: its families of starts against Open3D's multiway registration, a
10-scan campaign of 40k-point scans timed, and 1 worker against N side by side.

    python benchmarks/campaign.py --families           # every family below, ours and the peer
    python benchmarks/campaign.py --families --only crops  # only the crop families
    python benchmarks/campaign.py --crop-pairs         # what the pairwise engine can do on the crops (below)
    python benchmarks/campaign.py --large              # 10 scans of ~40k points, rough poses, timed
    python benchmarks/campaign.py                      # 24 scans, seed 0: 1 vs 2 workers, 3 runs each
    python benchmarks/campaign.py --scans 36 --workers 4 --pairs overlap
    python benchmarks/campaign.py --write DIR          # only write the campaign (PLY + .conf) into DIR
    python benchmarks/campaign.py --smallest           # 4 scans, one run each: it runs
    python benchmarks/campaign.py --scale 100 500      # campaigns of 100 and 500 stops, rough poses and none
    python benchmarks/campaign.py --uncalibrated       # 15 stops, every pose the identity, and no poses

--families (the rules, fixed before any result was looked at): the 24-stop campaign of seed 0; starts
"frame" (each true pose turned 15 degrees about its scan frame's origin, the sensor, on a seeded
random axis), "axis" (turned 15 degrees either way about the turntable's axis through the object),
both shifted by 10 % of the object's size (as 25 mm is of the bunny's 0.25 m), seed 0; and "identity"
(no poses). Each on the whole scans and on crops (each scan replaced by its crop 0, app/crops.py).
We are told the rotation (15 degrees per scan) and no translation; from identity poses nothing. A
scan is right within 2 degrees and 2 mm of the truth relative to the first (benchmarks/campaign_runs.py).

--crop-pairs (the diagnosis of the crop families): per crop scan, the share (core.merge_tasks.share_at)
of it matching each other crop at the truth, its best partners; then each scan's 3 best partners at the
truth (share >= 0.2) and its ring neighbours registered as a campaign's first registration would
(core.merge_tasks.pair_task's engine, the pair's seed, no hybrid fallback) from each start: the "frame"
and "axis" rough poses (twice 15 degrees, no translation) and no guess; per pair right (2 deg / 2 mm)
or not, trusted or not and why not (misfit, what the matched overlap pins); per start the groups the
right trusted pairs join, and those the right pairs join trusted or not.

--large: 10 stops, a 310 x 310 range image (38.6k-44.2k points a scan), "frame" starts as above,
written as files and merged by ``rangereg merge ... --init --rotation-uncertainty 15 --json`` in
this process (its defaults: the plain loop until a cluster pays); the report's seconds (files read to
model written), the whole command's, and whether every scan is right. Target: <= 60 s on 2 cores.

--scale N...: turntables of N stops (seed 0, a 40 x 40 range image: 0.6-0.8k points a scan, so that 500
stops stay minutes), from the "frame" starts (15 degrees about the sensor, 10 % of the size) and from no
poses; per campaign the merge's seconds, registrations, overlaps measured, right / wrong / not placed,
and the progress estimates checked against the time the tasks then took (core.merge_progress.Forecast).

--uncalibrated (the proxy for a turntable nobody calibrated, as the dragon's 15 stops): the default
24-stop scanner at 15 stops, every initial pose the identity (told 15 degrees, the default), and no
poses at all; right within 2 degrees and 2 mm.

The speed-up comparison (no mode flag):

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

from rangereg.app.distributed import TaskRunner, stderr_lines  # noqa: E402
from rangereg.core.merge import MergeConfig, PairStatus, clear_geometry_cache, merge  # noqa: E402
from rangereg.core.simulate import Scanner  # noqa: E402
from rangereg.core.transforms import invert, pose_error  # noqa: E402
from rangereg.core.turntable import (  # noqa: E402
    FAMILIES,
    TurntableConfig,
    make_campaign,
    rough_poses,
    write_campaign,
    write_conf,
)

ROT_TARGET, TRANS_TARGET = 1.0, 0.005  # degrees; fraction of the object's size
OFFSET_DEG, SHIFT_SHARE = 15.0, 0.10  # --families and --large: the rough starts (module notes)
LARGE = Scanner(rows=310, cols=310, fov_deg=(24.0, 24.0), noise=0.3, outliers=0.02, jitter=0.35)


def families(a) -> int:
    from rangereg.app.crops import crop

    from benchmarks.campaign_runs import load, ours, peer, table

    camp = make_campaign(a.seed, TurntableConfig(scans=a.scans))
    truth = [s.pose for s in camp.scans]
    print(f"{camp!r}; {load()} before")
    rows = []
    for cut in {"whole": (False,), "crops": (True,)}.get(a.only, (False, True)):
        scans = [crop(s, 0) for s in camp.scans] if cut else camp.scans
        for family in FAMILIES:
            name = f"turntable {a.scans}{', crops 0' if cut else ''}, {family}"
            initial = None if family == "identity" else rough_poses(truth, family, OFFSET_DEG, SHIFT_SHARE * camp.size,
                                                                      a.seed)
            mine, _ = ours(scans, truth, initial, OFFSET_DEG, seed=a.seed, workers=a.run_workers)
            other = peer(scans, truth, initial)
            rows.append((name, mine, other))
            print(f"{name}: ours {mine.right}/{len(scans)} right, {mine.wrong} placed wrong, {mine.unplaced} not placed "
                  f"({mine.seconds:.1f} s; {mine.note}); multiway {other.right}/{len(scans)} ({other.seconds:.1f} s); "
                  f"{load()}", flush=True)
    print()
    print(table(rows))
    print(f"\n{load()} after")
    return 0 if all(m.right == len(m.errors) for _, m, _ in rows) else 1


def crop_pairs(a) -> int:
    from dataclasses import replace

    from rangereg.app.crops import crop
    from rangereg.core.errors import InputError
    from rangereg.core.guess import Guess
    from rangereg.core.merge_tasks import Shared, built, pair_seed, scan_arrays, share_at, token
    from rangereg.core.posegraph import components
    from rangereg.core.register import Config, register

    from benchmarks.campaign_runs import RIGHT_DEG, RIGHT_MM, load

    camp = make_campaign(a.seed, TurntableConfig(scans=a.scans))
    truth = [s.pose for s in camp.scans]
    scans = [crop(s, 0) for s in camp.scans]
    n = len(scans)
    config = Config(method="global", seed=a.seed)
    config = replace(config, candidates=replace(config.candidates, time_limit=None, fallback_steps=0))
    shared = Shared(token(scans, config), tuple(scan_arrays(s) for s in scans), config, stated=Guess.identity(OFFSET_DEG))
    rel = lambda P, i, j: invert(P[i]) @ P[j]  # noqa: E731
    print(f"{camp!r}, crops 0 ({min(len(s.points) for s in scans)}-{max(len(s.points) for s in scans)} points); {load()}")
    share = np.zeros((n, n))
    for i in range(n):
        for j in range(i + 1, n):
            share[i, j] = share[j, i] = share_at(shared, i, j, rel(truth, i, j))
    for i in range(n):
        best = np.argsort(-share[i], kind="stable")[:4]
        print(f"{scans[i].name}: best partners at the truth " + ", ".join(f"{j} {share[i, j]:.2f}" for j in best))
    pairs = sorted({(min(i, int(j)), max(i, int(j))) for i in range(n) for j in np.argsort(-share[i], kind="stable")[:3]
                    if share[i, j] >= 0.2} | {(min(i, (i + 1) % n), max(i, (i + 1) % n)) for i in range(n)})
    starts = {f: rough_poses(truth, f, OFFSET_DEG, SHIFT_SHARE * camp.size, a.seed) for f in ("frame", "axis")}
    for name, P in {**starts, "no guess": None}.items():
        right, trusted_right, trusted_wrong = [], [], []
        for i, j in pairs:
            guess = Guess(np.eye(4), 180.0, None) if P is None else Guess(rel(P, i, j), 2 * OFFSET_DEG, None)
            try:
                res = register(built(shared, j)[0], built(shared, i)[0], guess, replace(config, seed=pair_seed(a.seed, i, j)))
            except InputError as exc:  # as core.merge_tasks.pair_task: a pair that did not register
                print(f"  {name} {i}-{j} share {share[i, j]:.2f}: not registered ({exc})")
                continue
            rot, move = pose_error(res.transform, rel(truth, i, j), scans[j].centroid)
            ok = rot < RIGHT_DEG and move < RIGHT_MM
            d = res.verdict
            right += [(i, j)] if ok else []
            (trusted_right if ok else trusted_wrong).extend([(i, j)] if res.below_threshold else [])
            c = d.constraint
            print(f"  {name} {i}-{j} share {share[i, j]:.2f}: {'right' if ok else 'WRONG'} {rot:.2f} deg / {move:.2f} mm, "
                  f"{'trusted' if res.below_threshold else 'not trusted'}, misfit "
                  f"{'-' if d.misfit is None else f'{d.misfit:.2f}'}, pins {'-' if c is None else f'{c.ratio:.4f}'}"
                  f"{'' if c is None or c.rise is None else f' rise {c.rise:.2f}'}"
                  f"{'' if c is None or c.stable_rise is None else f' stable rise {c.stable_rise:.2f}'}", flush=True)

        def joined(keys):
            label = components(n, keys)
            return sorted((sorted(k for k in range(n) if label[k] == lab) for lab in set(label)), key=len, reverse=True)

        print(f"{name}: {len(pairs)} pairs, {len(right)} right ({len(trusted_right)} trusted), {len(trusted_wrong)} "
              f"wrong trusted; groups by right trusted pairs {joined(trusted_right)}; by right pairs {joined(right)}; "
              f"{load()}")
    return 0


def large(a) -> int:
    import contextlib
    import io
    import json
    import tempfile

    from rangereg.app.cli import main as cli

    from benchmarks.campaign_runs import load

    cfg = TurntableConfig(scans=10, scanner=LARGE)
    with tempfile.TemporaryDirectory() as tmp:
        camp = write_campaign(tmp, a.seed, cfg)
        truth = [s.pose for s in camp.scans]
        write_conf(Path(tmp) / "init" / "frame.conf", [f"{s.name}.ply" for s in camp.scans],
                   rough_poses(truth, "frame", OFFSET_DEG, SHIFT_SHARE * camp.size, a.seed))
        files = sorted(str(p) for p in Path(tmp).glob("scan*.ply"))
        print(f"{camp!r}; {load()} before")
        argv = ["merge", *files, "--init", f"{tmp}/init/frame.conf", "--rotation-uncertainty", str(OFFSET_DEG),
                "--out", f"{tmp}/model.ply", "--json"] + (["--workers", str(a.run_workers)] if a.run_workers else [])
        out = io.StringIO()
        t0 = time.perf_counter()
        with contextlib.redirect_stdout(out):
            status = cli(argv)
        whole = time.perf_counter() - t0
    rep = json.loads(out.getvalue())
    rot, tr = rep["rotation_error_deg"], rep["translation_error"]
    cycles = [r["cycle_residual"] for r in rep["scan_reports"] if r["cycle_residual"]]
    worst = "-" if not cycles else "{rotation_deg:.3f} deg / {translation:.3f} mm".format(
        **max(cycles, key=lambda c: c["rotation_deg"]))
    right = sum(r is not None and r < 2.0 and t < 2.0 for r, t in zip(rot, tr))
    print(f"rangereg merge, 10 scans of {min(len(s.points) for s in camp.scans)}-{max(len(s.points) for s in camp.scans)} "
          f"points, rough 'frame' starts: exit {status}; {right}/10 right (worst "
          f"{max(r for r in rot if r is not None):.3f} deg, {max(t for t in tr if t is not None):.3f} mm); "
          f"report {rep['seconds']:.1f} s (pairwise {rep['pair_seconds']:.1f} s), whole command {whole:.1f} s; "
          f"{rep['graph']['registrations']} registrations in {rep['graph']['rounds']} rounds; largest cycle residual "
          f"{worst}; ran on: {rep['runner']}; "
          f"{load()} after")
    return 0 if right == 10 and rep["seconds"] <= 60 else 1


SCALE = Scanner(rows=40, cols=40, fov_deg=(24.0, 24.0), noise=0.3, outliers=0.02, jitter=0.35)


def _one(camp, scans, initial, rotation_deg: float | None, workers, label: str) -> tuple:
    """One merge scored: (row text, Outcome, MergeResult)."""
    from benchmarks.campaign_runs import load, ours

    mine, res = ours(scans, [s.pose for s in camp.scans], initial, rotation_deg or 15.0, seed=camp.seed,
                     workers=workers)
    fc = "; ".join(f"{f.step} r{f.round}: {f.left} tasks est {f.estimated:.1f} s, took {f.measured:.1f} s"
                   for f in res.forecasts if f.left >= 20) or "no long map"
    rings = f"largest loop {len(res.rings[0].order)} scans, closing residual {res.rings[0].residual[0]:.3f} deg / " \
            f"{res.rings[0].residual[1]:.3f} mm, after {res.rings[0].after[0]:.3f} deg" if res.rings else "no loop"
    row = (f"{label}: {mine.right}/{len(scans)} right, {mine.wrong} wrong, {mine.unplaced} not placed; "
           f"{mine.seconds:.1f} s (pairwise {res.pair_seconds:.1f}, overlaps {res.overlap_seconds:.1f}); "
           f"{res.registrations} registrations in {res.rounds} rounds, {res.skipped} pairs skipped by overlap; "
           f"worst {mine.worst()}; {rings}; forecasts: {fc}; {load()}")
    return row, mine, res


def scale(a) -> int:
    from benchmarks.campaign_runs import load

    print(f"{load()} before")
    times = {}
    ok = True
    for n in a.scale:
        camp = make_campaign(a.seed, TurntableConfig(scans=n, scanner=SCALE))
        truth = [s.pose for s in camp.scans]
        starts = {"frame": rough_poses(truth, "frame", OFFSET_DEG, SHIFT_SHARE * camp.size, a.seed)}
        if not a.rough_only:
            starts["no poses"] = None
        for name, initial in starts.items():
            row, mine, _ = _one(camp, camp.scans, initial, OFFSET_DEG, a.run_workers, f"{n} stops, {name}")
            times[n, name] = mine.seconds
            ok &= mine.wrong == 0
            print(row, flush=True)
    base = min(a.scale)
    for (n, name), t in sorted(times.items()):
        if n != base and (base, name) in times:
            print(f"{name}: {n} stops / {base} stops = {t / times[base, name]:.2f} x the time "
                  f"({n / base:.0f} x the scans)")
    return 0 if ok else 1


def uncalibrated(a) -> int:
    from benchmarks.campaign_runs import load

    camp = make_campaign(a.seed, TurntableConfig(scans=15))
    print(f"{camp!r}; {load()} before")
    ok = True
    for name, initial in (("identity poses, told 15 deg", [np.eye(4)] * 15), ("no poses", None)):
        row, mine, _ = _one(camp, camp.scans, initial, OFFSET_DEG, a.run_workers, f"15 stops, {name}")
        ok &= mine.right == 15
        print(row, flush=True)
    return 0 if ok else 1


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
    e = [(np.inf, np.inf) if T is None else pose_error(T, invert(ref) @ s.pose, s.points.mean(0))
         for T, s in zip(poses, camp.scans)]
    return np.array([x[0] for x in e]), np.array([x[1] for x in e])


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scans", type=int, default=24)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=2, help="workers of the distributed run (default 2)")
    p.add_argument("--pairs", choices=MergeConfig.PAIR_MODES, default="init")
    p.add_argument("--initial", choices=("perturbed", "chain"), default="perturbed")
    p.add_argument("--write", metavar="DIR", help="write the campaign into DIR and stop")
    p.add_argument("--repeat", type=int, default=3, help="runs per setting, interleaved; medians compared")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.add_argument("--smallest", action="store_true", help="4 scans, one run per setting, one threading")
    p.add_argument("--families", action="store_true", help="every family of starts, ours and Open3D's multiway")
    p.add_argument("--only", choices=("whole", "crops"), help="--families: only the whole scans, or only the crops")
    p.add_argument("--crop-pairs", action="store_true", help="the crop families' diagnosis: overlaps at the truth, "
                   "neighbour pairs registered from each start (module notes)")
    p.add_argument("--large", action="store_true", help="10 scans of ~40k points from rough poses, timed")
    p.add_argument("--run-workers", type=int, default=None, help="--families / --large: as merge --workers "
                   "(default: merge's own choice)")
    p.add_argument("--scale", type=int, nargs="+", help="campaigns of these many stops (module notes)")
    p.add_argument("--rough-only", action="store_true", help="--scale: only the rough starts")
    p.add_argument("--uncalibrated", action="store_true", help="15 stops from identity poses and from none")
    a = p.parse_args()
    if a.scale:
        return scale(a)
    if a.uncalibrated:
        return uncalibrated(a)
    if a.families:
        return families(a)
    if a.crop_pairs:
        return crop_pairs(a)
    if a.large:
        return large(a)
    if a.smallest:
        a.scans, a.repeat = 4, 1
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
                res, wall, started, cpu = run(camp, initial, workers, threads, a.pairs, a.quiet)
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
          f"{sum(p.status is PairStatus.REJECTED for p in first.pairs)} rejected by the pose graph")
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
