"""``rangereg bench``: the paper's tables (app.bench), or ``--sweep`` (app.sweep); only the output file is checked here."""

from __future__ import annotations

from argparse import Namespace

from rangereg.app.distributed import reach_scheduler
from rangereg.app.outputs import check_output
from rangereg.core.errors import InputError


def run(a: Namespace) -> int:
    if not a.sweep:
        given = [f for f, v in (("--workers", a.workers), ("--scheduler", a.scheduler)) if v is not None]
        if given:
            two = len(given) > 1
            raise InputError(f"{' and '.join(given)} {'apply' if two else 'applies'} only with --sweep "
                             f"({'they spread' if two else 'it spreads'} the sweep's starts)")
    if a.scheduler is not None and a.workers is not None:
        raise InputError("--workers and --scheduler: give one (a scheduler's own workers run the starts)")
    if a.scheduler is not None:
        reach_scheduler(a.scheduler)
    elif a.workers is None:
        a.workers = 1  # the sweep's default: its starts in this process
    if a.json is not None:
        check_output(a.json, "--json", (".json",))
    if a.sweep:
        from rangereg.app.sweep import sweep

        return sweep(a)
    from rangereg.app.bench import main

    return main(a)
