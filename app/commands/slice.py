"""``rangereg slice``: E over two of the six pose parameters around a pose (paper Fig. 3 and 7) as a
PNG (and the numbers as .npz), with a ``register --trace`` run drawn on it. A trace whose header names
other scans (by content) is refused; one without a header (older) is drawn with a note that it could
not be checked; another guess, method or settings are drawn and said."""

from __future__ import annotations

from argparse import Namespace
from pathlib import Path

import numpy as np
from rangereg.app.commands import pair
from rangereg.app.options import parse_numbers, read_text_file
from rangereg.app.outputs import check_distinct, check_output, write_outputs
from rangereg.core.errors import InputError


def read_trace(path: str):
    """A ``register --trace`` file as a core.trace.Trace; anything else is one InputError naming the line."""
    from rangereg.core.trace import read_trace as read

    return read(read_text_file(path, "--trace"), f"--trace {path}")


SLICE_KNOBS = ("problem.", "guess.", "seed", "lock.")  # what the slice depends on: the overlap cut, its sample, a lock


def trace_notes(trace, guess, cfg, units: str = "units") -> list[str]:
    """What to say about a trace of these scans (checked before): how its run differs from this slice's
    guess (a core Guess, or a (4, 4) pose) and settings (drawn all the same), or that an old trace without a
    header could not be checked."""
    from rangereg.core.trace import NO_HEADER

    if trace.header is None:
        return [f"note: {trace.name}: {NO_HEADER}"]
    h = trace.header
    said = [f"trace: {h.source.name} -> {h.target.name}, method {h.method}, seed {h.seed}, rangereg {h.version}"]
    diff = h.differences(guess, cfg, SLICE_KNOBS, units)
    if diff:
        said.append("note: the traced run differs from this slice's settings in " + "; ".join(diff))
    return said


def run(a: Namespace) -> int:
    from rangereg.core.landscape import check_spans, compute_slice, default_span, parse_params, project
    from rangereg.core.problem import prepare

    params = parse_params(a.params)
    spans = parse_numbers(a.span, "--span", 2) if a.span is not None else None
    if spans is not None:
        try:
            check_spans(params, spans)
        except InputError as exc:
            raise InputError(f"--span: {exc}") from None
    if a.center == "end" and a.trace_in is None:
        raise InputError("--center end needs --trace (the run whose end to slice around)")
    cfg = pair.config(a)
    if cfg.lock.turntable or set(params) & set(cfg.lock.locked):
        raise InputError(f"--params {','.join(params)}: the slice must vary parameters the search may move "
                         f"(--lock {cfg.lock} leaves {', '.join(cfg.lock.free)})")
    files, scans = pair.inputs(a), [a.source, a.target]
    png = check_output(a.png, "--png", (".png",), files, scans)
    npz = check_output(a.npz, "--npz", (".npz",), files, scans) if a.npz is not None else None
    check_distinct({"--png": png, "--npz": npz})
    trace = read_trace(a.trace_in) if a.trace_in is not None else None
    events = trace.events if trace is not None else []
    source, target, T_init = pair.load(a)
    if trace is not None:
        trace.check_scans(source, target)  # a trace of other scans is refused (by content, not file name)
    guess = pair.guess(a, T_init)
    problem = prepare(source, target, guess, cfg.problem, seed=cfg.seed)
    center = trace.end if (a.center == "end" and trace is not None) else problem.T_init
    spans = spans or tuple(default_span(problem, n) for n in params)
    sl = compute_slice(problem, center, params, spans, a.steps)
    start = trace.start if trace is not None and trace.start is not None else problem.T_init  # where the run began
    path_xy = project(problem, center, params, [start] + [e.T for e in events]) if events else None
    phases = ["icp"] + [e.phase for e in events] if events else None

    def write_png(p: Path) -> None:
        from rangereg.app.plots import slice_png

        title = f"{Path(a.source).stem} -> {Path(a.target).stem}: E({params[0]}, {params[1]})"
        slice_png(sl, p, path_xy, phases, title=title, units=target.units)

    def write_npz(p: Path) -> None:
        with open(p, "wb") as f:  # a file object: savez adds no suffix of its own
            np.savez(f, params=np.array(params), axis_a=sl.axis_a, axis_b=sl.axis_b, values=sl.values, center=center,
                     path=path_xy if path_xy is not None else np.zeros((0, 2)))

    try:
        for line in trace_notes(trace, guess, cfg, target.units) if trace is not None else []:
            print(line)
        print(f"{sl!r} -> {png}" + (f", {npz}" if npz else ""))
    finally:  # the files are written even when stdout is gone (`| head`)
        write_outputs([(png, "--png", write_png, ".png"), (npz, "--npz", write_npz, ".npz")])
    return 0
