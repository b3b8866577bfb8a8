"""What ``register`` and ``slice`` share: the settings checked, the outputs checked, then the two scans
and the initial guess read (cheap checks first, so a typo never waits for a scan to load)."""

from __future__ import annotations

import sys
from argparse import Namespace

import numpy as np
from rangereg.app.options import Settings, parse_init, to_config, to_guess
from rangereg.core.sidefiles import names_a_file


def inputs(a: Namespace) -> list[str]:
    """Every file the command reads (never to be overwritten by an output), checked as far as it can be
    without reading a scan: the scans' kinds, formats and sizes, and ``--init`` read (once: it may be a
    pipe) into ``a.init_transform``."""
    from rangereg.core.io import check_scan_file

    for scan in (a.source, a.target):
        check_scan_file(scan)
    files = [a.source, a.target]
    if getattr(a, "init", None) is not None:
        a.init_transform = parse_init(a.init)
        if names_a_file(a.init):
            files.append(a.init)
    if getattr(a, "trace_in", None) is not None:
        files.append(a.trace_in)
    return files


def config(a: Namespace, **overrides):
    """The core Config from the parsed flags, through the one settings path (app.options)."""
    return to_config(Settings.from_mapping(vars(a), **overrides))


def guess(a: Namespace, T_init: np.ndarray, **overrides):
    """The core Guess from the parsed flags at pose ``T_init``, through the one settings path (app.options)."""
    return to_guess(Settings.from_mapping(vars(a), **overrides), T_init)


def load(a: Namespace) -> tuple[object, object, np.ndarray]:
    """(source, target, T_init (4, 4) T_target_source): ``--init`` if given, else the scans' stored guesses."""
    from rangereg.core.io import load_pair
    from rangereg.core.problem import relative_guess
    from rangereg.core.scan import scale_mismatch

    T_init = getattr(a, "init_transform", None)
    if T_init is None and a.init is not None:
        T_init = parse_init(a.init)
    kind = getattr(a, "scan_kind", None)
    source, target = load_pair(a.source, a.target, a.viewpoint_source, a.viewpoint_target, kind)
    mismatch = scale_mismatch(source, target)
    # stated alike: registered, with a warning (else core.problem refuses the pair)
    if mismatch and source.units_stated and target.units_stated and source.units == target.units:
        sys.stderr.write(f"warning: {mismatch}, though both sidecars say {source.units}\n")
    return source, target, T_init if T_init is not None else relative_guess(source, target)
