"""``rangereg bench``: the paper's tables (app.bench); only the output file is checked here."""

from __future__ import annotations

from argparse import Namespace

from app.outputs import check_output


def run(a: Namespace) -> int:
    from app.bench import main

    if a.json is not None:
        check_output(a.json, "--json", (".json",))
    return main(a)
