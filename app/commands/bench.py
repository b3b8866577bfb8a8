"""``rangereg bench``: the paper's tables (app.bench), or ``--sweep`` (app.sweep); only the output file is checked here."""

from __future__ import annotations

from argparse import Namespace

from app.outputs import check_output


def run(a: Namespace) -> int:
    if a.json is not None:
        check_output(a.json, "--json", (".json",))
    if a.sweep:
        from app.sweep import sweep

        return sweep(a)
    from app.bench import main

    return main(a)
