"""The ``rangereg`` command line: the parser and the dispatch. Each command's body is in ``app.commands``.

Every transform maps SOURCE coordinates into TARGET's frame (``T_target_source``). Bad input gives
one line on stderr and exit status 2, checked before the work starts where it can be. SIGINT, SIGTERM
and SIGHUP end any command with one line and status 130, 143 or 129 (128 + the signal), after every
``finally`` has run (temporary files removed, workers stopped: app.process). This module imports only
the standard library at its top, so that the handlers are in place before numpy and the engine load.
"""

from __future__ import annotations

import argparse
import importlib
import signal
import sys
from pathlib import Path

from rangereg.app.process import Handlers, Interrupted, discard_open_outputs, error_line, exit_now, quiet_stdout, streams_ready

ASSETS = Path(__file__).resolve().parent.parent / "assets"


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, no usage dump
        sys.stderr.write(f"{self.prog}: error: {' '.join(message.split())}\n")
        raise SystemExit(2)


def _knob(name: str):
    """An argparse type checking ``app.options.KNOBS[name]`` (the one place each range is written)."""
    from rangereg.app.options import KNOBS, check_value

    def parse(text: str):
        v = check_value(KNOBS[name], text)
        if isinstance(v, str):
            raise argparse.ArgumentTypeError(v)
        return v

    parse.__name__ = KNOBS[name].describe()
    return parse


def _vec3(text: str):
    import numpy as np
    from rangereg.core.scan import check_coordinates

    try:
        v = np.array([float(t) for t in text.replace(" ", "").split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z numbers, got {text!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    problem = check_coordinates(v)
    if problem:
        raise argparse.ArgumentTypeError(f"{problem}, got {text!r}")
    return v


# the commands that run Open3D's registration (its import costs ~1 s: info and scenes do without)
LIBRARY_COMMANDS = ("register", "slice", "merge", "bench", "serve")


def scan_kind(s) -> None:
    """The --scan-kind flag, the same on every command that reads scans (core.assemble: it overrides what
    the sidecar, the file and the points say)."""
    from rangereg.core.scan import ScanKind

    kinds = [k.value for k in ScanKind]
    s.add_argument("--scan-kind", choices=kinds, metavar="KIND", help=f"how the scans were taken, one of "
                   f"{', '.join(kinds)} (default: from each file: points all around the sensor are a panorama, "
                   "in front of it a single view, with no sensor position and no single view unstructured)")


def build_parser() -> argparse.ArgumentParser:
    from rangereg.app.options import KNOBS
    from rangereg.core.frustum import KINDS
    from rangereg.core.guess import DEFAULT_ROTATION_DEG
    from rangereg.core.problem import ProblemConfig
    from rangereg.core.register import METHODS, Config
    from rangereg.core.simulate import SCENES

    p = _Parser(prog="rangereg", description="Register 3-D range scans with the hybrid simulated annealing + ICP "
                "algorithm of Luck, Hoff, Underwood and Little (ICRA 2000).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    s = sub.add_parser("info", help="describe scan files", description="Describe scans: points, bounds, units, "
                       "viewpoint, range grid, surface triangles, point spacing.")
    s.add_argument("scan", nargs="+", help="scan files (.ply .pcd .xyz .txt .csv .pts .obj .stl .off .e57 .las .laz, "
                   "KITTI or nuScenes LiDAR .bin), each described in turn; an .e57 "
                   "alone lists its scans, FILE.e57#K (K from 0) or FILE.e57#NAME describes one")
    s.add_argument("--viewpoint", type=_vec3, help="sensor position x,y,z (overrides stored/estimated; one scan only)")
    scan_kind(s)
    s.add_argument("--triangles", action="store_true", help="count the surface's triangles even for a large scan "
                   "without a range grid (a 2.5-D Delaunay: about 30 s for 2M points)")
    s.add_argument("--json", action="store_true", help="print one JSON object per file, a line each")

    pc, cfg = ProblemConfig(), Config()

    def pair(s):
        s.add_argument("source", help="the scan to move (one scan of an E57: FILE.e57#K, K from 0, or FILE.e57#NAME)")
        s.add_argument("target", help="the scan to register onto")
        s.add_argument("--init", help="initial T_target_source: 16 numbers (row-major, quoted, spaces or commas) or "
                       "a file holding them or JSON with 'transform'; default: from the scans' stored rough poses, "
                       "else identity")
        s.add_argument("--viewpoint-source", type=_vec3, metavar="X,Y,Z")
        s.add_argument("--viewpoint-target", type=_vec3, metavar="X,Y,Z")
        scan_kind(s)
        s.add_argument("--frustum", choices=KINDS, default=pc.frustum, help=f"overlap frustum (default {pc.frustum})")
        s.add_argument("--max-points", type=_knob("max_points"), default=pc.max_points,
                       help=f"overlap points in E, 3 to {KNOBS['max_points'].high:,} (default {pc.max_points})")
        s.add_argument("--seed", type=_knob("seed"), default=0, help="seed of every random choice (default 0)")
        s.add_argument("--rotation-uncertainty", type=_knob("rotation_uncertainty"), metavar="DEG",
                       help="how far off the guess may be in rotation, 0.01 to 180, about the scan frame's origin (where "
                       "a 4x4 --init's rotation acts: the global method adds the move this implies at the scans' "
                       f"centroid to the translation); default {DEFAULT_ROTATION_DEG:g} deg; 180: any rotation. "
                       "The global method takes no --init, no stored rough poses and neither uncertainty flag as no "
                       "guess at all")
        s.add_argument("--translation-uncertainty", type=_knob("translation_uncertainty"), metavar="UNITS",
                       help="how far off the guess may be in translation (default 15 %% of the target's size; "
                       "the global method leaves it free from a stated rotation of 90 deg up)")
        s.add_argument("--lock", metavar="SPEC", help="degrees of freedom the search may not move: any of "
                       "tx,ty,tz,rx,ry,rz (about the overlap centroid; 'rotation' or 'translation' for three), or "
                       "turntable:px,py,pz,dx,dy,dz (rotation about that line in TARGET's frame only; "
                       "turntable+translation:... also shifts); default none")

    s = sub.add_parser("register", help="register SOURCE onto TARGET", description="Register SOURCE onto TARGET; "
                       "prints the transform that maps SOURCE into TARGET's frame.")
    pair(s)
    s.add_argument("--method", choices=METHODS, default=cfg.method, help="global: candidate poses in stages, cheapest "
                   "first (the guess, rotation samples within the uncertainty, KISS-Matcher, FPFH+RANSAC), scored by "
                   "the robust E and refined by ICP until one is trusted, else the paper's hybrid from the best; "
                   "hybrid: the paper's Fig. 6 alone; icp, sa, icp-restarts: the paper's baselines; basin-hopping: "
                   f"hops from ICP's minima (default {cfg.method})")
    s.add_argument("--no-candidates", dest="candidates", action="store_false", help="global: try the guess alone "
                   "(no rotation samples, no feature matching)")
    s.add_argument("--rotation-samples", type=_knob("rotation_samples"), metavar="N", help="global: rotations "
                   "spread over all of SO(3), of which those within --rotation-uncertainty are tried (default 720)")
    s.add_argument("--full-search", action="store_true", help="global: no bound on the search when no candidate is "
                   "trusted: every stage runs and the paper's hybrid searches round the best candidate until it "
                   "stops by itself (default: 1000 steps of search, 300 of them the hybrid's, at most)")
    s.add_argument("--time-limit", type=_knob("time_limit"), metavar="S", help="global: seconds of search at most, "
                   "counted after the setup (default: none; the search is bounded by its work, so a busy machine gives "
                   "the same answer; a bound in seconds may not)")
    s.add_argument("--threshold", type=_knob("threshold"), help="stop below this E (squared units); default: "
                   "estimated from the scans' own noise; 0: search until annealing gives up")
    s.add_argument("--polish", action="store_true", help="finish with unweighted ICP (paper section 4)")
    s.add_argument("--coarse-to-fine", action="store_true", help="search a smoothed error surface first")
    s.add_argument("--hops", type=_knob("hops"), default=cfg.hops,
                   help=f"basin-hopping: hops at most, 0 to {KNOBS['hops'].high:,} (default {cfg.hops})")
    s.add_argument("--recut-rounds", type=_knob("recut_rounds"), default=cfg.recut_rounds, metavar="N",
                   help="hybrid: search again from an overlap re-cut at the pose found, up to N rounds in all, "
                   f"1 to {KNOBS['recut_rounds'].high} (default {cfg.recut_rounds})")
    s.add_argument("--trace", help="write every step as JSON lines (.jsonl): a header (both scans' fingerprints, "
                   "the guess, every setting, seed, version), the events, the result; put in place when the run ends")
    s.add_argument("--out", help="write the transform as JSON (.json)")
    s.add_argument("--json", action="store_true", help="print one JSON object")

    s = sub.add_parser("slice", help="plot a 2-D slice of the error surface",
                       description="E over two of tx,ty,tz (units), rx,ry,rz (degrees) around a pose.")
    pair(s)
    s.add_argument("--params", default="tx,ry", help="two parameters, e.g. tx,ry")
    s.add_argument("--span", help="half-widths a,b > 0 (units / degrees); default: the initial uncertainty")
    s.add_argument("--steps", type=_knob("steps"), default=61,
                   help=f"grid steps per axis, 2 to {KNOBS['steps'].high} (default 61)")
    s.add_argument("--trace", dest="trace_in", help="a --trace file from 'register' to draw on the slice (refused when "
                   "its header names other scans)")
    s.add_argument("--center", choices=("init", "end"), default="init",
                   help="slice around the initial pose or the trace's end (default init)")
    s.add_argument("--png", required=True, help="write the picture here (.png)")
    s.add_argument("--npz", help="write the numbers here (.npz)")

    s = sub.add_parser("bench", help="reproduce the paper's tables", description="Run every method from the same "
                       "seeded starts on the scenes (and the shared bunny scans when present).")
    s.add_argument("--quick", action="store_true", help="fewer runs (under 3 minutes)")
    s.add_argument("--sweep", action="store_true", help="success per start offset on the bunny pairs, with "
                   "Open3D's ICP and FPFH+RANSAC on the same starts")
    s.add_argument("--modes", help="--sweep: how starts are made, comma-separated of origin, turntable, centroid, "
                   "no-guess (default all); the sensor families: identity, sensor, no-guess")
    s.add_argument("--families", help="--sweep: which pairs, comma-separated of whole, crop-whole, crop-crop "
                   "(default all), or of the sensor families lidar, kinect, sim-street, sim-room, sim-fragments "
                   "(app/sweep_sensors.py)")
    s.add_argument("--lesson", action="store_true", help="the lesson's starts on its scene (ribbed) with ICP, "
                   "annealing and the hybrid, and the lesson's targets")
    s.add_argument("--json", help="write the rows as JSON to this file")
    s.add_argument("--runs", type=_knob("runs"), help="starts per scene (default 10, quick 2; lesson: all 10)")
    s.add_argument("--workers", type=_knob("workers"), help="--sweep: starts at once: 1 = in this process "
                   "(default), N = a local Dask cluster of N processes")
    s.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="--sweep: run the starts on an existing Dask cluster")
    s.add_argument("--bunny", default=str(Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "bunny"),
                   help="folder of the Stanford bunny scans")

    s = sub.add_parser("serve", help="open the workbench in a browser", description="Start the viser workbench.")
    s.add_argument("source", nargs="?")
    s.add_argument("target", nargs="?")
    s.add_argument("--scene", choices=SCENES, default="corner")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=_knob("port"), default=8080)
    s.add_argument("--data-dir", help="folder whose scan files the page may open")
    s.add_argument("--trace", help="a --trace file from 'register' (of SOURCE and TARGET) to replay on the page")
    s.add_argument("--upload-cap-mb", type=_knob("upload_cap_mb"), default=200.0,
                   help="largest upload accepted (default 200 MB)")
    scan_kind(s)

    s = sub.add_parser("merge", help="register a set of scans and fuse them into one model",
                       description="Register overlapping pairs, make poses globally consistent, fuse one mesh. "
                       "Exit status 0: every scan placed; 3: some scan not placed (the report says why); 2: bad input.")
    s.add_argument("scans", nargs="+", help="scan files; an .e57 without #K brings all its scans, with their stored "
                   "poses as the initial poses")
    s.add_argument("--init", help="initial poses: a Stanford .conf (default: the scans' stored rough poses, else "
                   "no guess: every pair registered over all rotations)")
    s.add_argument("--rotation-uncertainty", type=_knob("rotation_uncertainty"), help="degrees each initial pose "
                   "may be off, about its scan frame's origin (default 15; a pair's guess: twice it)")
    s.add_argument("--translation-uncertainty", type=_knob("translation_uncertainty"), help="units each initial "
                   "pose may be off (default: unstated, a share of the scan's size)")
    s.add_argument("--truth", help="ground-truth poses (.conf) to report errors against")
    scan_kind(s)
    s.add_argument("--out", default="model.ply", help="the fused mesh (.ply), or the scans with their registered "
                   "poses (.e57; points untouched, the first scan left at its initial pose)")
    s.add_argument("--seed", type=_knob("seed"), default=0)
    s.add_argument("--workers", type=_knob("workers"), default=None, help="pairwise registrations at once: 1 = a "
                   "plain loop here, N = a local Dask cluster of N processes (default: the plain loop, and a "
                   "cluster of one worker per core once the work left pays for its start)")
    s.add_argument("--scheduler", metavar="tcp://HOST:PORT", help="run the pairwise registrations on an existing "
                   "Dask cluster (started with 'dask scheduler' and 'dask worker')")
    s.add_argument("--threads", type=_knob("threads"), default=None, help="threads per task stream (this process, or "
                   "each worker): default all cores for --workers 1, cores // N for a local cluster of N")
    s.add_argument("--pairs", choices=("init", "overlap", "chain", "all", "features", "sequence"), help="the first "
                   "round's pairs: init = each scan's best-overlapping partners under the initial poses (default with "
                   "poses); overlap = every overlapping pair; chain = consecutive scans and the last with the "
                   "first; all = every pair (default without poses up to 6 scans); features = each scan's "
                   "likeliest neighbours by their features (default without poses beyond); sequence = frames in "
                   "order (LiDAR or RGB-D): consecutive frames from the identity (odometry, within "
                   "--rotation-uncertainty of it), then the loop closures the odometry's poses make likely")
    s.add_argument("--json", action="store_true")

    s = sub.add_parser("scenes", help="regenerate the bundled default scenes",
                       description="Simulate the paper's scenes (corner, wing, bowl) into a folder.")
    s.add_argument("--out", default=str(ASSETS))
    s.add_argument("--seed", type=_knob("seed"), default=0)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run one command; returns the exit status (0; 2 for bad input; 128 + the signal when interrupted)."""
    command: list = [None]
    with Handlers(command, whole_process=argv is None) as handlers:
        try:
            if not streams_ready():
                error_line(None, "standard output is closed (>&-): the result would be lost; "
                             "send it to a file or to /dev/null")
                return 2
            status = _run(argv, command)
            if handlers.first is not None:  # a command that ends quietly on a signal (serve) still says it
                raise handlers.first
            return status
        except BaseException as exc:
            # A signal may surface as another exception: raised inside a C extension's import it
            # becomes an ImportError. Once one has arrived, it is what ends the command.
            stop = handlers.first or (Interrupted(signal.SIGINT) if isinstance(exc, KeyboardInterrupt) else None)
            if stop is None:
                return _failed(command[0], exc)
            discard_open_outputs()
            handlers.say(stop.text)
            if argv is None:  # the entry point: end here (app.process.exit_now says why)
                exit_now(stop.status)
            return stop.status


def _run(argv: list[str] | None, command: list) -> int:
    from rangereg.core.open3d_import import defer_plotly

    defer_plotly()  # before anything imports Open3D: its plotly drawing (plotly, dash: ~0.33 s) loads on first use
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as exc:  # --help (0) or a parser error (2, one line written)
        return exc.code if isinstance(exc.code, int) else 2
    command[0] = args.command
    module = importlib.import_module(f"rangereg.app.commands.{args.command}")
    if hasattr(module, "start_early"):  # what overlaps the libraries' import (Open3D's: 1-2 s)
        module.start_early(args)
    if args.command in LIBRARY_COMMANDS:
        from rangereg.core.quiet import quiet_open3d

        quiet_open3d()  # Open3D's warnings stay off the console (core.quiet)
    status = module.run(args)
    sys.stdout.flush()
    return status


def _failed(command: str | None, exc: BaseException) -> int:
    """The one line and the status for a command that raised ``exc``; anything unexpected is raised again."""
    from rangereg.core.errors import InputError

    if isinstance(exc, BrokenPipeError):  # the reader went away (`| head`): nothing more to say
        quiet_stdout()
        return 1
    if isinstance(exc, InputError):
        error_line(command, str(exc))
    elif isinstance(exc, OSError):  # a file the core reads that the OS refuses; a full stdout (error_line)
        error_line(command, f"{exc.filename}: {exc.strerror}" if exc.filename else f"{exc.strerror or exc}")
    elif isinstance(exc, MemoryError):
        error_line(command, "out of memory: the input needs more memory than this machine has free")
    else:
        raise exc
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
