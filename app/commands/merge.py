"""``rangereg merge``: the output and side files checked up front, then app.merge_cli does the work."""

from __future__ import annotations

from argparse import Namespace

from app.options import read_text_file
from app.outputs import check_output
from core.errors import InputError


def run(a: Namespace) -> int:
    from app.merge_cli import main

    if len(a.scans) < 2:
        raise InputError("merge needs at least two scans")
    for flag in ("--init", "--truth"):
        path = getattr(a, flag[2:])
        if path is not None:
            read_text_file(path, flag)  # missing, a folder, unreadable, binary: one line now
    inputs = [p for p in (a.init, a.truth) if p]
    check_output(a.out, "--out", (".ply",), inputs, a.scans)
    return main(a)
