"""The ``rangereg`` command line: info, register, slice, bench, serve, merge, scenes.

Every transform maps SOURCE coordinates into TARGET's frame (``T_target_source``). Bad input gives
one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from core.errors import InputError

ASSETS = Path(__file__).resolve().parent.parent / "assets"


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, exit 2, no usage dump
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _vec3(text: str) -> np.ndarray:
    try:
        v = np.array([float(t) for t in text.replace(" ", "").split(",")])
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected x,y,z numbers, got {text!r}") from None
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise argparse.ArgumentTypeError(f"expected three finite numbers x,y,z, got {text!r}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    return v


def _number(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not np.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    from core.frustum import KINDS
    from core.register import METHODS
    from core.simulate import SCENES

    p = _Parser(prog="rangereg", description="Register 3-D range scans with the hybrid simulated annealing + ICP "
                "algorithm of Luck, Hoff, Underwood and Little (ICRA 2000).")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    s = sub.add_parser("info", help="describe a scan file", description="Describe a scan: points, bounds, units, "
                       "viewpoint, range grid, surface triangles, point spacing.")
    s.add_argument("scan", help="scan file (.ply .pcd .xyz .txt .csv .obj .stl .off)")
    s.add_argument("--viewpoint", type=_vec3, help="sensor position x,y,z (overrides stored/estimated)")
    s.add_argument("--json", action="store_true", help="print one JSON object")

    def pair(s, init=True):
        s.add_argument("source", help="the scan to move")
        s.add_argument("target", help="the scan to register onto")
        if init:
            s.add_argument("--init", help="initial T_target_source: 16 numbers (row-major) or JSON with "
                           "'transform'; default: from the scans' stored rough poses, else identity")
        s.add_argument("--viewpoint-source", type=_vec3, metavar="X,Y,Z")
        s.add_argument("--viewpoint-target", type=_vec3, metavar="X,Y,Z")
        s.add_argument("--frustum", choices=KINDS, default="convex", help="overlap frustum (default convex)")
        s.add_argument("--max-points", type=_positive_int, default=300, help="overlap points in E (default 300)")
        s.add_argument("--seed", type=_positive_int, default=0)
        s.add_argument("--rotation-uncertainty", type=_number, default=15.0, metavar="DEG",
                       help="how far off the guess may be in rotation (default 15 deg)")
        s.add_argument("--translation-uncertainty", type=_number, metavar="UNITS",
                       help="how far off the guess may be in translation (default 15 %% of the target's size)")

    s = sub.add_parser("register", help="register SOURCE onto TARGET", description="Register SOURCE onto TARGET; "
                       "prints the transform that maps SOURCE into TARGET's frame.")
    pair(s)
    s.add_argument("--method", choices=METHODS, default="hybrid")
    s.add_argument("--threshold", type=_number, help="stop below this E (squared units); default: estimated "
                   "from the scans' own noise; 0: search until annealing gives up")
    s.add_argument("--polish", action="store_true", help="finish with unweighted ICP (paper section 4)")
    s.add_argument("--coarse-to-fine", action="store_true", help="search a smoothed error surface first")
    s.add_argument("--hops", type=_positive_int, default=200, help="basin-hopping: hops at most (default 200)")
    s.add_argument("--recut-rounds", type=_positive_int, default=1, metavar="N", help="hybrid: search again "
                   "from an overlap re-cut at the pose found, up to N rounds in all (default 1)")
    s.add_argument("--trace", help="write every ICP/SA step as JSON lines")
    s.add_argument("--out", help="write the transform as JSON")
    s.add_argument("--json", action="store_true", help="print one JSON object")

    s = sub.add_parser("slice", help="plot a 2-D slice of the error surface",
                       description="E over two of tx,ty,tz (units), rx,ry,rz (degrees) around a pose.")
    pair(s)
    s.add_argument("--params", default="tx,ry", help="two parameters, e.g. tx,ry")
    s.add_argument("--span", help="half-widths a,b (units / degrees); default: the initial uncertainty")
    s.add_argument("--steps", type=_positive_int, default=61)
    s.add_argument("--trace", help="a --trace file from 'register' to draw on the slice")
    s.add_argument("--center", choices=("init", "end"), default="init",
                   help="slice around the initial pose or the trace's end (default init)")
    s.add_argument("--png", required=True, help="write the picture here")
    s.add_argument("--npz", help="write the numbers here")

    s = sub.add_parser("bench", help="reproduce the paper's tables", description="Run every method from the same "
                       "seeded starts on the scenes (and the shared bunny scans when present).")
    s.add_argument("--quick", action="store_true", help="fewer runs (under 3 minutes)")
    s.add_argument("--sweep", action="store_true", help="success per start offset on the bunny pairs, with "
                   "Open3D's ICP and FPFH+RANSAC on the same starts")
    s.add_argument("--json", help="write the rows as JSON to this file")
    s.add_argument("--runs", type=_positive_int, help="starts per scene (default 10, quick 2)")
    s.add_argument("--bunny", default=str(Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "bunny"),
                   help="folder of the Stanford bunny scans")

    s = sub.add_parser("serve", help="open the workbench in a browser", description="Start the viser workbench.")
    s.add_argument("source", nargs="?")
    s.add_argument("target", nargs="?")
    s.add_argument("--scene", choices=SCENES, default="corner")
    s.add_argument("--host", default="127.0.0.1")
    s.add_argument("--port", type=_positive_int, default=8080)
    s.add_argument("--data-dir", help="folder whose scan files the page may open")
    s.add_argument("--upload-cap-mb", type=_number, default=200.0, help="largest upload accepted (default 200 MB)")

    s = sub.add_parser("merge", help="register a set of scans and fuse them into one model",
                       description="Register overlapping pairs, make poses globally consistent, fuse one mesh.")
    s.add_argument("scans", nargs="+")
    s.add_argument("--init", help="initial poses: a Stanford .conf (default: stored rough poses, else a chain)")
    s.add_argument("--truth", help="ground-truth poses (.conf) to report errors against")
    s.add_argument("--out", default="model.ply")
    s.add_argument("--seed", type=_positive_int, default=0)
    s.add_argument("--json", action="store_true")

    s = sub.add_parser("scenes", help="regenerate the bundled default scenes",
                       description="Simulate the paper's scenes (corner, wing, bowl) into a folder.")
    s.add_argument("--out", default=str(ASSETS))
    s.add_argument("--seed", type=_positive_int, default=0)
    return p


def _load(path, viewpoint=None):
    from core.io import load_scan

    return load_scan(path, viewpoint=viewpoint)


def cmd_info(a) -> int:
    from core.surface import Surface

    scan = _load(a.scan, a.viewpoint)
    tri = Surface.from_scan(scan).n_triangles
    info = {"points": len(scan.points), "bounds": [scan.points.min(0).tolist(), scan.points.max(0).tolist()],
            "units": scan.units, "viewpoint": scan.viewpoint.tolist(), "viewpoint_estimated": scan.viewpoint_estimated,
            "grid": scan.grid is not None, "triangles": tri, "spacing": scan.spacing, "dropped": scan.dropped,
            "ground_truth": scan.pose is not None}
    if a.json:
        print(json.dumps(info))
        return 0
    lo, hi = info["bounds"]
    print(f"{a.scan}")
    print(f"  points      {info['points']}" + (f" ({scan.dropped} NaN/inf dropped)" if scan.dropped else ""))
    print(f"  bounds      {np.round(lo, 5).tolist()} .. {np.round(hi, 5).tolist()} {scan.units}")
    print(f"  viewpoint   {np.round(scan.viewpoint, 5).tolist()}" + (" (estimated)" if scan.viewpoint_estimated else ""))
    print(f"  range grid  {'x'.join(map(str, scan.grid.shape)) if scan.grid is not None else 'no'}")
    print(f"  triangles   {tri}")
    print(f"  spacing     {scan.spacing:.6g} {scan.units} (median nearest-neighbour)")
    if scan.pose is not None:
        print("  ground truth pose: yes")
    return 0


def _pair_and_config(a, method="hybrid", threshold=None, **options):
    from core.io import read_transform
    from core.problem import ProblemConfig, relative_guess
    from core.register import Config

    source = _load(a.source, a.viewpoint_source)
    target = _load(a.target, a.viewpoint_target)
    T_init = read_transform(a.init) if a.init else relative_guess(source, target)
    if a.max_points < 3:
        raise InputError(f"--max-points must be at least 3, got {a.max_points}")
    if a.seed < 0:
        raise InputError(f"--seed must be >= 0, got {a.seed}")
    pc = ProblemConfig(max_points=a.max_points, frustum=a.frustum, rotation_uncertainty_deg=a.rotation_uncertainty,
                       translation_uncertainty=a.translation_uncertainty)
    cfg = Config(method=method, threshold=threshold, seed=a.seed, problem=pc, **options)
    cfg.validate()
    return source, target, T_init, cfg


class _Progress:
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


def cmd_register(a) -> int:
    from core.register import register

    source, target, T_init, cfg = _pair_and_config(a, a.method, a.threshold, polish=a.polish,
                                                   coarse_to_fine=a.coarse_to_fine, hops=a.hops,
                                                   recut_rounds=a.recut_rounds)
    trace = open(a.trace, "w") if a.trace else None
    progress = _Progress(not a.json and sys.stderr.isatty() or (not a.json and a.trace is None))

    def listener(e):
        if trace is not None:
            trace.write(json.dumps(e.to_json()) + "\n")
        progress(e)

    try:
        res = register(source, target, T_init, cfg, listener)
    finally:
        if trace is not None:
            trace.close()
    if a.out:
        from core.io import write_transform

        write_transform(a.out, res.transform, error=res.error, method=res.method)
    if a.json:
        print(json.dumps(res.to_json()))
        return 0
    print(f"method      {res.method}")
    print(f"error       {res.error:.6g} {target.units}^2 (threshold {res.threshold:.6g})")
    print(f"iterations  ICP {res.iterations['icp']}, SA {res.iterations['sa']}  (local minima {res.local_minima})")
    print(f"stopped     {res.stop_text} after {res.seconds:.2f} s")
    print("transform (maps SOURCE into TARGET's frame):")
    for row in res.transform:
        print("  " + " ".join(f"{v: .8f}" for v in row))
    if source.pose is not None and target.pose is not None:
        from core.transforms import invert, pose_error

        rot, tr = pose_error(res.transform, invert(target.pose) @ source.pose, source.points.mean(0))
        print(f"vs ground truth: rotation {rot:.3f} deg, translation {tr:.4g} {target.units} (at the source centroid)")
    if res.threshold > 0 and res.error >= res.threshold:
        t_unc = cfg.problem.translation_uncertainty_for(target.size)
        print(f"note: E stayed above the threshold, so this is probably not the registration. The search covers "
              f"about twice the guess's stated uncertainty ({cfg.problem.rotation_uncertainty_deg:g} deg, "
              f"{t_unc:.4g} {target.units}); if the guess may be farther off, give a better --init or a larger "
              "--rotation-uncertainty / --translation-uncertainty, or try --method basin-hopping.")
    return 0


def cmd_slice(a) -> int:
    from core.events import Event
    from core.landscape import compute_slice, default_span, parse_params, project
    from core.problem import prepare

    params = parse_params(a.params)
    if a.steps < 2:
        raise InputError(f"--steps must be at least 2, got {a.steps}")
    source, target, T_init, cfg = _pair_and_config(a)
    problem = prepare(source, target, T_init, cfg.problem, seed=cfg.seed)
    events = []
    if a.trace:
        tp = Path(a.trace)
        if not tp.exists():
            raise InputError(f"{tp}: no such file")
        try:
            events = [Event.from_json(json.loads(line)) for line in tp.read_text().splitlines() if line.strip()]
        except (json.JSONDecodeError, KeyError, TypeError) as exc:
            raise InputError(f"{tp}: not a rangereg trace (JSON lines of events): {exc}") from None
    center = events[-1].T if (a.center == "end" and events) else problem.T_init
    if a.span:
        try:
            spans = tuple(float(v) for v in a.span.split(","))
        except ValueError:
            raise InputError(f"--span needs two numbers a,b, got {a.span!r}") from None
        if len(spans) != 2:
            raise InputError(f"--span needs two numbers a,b, got {a.span!r}")
    else:
        spans = tuple(default_span(problem, n) for n in params)
    sl = compute_slice(problem, center, params, spans, a.steps)
    path_xy = project(problem, center, params, [problem.T_init] + [e.T for e in events]) if events else None
    phases = ["icp"] + [e.phase for e in events] if events else None
    from app.plots import slice_png

    slice_png(sl, a.png, path_xy, phases, title=f"{Path(a.source).stem} -> {Path(a.target).stem}: E({params[0]}, {params[1]})")
    if a.npz:
        np.savez(a.npz, params=np.array(params), axis_a=sl.axis_a, axis_b=sl.axis_b, values=sl.values,
                 center=center, path=path_xy if path_xy is not None else np.zeros((0, 2)))
    print(f"{sl!r} -> {a.png}" + (f", {a.npz}" if a.npz else ""))
    return 0


def cmd_scenes(a) -> int:
    from core.scenes import write_scenes

    for path in write_scenes(Path(a.out), a.seed):
        print(path)
    return 0


def cmd_bench(a) -> int:
    from app.bench import main as bench_main

    return bench_main(a)


def cmd_serve(a) -> int:
    from app.workbench import serve

    return serve(a)


def cmd_merge(a) -> int:
    from app.merge_cli import main as merge_main

    return merge_main(a)


COMMANDS = {"info": cmd_info, "register": cmd_register, "slice": cmd_slice, "bench": cmd_bench, "serve": cmd_serve,
            "merge": cmd_merge, "scenes": cmd_scenes}


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except InputError as exc:
        sys.stderr.write(f"rangereg {args.command}: error: {exc}\n")
        return 2
    except KeyboardInterrupt:
        sys.stderr.write("rangereg: interrupted\n")
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
