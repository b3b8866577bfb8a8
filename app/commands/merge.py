"""``rangereg merge``: a set of scans -> globally consistent poses -> one fused mesh (core.merge).

The output and side files are checked up front; the report is printed before the model is written
(atomically, app.outputs), so a write that fails late loses nothing printed.

The pairwise registrations run as tasks (app.distributed): ``--workers 1`` a plain loop, ``--workers N``
a local Dask cluster of N processes (default: one per core), ``--scheduler tcp://HOST:PORT`` an
existing cluster; ``threads`` (when the parser has it) caps the threads of each task stream.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from app.options import Settings, read_text_file, to_config
from app.outputs import check_output, write_output
from core.errors import InputError

PROGRESS_DELAY = 1.0  # s: a run that fails sooner shows no progress lines


def _poses_for(conf: dict[str, np.ndarray], scans, what: str) -> list[np.ndarray]:
    missing = [s.name for s in scans if s.name not in conf]
    if missing:
        raise InputError(f"{what} has no pose for {', '.join(missing)} (it lists {', '.join(sorted(conf))})")
    return [conf[s.name] for s in scans]


class DelayedLines:
    """A progress sink for stderr that holds its lines until the inputs have passed every check (the
    registrations have started: a line starting with ``release``) and the run has taken ``delay``
    seconds, so that bad input (no overlap, a scan that overlaps nothing) prints one line, the error."""

    def __init__(self, delay: float = PROGRESS_DELAY, release: str = "registering", stream=None):
        self.t0, self.delay, self.release, self.stream = time.perf_counter(), delay, release, stream or sys.stderr
        self.held: list[str] = []
        self.released = False

    def __call__(self, line: str) -> None:
        self.held.append(f"  {line}\n")
        self.released = self.released or line.startswith(self.release)
        if self.released and time.perf_counter() - self.t0 >= self.delay:
            self.stream.write("".join(self.held))
            self.stream.flush()
            self.held.clear()


def run(a) -> int:
    from app.distributed import TaskRunner
    from core.e57 import count_scans, split_selection
    from core.e57_write import world_poses, write_e57
    from core.fuse import double_layer_fraction
    from core.io import load_conf, load_scans
    from core.merge import PAIR_MODES, merge
    from core.ply import write_ply
    from core.transforms import invert, pose_error

    workers, scheduler, pairs = a.workers, a.scheduler, a.pairs
    threads = getattr(a, "threads", None)  # threads per task stream (app.distributed); None: its default
    if sum(count_scans(p) for p in a.scans) < 2:  # an E57 without '#K' is all its scans
        raise InputError("merge needs at least two scans")
    for flag in ("--init", "--truth"):
        path = getattr(a, flag[2:])
        if path is not None:
            read_text_file(path, flag)  # missing, a folder, unreadable, binary: one line now
    out = check_output(a.out, "--out", (".ply", ".e57"), [p for p in (a.init, a.truth) if p],
                       [split_selection(p)[0] for p in a.scans])
    as_e57 = out.suffix.lower() == ".e57"  # the scans with their registered poses, not a fused model
    if pairs is not None and pairs not in PAIR_MODES:
        raise InputError(f"--pairs must be one of {', '.join(PAIR_MODES)}, got {pairs!r}")
    scans = load_scans(a.scans)
    names = [s.name for s in scans]
    if len(set(names)) != len(names):
        raise InputError(f"two scans share a name ({', '.join(names)}): rename one")
    initial = _poses_for(load_conf(a.init), scans, a.init) if a.init else None
    truth = _poses_for(load_conf(a.truth), scans, a.truth) if a.truth else None
    if truth is None and all(s.pose is not None for s in scans):
        truth = [s.pose for s in scans]  # ground truth stored with the scans (sidecar or .conf beside them)
    config = to_config(Settings(method="hybrid", seed=a.seed, rotation_uncertainty=25.0))
    say = DelayedLines() if not a.json or sys.stderr.isatty() else None
    with TaskRunner(workers, scheduler, progress=say, threads=threads) as runner:
        res = merge(scans, initial, config, progress=say, pairs=pairs, map_tasks=runner.map, build_model=not as_e57)
    gap = float(np.median([s.spacing for s in scans]))
    report = {
        "scans": names,
        "poses": [np.asarray(T).tolist() for T in res.poses],
        "pairs": [{"target": names[p.i], "source": names[p.j], "error": p.error, "overlap": p.overlap,
                   "status": p.status, "seconds": p.seconds} for p in res.pairs],
        "graph": {"mode": res.mode, "pairs": len(res.pairs), "used": len(res.used),
                  "rejected": sum(p.status == "rejected" for p in res.pairs),
                  "dropped": sum(p.status == "dropped" for p in res.pairs)},
        "workers": 1 if runner.serial else (runner.workers if scheduler is None else None),
        "scheduler": scheduler,
        "threads_per_worker": runner.stream_threads,  # None: the libraries' defaults (or the scheduler's workers')
        "pair_seconds": res.pair_seconds,
        "seconds": res.seconds,
        "model": None if as_e57 else {
            "path": str(out), "vertices": len(res.model.vertices), "triangles": len(res.model.faces),
            "double_layer_fraction": double_layer_fraction(res.model.vertices, res.model.faces, gap)},
        "scans_out": str(out) if as_e57 else None,
    }
    if truth is not None:
        errs = [pose_error(T, invert(truth[0]) @ Tt, s.points.mean(0)) for T, Tt, s in zip(res.poses, truth, scans)]
        report["rotation_error_deg"] = [e[0] for e in errs]
        report["translation_error"] = [e[1] for e in errs]
    try:
        _print(report, a.json, res, names, scans, truth, runner, scheduler, out)
    finally:
        if as_e57:
            first = None if initial is None else initial[0]  # the first scan stays where --init or its stored pose has it
            write_output(out, "--out", lambda p: write_e57(p, scans, world_poses(scans, res.poses, first)), ".e57")
        else:
            write_output(out, "--out", lambda p: write_ply(p, res.model.vertices, res.model.faces,
                                                           comments=("rangereg fused model",)), ".ply")
    return 0


def _print(report, as_json, res, names, scans, truth, runner, scheduler, out) -> None:
    if as_json:
        print(json.dumps(report))
        return
    g = report["graph"]
    where = "1 process" if runner.serial else (scheduler or f"{runner.workers} local workers")
    print(f"registered {g['pairs']} pairs ({g['mode']}) on {where} in {res.pair_seconds:.1f} s; "
          f"{g['used']} used, {g['rejected']} rejected by the pose graph, {g['dropped']} dropped (E far above "
          f"the others'); {res.seconds:.1f} s in all:")
    for p in report["pairs"]:
        tag = "" if p["status"] == "used" else f"  [{p['status']}]"
        print(f"  {p['source']} -> {p['target']}  E={p['error']:.4g}  overlap {p['overlap']:.0%}{tag}")
    print(f"poses (into {names[0]}'s frame):")
    for k, (name, T) in enumerate(zip(names, res.poses)):
        line = f"  {name}: t={np.round(T[:3, 3], 6).tolist()}"
        if truth is not None:
            line += f"  vs truth {report['rotation_error_deg'][k]:.3f} deg, {report['translation_error'][k]:.4g} {scans[k].units}"
        print(line)
    m = report["model"]
    if m is None:
        print(f"scans: {len(names)} with their registered poses (the first scan where its initial pose has it) -> {out}")
        return
    print(f"model: {m['vertices']} vertices, {m['triangles']} triangles, double layer on "
          f"{m['double_layer_fraction']:.2%} of triangles -> {out}")
