"""``rangereg merge``: a set of scans -> globally consistent poses -> one fused mesh (core.merge).

The output and side files are checked up front; the report is printed before the model is written
(atomically, app.outputs), so a write that fails late loses nothing printed.

The initial poses (``--init``, else the scans' stored rough poses, else none: no guess) come with the
stated uncertainty (``--rotation-uncertainty``, ``--translation-uncertainty``, per scan, through
app.options like ``register``'s). Exit status 0 when every scan is placed, 3 when some scan is not
(the report says which and why; the model holds the placed ones), 2 on bad input.

The pairwise registrations run as tasks (app.distributed): ``--workers 1`` a plain loop, ``--workers N``
a local Dask cluster of N processes, none given: the plain loop until the work left pays for a local
cluster; ``--scheduler tcp://HOST:PORT`` an existing cluster; ``threads`` (when the parser has it)
caps the threads of each task stream.
"""

from __future__ import annotations

import os
import sys
import time

import numpy as np
from rangereg.app.options import Settings, read_text_file, to_config, to_guess
from rangereg.app.outputs import check_output, library_prints_to_stderr, strict_json, write_output
from rangereg.core.errors import InputError
from rangereg.core.guess import Guess

PROGRESS_DELAY = 1.0  # s: a run that fails sooner shows no progress lines
NOT_PLACED = 3  # exit status: the merge ran, but some scan is not placed


def _poses_for(conf: dict[str, np.ndarray], scans, what: str) -> list[np.ndarray]:
    missing = [s.name for s in scans if s.name not in conf]
    if missing:
        raise InputError(f"{what} has no pose for {', '.join(missing)} (it lists {', '.join(sorted(conf))})")
    return [conf[s.name] for s in scans]


class DelayedLines:
    """A progress sink for stderr (core.merge's :class:`MergeProgress` events, and the task runner's own
    lines) that holds its lines until the inputs have passed every check (the first pair registrations
    have started) and the run has taken ``delay`` seconds, so that bad input prints one line, the error."""

    def __init__(self, delay: float = PROGRESS_DELAY, stream=None):
        self.t0, self.delay, self.stream = time.perf_counter(), delay, stream or sys.stderr
        self.held: list[str] = []
        self.released = False

    def __call__(self, event) -> None:
        from rangereg.core.merge_progress import MergeProgress, Step

        self.held.append(f"  {event}\n")
        self.released = self.released or (isinstance(event, MergeProgress) and event.step is Step.PAIRS)
        if self.released and time.perf_counter() - self.t0 >= self.delay:
            self.stream.write("".join(self.held))
            self.stream.flush()
            self.held.clear()


def stated_config(a, have_poses: bool, lacking: list[str] = ()):
    """(the registration config, the per-scan uncertainty of the initial poses: a core Guess about the identity)
    from the flags (no poses: none may be stated, and the campaign has no guess; a sequence's: how far each frame
    may lie from the identity of the one before).
    ``lacking``: the scans with no stored rough pose when others have one."""
    rot, trans = getattr(a, "rotation_uncertainty", None), getattr(a, "translation_uncertainty", None)
    if not have_poses and getattr(a, "pairs", None) != "sequence" and (rot is not None or trans is not None):
        why = (f"stored rough poses are missing for {', '.join(lacking)} (give every pose with --init)" if lacking
               else "without --init or stored poses there are none")
        raise InputError("--rotation-uncertainty and --translation-uncertainty say how far the initial poses may be "
                         f"off; {why} (no guess: every pair is registered over all rotations)")
    s = Settings(method="global", seed=a.seed, rotation_uncertainty=rot, translation_uncertainty=trans)
    return to_config(s), to_guess(s)


def run(a) -> int:
    from rangereg.app.distributed import TaskRunner
    from rangereg.core.e57 import count_scans, split_selection
    from rangereg.core.io import load_conf, load_scans
    from rangereg.core.merge import MergeConfig, merge

    workers, scheduler, pairs = a.workers, a.scheduler, a.pairs
    if scheduler is not None and workers is not None:
        raise InputError("--workers and --scheduler: give one (a scheduler's own workers run the pairs)")
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
    if pairs is not None and pairs not in MergeConfig.PAIR_MODES:
        raise InputError(f"--pairs must be one of {', '.join(MergeConfig.PAIR_MODES)}, got {pairs!r}")
    say = DelayedLines() if not a.json or sys.stderr.isatty() else None
    # the runner's flags (and a --scheduler's reach) are checked before any scan is read
    runner = TaskRunner(workers, scheduler, progress=say, threads=threads)
    _each_once(a.scans)
    scans = load_scans(a.scans, kind=getattr(a, "scan_kind", None))
    names = [s.name for s in scans]
    if len(set(names)) != len(names):
        raise InputError(f"two scans share a name ({', '.join(names)}): rename one")
    initial = _poses_for(load_conf(a.init), scans, a.init) if a.init else None
    truth = _poses_for(load_conf(a.truth), scans, a.truth) if a.truth else None
    truth_from = f"--truth {a.truth}" if a.truth else None
    if truth is None and all(s.pose is not None for s in scans):
        truth = [s.pose for s in scans]  # ground truth stored with the scans (sidecar or .conf beside them)
        truth_from = "stored with the scans (their sidecars or a .conf beside them)"
    have = initial is not None or all(s.guess is not None for s in scans)
    lacking = [] if have or not any(s.guess is not None for s in scans) else [s.name for s in scans if s.guess is None]
    config, stated = stated_config(a, have, lacking)
    if lacking and say is not None:
        say(f"stored rough poses are missing for {', '.join(lacking)}: none is used (no guess)")
    # --json: stdout holds the report alone (Open3D's C++ warnings go to stderr)
    with library_prints_to_stderr(a.json), runner:
        res = merge(scans, initial, config, progress=say, pairs=pairs, map_tasks=runner.map, build_model=not as_e57,
                    stated=stated)
    report = build_report(res, scans, truth, stated if have or pairs == "sequence" else Guess.none(), runner,
                          scheduler, out, as_e57)
    report["truth_from"] = truth_from
    try:
        if a.json:
            print(strict_json(report))
        else:
            print_report(report, res, scans)
        missing = [s.name for s in res.scans if not s.placed]
        if missing:
            sys.stderr.write(f"rangereg merge: {len(missing)} of {len(scans)} scans not placed ({', '.join(missing)}): "
                             f"no trusted pair joins them to {report['reference']}; the "
                             f"{'file' if as_e57 else 'model'} holds the placed scans\n")
    finally:
        if as_e57:
            write_output(out, "--out", lambda p: _write_placed_e57(p, scans, res, initial), ".e57")
        else:
            from rangereg.core.ply import write_ply

            write_output(out, "--out", lambda p: write_ply(p, res.model.vertices, res.model.faces,
                                                           comments=("rangereg fused model",)), ".ply")
    return NOT_PLACED if not all(res.placed) else 0


def _write_placed_e57(path, scans, res, initial) -> None:
    """The placed scans with their registered poses, the reference scan kept where its initial pose (given or
    stored) has it; a scan not placed is left out, never written at a pose nobody found."""
    from rangereg.core.e57_write import world_poses, write_e57

    ref = res.reference
    T_world_ref = initial[ref] if initial is not None else scans[ref].guess
    placed = [k for k, T in enumerate(res.poses) if T is not None]
    write_e57(path, [scans[k] for k in placed],
              world_poses([scans[ref]], [res.poses[k] for k in placed], T_world_ref))


def build_report(res, scans, truth, stated, runner, scheduler, out, as_e57: bool = False) -> dict:
    """Everything the merge found, as one JSON-ready dict (``--json`` prints it). ``stated``: each initial pose's
    uncertainty (a core Guess; no guess: none)."""
    from rangereg.core.fuse import double_layer_fraction
    from rangereg.core.merge_result import PairStatus
    from rangereg.core.transforms import invert, pose_error

    names = [s.name for s in scans]
    gap = float(np.median([s.spacing for s in scans]))
    pair = Guess.between(stated, stated)
    report = {
        "scans": names,
        "reference": names[res.reference],  # the poses are in its frame: the first scan's unless its group is not the largest
        "placed": res.placed,
        "poses": [None if T is None else np.asarray(T).tolist() for T in res.poses],
        "scan_reports": [{"name": r.name, "placed": r.placed, "status": str(r.status),
                          "trusted_pairs": [names[k] for k in r.trusted],
                          "cycle_residual": _residual(r.cycle),
                          # placed through a cycle of used pairs that closes; False: by a bridge no cycle checks
                          "checked": r.placed and r.cycle is not None, "why": r.why} for r in res.scans],
        "pairs": [{"target": names[p.i], "source": names[p.j], "error": p.error, "trusted": p.trusted,
                   "misfit": p.misfit, "within_region": p.within_region, "overlap": p.overlap, "status": str(p.status),
                   "rejection": None if p.rejection is None else str(p.rejection), "reason": p.reason,
                   "cycle_residual": _residual(p.cycle), "round": p.round, "start": str(p.start),
                   "earlier": p.earlier, "stop_reason": p.stop_text, "seconds": p.seconds} for p in res.pairs],
        "graph": {"mode": res.mode, "pairs": len(res.pairs), "used": len(res.used),
                  "rejected": sum(p.status is PairStatus.REJECTED for p in res.pairs), "rounds": res.rounds,
                  "registrations": res.registrations, "skipped": res.skipped},
        # the loops the graph closed, longest first: the scans round each, its closing pair, the residual
        # by which that pair missed the loop's other pairs before the graph optimised the loop, and after
        "rings": [{"scans": [names[k] for k in r.order], "closing_pair": [names[r.closing[0]], names[r.closing[1]]],
                   "closing_residual": _residual(r.residual), "after": _residual(r.after)} for r in res.rings],
        "stated": {"no_guess": stated.is_none, "rotation_deg": stated.rotation_deg, "translation": stated.translation,
                   "pair_rotation_deg": pair.rotation_deg, "pair_translation": pair.translation},
        "runner": runner.ran_on,
        "workers": 1 if not runner.used_cluster else (runner.workers if scheduler is None else None),
        "scheduler": scheduler,
        # None: the libraries' defaults (or the scheduler's workers')
        "threads_per_worker": runner.stream_threads if runner.used_cluster or runner.serial else runner.threads,
        "pair_seconds": res.pair_seconds,
        "seconds": res.seconds,
        "model": None if as_e57 else {
            "path": str(out), "vertices": len(res.model.vertices), "triangles": len(res.model.faces),
            "double_layer_fraction": double_layer_fraction(res.model.vertices, res.model.faces, gap)},
        "scans_out": str(out) if as_e57 else None,
    }
    if truth is not None:
        errs = [None if T is None else pose_error(T, invert(truth[res.reference]) @ Tt, s.points.mean(0))
                for T, Tt, s in zip(res.poses, truth, scans)]
        report["rotation_error_deg"] = [None if e is None else e[0] for e in errs]
        report["translation_error"] = [None if e is None else e[1] for e in errs]
    return report


def _residual(r) -> dict | None:
    return None if r is None else {"rotation_deg": r[0], "translation": r[1]}


def _cycle_text(r: dict | None, units: str) -> str:
    return "on no cycle" if r is None else f"cycle {r['rotation_deg']:.3g} deg / {r['translation']:.3g} {units}"


def print_report(report: dict, res, scans) -> None:
    """The report for people: the run, every pair, every scan, the model."""
    g, st, units, names = report["graph"], report["stated"], scans[0].units, report["scans"]
    where = "no guess (every pair over all rotations and translations)" if st["no_guess"] else (
        f"each frame from the one before it (the identity when no poses are given) within {st['rotation_deg']:g} deg"
        " (odometry), then the loop closures its poses make likely" if g["mode"] == "sequence" else
        f"initial poses within {st['rotation_deg']:g} deg" +
        (f" and {st['translation']:g} {units}" if st["translation"] is not None else "") +
        f" each (pairs: {st['pair_rotation_deg']:g} deg)")
    bridged = sum(r["placed"] and not r["checked"] for r in report["scan_reports"])
    unchecked = f" ({bridged} on no loop of pairs that checks them)" if bridged else ""
    print(f"{sum(report['placed'])} of {len(names)} scans placed{unchecked}; {g['pairs']} pairs ({g['used']} used, "
          f"{g['rejected']} rejected) in {g['rounds']} round(s), {g['registrations']} registrations; "
          f"{res.pair_seconds:.1f} s pairwise, {res.seconds:.1f} s in all")
    print(f"start: {where}; first round: {g['mode']}")
    print(f"ran on: {report['runner']}")
    if report["rings"]:
        r = report["rings"][0]
        more = f" ({len(report['rings']) - 1} more loops)" if len(report["rings"]) > 1 else ""
        print(f"largest loop: {len(r['scans'])} scans closed by {r['closing_pair'][1]} -> {r['closing_pair'][0]}, "
              f"closing residual {_cycle_text(r['closing_residual'], units)[6:]}, after the graph "
              f"{_cycle_text(r['after'], units)[6:]}{more}")
    print("pairs (source -> target):")
    for p in report["pairs"]:
        trust = "trusted" if p["trusted"] else "untrusted"
        why = f": {p['reason']}" if p["reason"] else ""
        cyc = f", {_cycle_text(p['cycle_residual'], units)}" if p["cycle_residual"] else ""
        again = f"; before: {p['earlier']}" if p["earlier"] else ""
        print(f"  {p['source']} -> {p['target']}  E={p['error']:.4g}  {trust}, overlap {p['overlap']:.0%}, "
              f"round {p['round']} from {p['start']}: {p['status'].upper()}{why}{cyc}{again}")
    truth = f"; truth {report['truth_from']}" if report.get("truth_from") else ""
    print(f"scans (poses into {report['reference']}'s frame{truth}):")
    for k, r in enumerate(report["scan_reports"]):
        partners = ", ".join(r["trusted_pairs"]) or "none"
        if r["placed"]:
            T = np.asarray(report["poses"][k])
            line = f"  {r['name']}: placed, t={np.round(T[:3, 3], 6).tolist()}; trusted pairs with {partners}; " + \
                   (f"largest {_cycle_text(r['cycle_residual'], units)}" if r["cycle_residual"] else "on no loop")
            if "rotation_error_deg" in report:
                line += f"; vs truth {report['rotation_error_deg'][k]:.3f} deg, {report['translation_error'][k]:.4g} {units}"
        else:
            line = f"  {r['name']}: NOT PLACED: {r['why']}"
        print(line)
    m = report["model"]
    if m is None:
        print(f"scans: the {sum(report['placed'])} placed with their registered poses ({report['reference']} where its "
              f"initial pose has it) -> {report['scans_out']}")
        return
    print(f"model of the {sum(report['placed'])} placed scans: {m['vertices']} vertices, {m['triangles']} triangles, "
          f"double layer on {m['double_layer_fraction']:.2%} of triangles -> {m['path']}")


def _each_once(paths: list[str]) -> None:
    """InputError where one file (the same scan of it) is given twice, by its name or through a link: merged with
    itself, it would be placed twice."""
    from rangereg.core.e57 import split_selection

    seen: dict[tuple, str] = {}
    for p in paths:
        path, selection = split_selection(p)
        try:
            st = os.stat(path)
            key = (st.st_dev, st.st_ino, selection)
        except OSError:  # missing or unreadable: the reading says so
            continue
        if key in seen:
            raise InputError(f"{seen[key]} and {p} are the same file: give each scan once")
        seen[key] = p
