"""``rangereg register``: register SOURCE onto TARGET and print T_target_source.

The trace (JSON lines) opens with a header line (core.trace.TraceHeader: both scans by content, the
guess used, the config, the seed, the version) that ``slice --trace`` and the page check against
their scans, and closes with the result (the pose returned).

Outputs (``--out``, ``--trace``) are checked before the scans are read; the trace is collected in a
temporary file and put in place only when the run ends, and the result is printed before any file
is written, so a write that fails late (a full disk) loses nothing but that file.
"""

from __future__ import annotations

import json
import os
import sys
import time
from argparse import Namespace

from rangereg.app.commands import pair
from rangereg.app.options import Settings, says_nothing
from rangereg.app.outputs import TraceFile, check_distinct, check_output, library_prints_to_stderr, strict_json, write_outputs
from rangereg.core.errors import InputError

TRACE_SUFFIXES = (".jsonl", ".ndjson", ".json")


class Progress:
    """Readable progress on stderr, at most twice a second."""

    def __init__(self, enabled: bool):
        self.enabled, self.last = enabled, 0.0

    def __call__(self, e) -> None:
        now = time.monotonic()
        if self.enabled and (now - self.last > 0.5 or e.local_minimum):
            self.last = now
            extra = f" T={e.temperature:.3g}" if e.temperature is not None else ""
            mark = "  <- ICP ended in a local minimum" if e.local_minimum else ""
            sys.stderr.write(f"  {e.phase:3s} iteration {e.iteration:6d}  E={e.error:.6g}{extra}{mark}\n")


def start_early(a: Namespace) -> None:
    """KISS-Matcher's process started, when this run may ask it, before Open3D is imported (app.cli): its
    start-up (~0.15-0.3 s of a core) then overlaps the import, not the reading of the files on the machine's
    other core. Files to pose, started here against at the reading (2026-12-07, runs alternating, load 1.3-2.1,
    with the scans' one k-d tree each): the shared LiDAR pair 0.47 against 0.58 s (10 each), the Kinect pair
    capture0002 -> 0001 1.61 against 1.77 s (5 each), the same poses. Raises InputError for bad flags, as the
    run would; where a scan names no file the run stops at its first check, and no process is started."""
    cfg = pair.config(a)
    scans_there = all(os.path.isfile(p) or os.path.isfile(p.rpartition("#")[0])  # (site.e57#3: one of its scans)
                      for p in (str(a.source), str(a.target)))
    if scans_there and cfg.method == "global" and cfg.candidates.enabled and cfg.candidates.kiss_matcher:
        from rangereg.core import kiss_matcher_candidates

        kiss_matcher_candidates.start()


def run(a: Namespace) -> int:
    with library_prints_to_stderr(a.json):  # --json: stdout holds the JSON and nothing else
        res, source, target, (cfg, guess), seconds, trace, out = _register(a)
    try:
        report(res, source, target, cfg, guess, a.json, seconds)  # first: a file that cannot be written loses only itself
    finally:  # the files are written even when stdout is gone (`| head`)
        failed = []
        if trace is not None:
            try:
                trace.commit()
            except InputError as exc:
                failed.append(str(exc))
        try:
            write_outputs([(out, "--out", lambda p: _write_transform(p, res))])
        except InputError as exc:
            failed.append(str(exc))
        if failed:
            raise InputError("; ".join(failed))
    return 0


def _register(a: Namespace):
    """Check, read, register: (result, source, target, (config, guess), seconds, trace file or None, --out path or
    None)."""
    from rangereg.core.register import register

    cfg = pair.config(a)
    files = pair.inputs(a)
    scans = [a.source, a.target]
    out = check_output(a.out, "--out", (".json",), files, scans) if a.out is not None else None
    trace_path = check_output(a.trace, "--trace", TRACE_SUFFIXES, files, scans) if a.trace is not None else None
    check_distinct({"--out": out, "--trace": trace_path})
    t_imports = time.perf_counter()
    import open3d  # noqa: F401  (imported here so that its 1-2 s are counted apart from the registration)
    import rangereg.core.global_search  # noqa: F401
    t0 = time.perf_counter()
    source, target, T_init = pair.load(a)
    # nothing said about the pose: any pose (the global method)
    nothing = says_nothing(a.init, source, target, Settings.from_mapping(vars(a)))
    guess = pair.guess(a, T_init, **({"no_guess": True} if nothing else {}))
    # progress is for someone watching a terminal: a log or a pipe gets the result and at most one error line
    progress = Progress(not a.json and sys.stderr.isatty())
    trace = TraceFile(trace_path) if trace_path else None
    if trace is not None:  # the header first: which scans (by content), the guess, every knob, the seed
        from rangereg.core.trace import TraceHeader

        trace.write(json.dumps(TraceHeader.of(source, target, guess, cfg, a.source, a.target).to_json()))

    def listener(e):
        if trace is not None:
            trace.write(json.dumps(e.to_json()))
        progress(e)

    try:
        res = register(source, target, guess, cfg, listener)
    except BaseException:
        if trace is not None:
            trace.discard()
        raise
    if trace is not None:  # the closing line: the pose the run returned (not always its last event)
        trace.write(json.dumps({"result": res.to_json()}))
    seconds = {"seconds": time.perf_counter() - t0, "import_seconds": t0 - t_imports}
    return res, source, target, (cfg, guess), seconds, trace, out


def _write_transform(path, res) -> None:
    from rangereg.core.io import write_transform

    write_transform(path, res.transform, error=res.error, method=res.method)


def report(res, source, target, cfg, guess, as_json: bool, seconds: dict) -> None:
    """Print the result of a run of ``cfg`` from ``guess`` (core Config and Guess): one JSON object, or lines for
    people (with the truth when the scans carry it).
    ``seconds``: 'seconds' from reading both files to the result, 'import_seconds' the imports before."""
    estimated = [s.name for s in (source, target) if s.viewpoint_estimated]
    notes = [f"{s.name}: {n}" for s in (source, target) for n in s.notes]  # what the reading said of each file
    if as_json:
        out = {**res.to_json(), "search_seconds": res.seconds, **seconds, "viewpoint_estimated": estimated,
               "scan_notes": notes, "advice": advice(res, guess)}
        if cfg.lock.active:
            out["lock"] = str(cfg.lock)
        print(strict_json(out))
        return
    it = res.iterations
    print(f"method      {res.method}")
    if res.details is not None:
        print(f"guess       {res.details.region.describe()}")
    if cfg.lock.active:
        print(f"locked      {cfg.lock} (free: {', '.join(cfg.lock.free)})")
    print(f"error       {res.error:.4g} {target.units}^2 (threshold {res.threshold:.4g})")
    print(f"iterations  ICP {it.icp}, SA {it.sa}" + (f", candidates {it.candidates}" if it.candidates else "")
          + f"  (local minima {res.local_minima})")
    print(f"stopped     {res.stop_text} after {seconds['seconds']:.2f} s (files to result; "
          f"imports {seconds['import_seconds']:.2f} s apart)")
    if res.cut != "frustum":
        print(f"overlap     cut by {res.cut}: the frustum under the guess held too few points")
    if estimated:
        print(f"viewpoint   estimated for {' and '.join(estimated)} (the file holds none): give it with "
              "--viewpoint-source / --viewpoint-target or a sidecar if you know it")
    for line in notes:
        print(f"read        {line}")
    print(f"trust       {'yes' if res.below_threshold else 'no'}: {res.trust_text}")
    print("transform (maps SOURCE into TARGET's frame):")
    for row in res.transform:
        print("  " + " ".join(f"{v: .8f}" for v in row))
    if source.pose is not None and target.pose is not None:
        from rangereg.core.transforms import invert, pose_error

        rot, tr = pose_error(res.transform, invert(target.pose) @ source.pose, source.points.mean(0))
        print(f"vs ground truth: rotation {rot:.3f} deg, translation {tr:.4g} {target.units} (at the source centroid)")
    note = advice(res, guess)
    if note:
        print(f"note: {note}")


def advice(res, guess) -> str:
    """What the user can do about this result (``guess``: the core Guess it started from), in a sentence ('' when
    nothing)."""
    if res.details is not None and res.below_threshold and not res.within_region:
        return ("the pose was found beyond the uncertainty stated for the guess; if the guess may be that far off, "
                "say so with --rotation-uncertainty / --translation-uncertainty (a twin of a symmetric scene inside "
                "the stated region would have won)")
    if res.below_threshold or res.threshold <= 0:
        return ""
    if res.details is not None:
        return ("not trusted, so this is probably not the registration. Give a better --init, state how far off the "
                "guess may be (--rotation-uncertainty, --translation-uncertainty; no --init and neither flag: no "
                "guess at all), or search on from this pose (--full-search; or --out pose.json, then --method "
                "hybrid --init pose.json).")
    if res.verdict is not None:  # a paper method: E below the threshold on its sample, the pair threshold doubts
        return ("E fits the sample it was minimised on, but the pair threshold's test (above) doubts the pose, so it "
                "may not be the registration. Try --method global (the same test decides, over the whole stated "
                "region)" + (", or a larger --max-points (a small sample fits wrong poses)" if res.verdict.pinned
                             else "") + ".")
    return ("E stayed above the threshold, so this is probably not the registration. The search covers about "
            f"twice the guess's stated uncertainty ({guess.rotation_deg:g} deg); if the guess may "
            "be farther off, give a better --init or a larger --rotation-uncertainty / --translation-uncertainty, "
            "or try --method global or basin-hopping.")
