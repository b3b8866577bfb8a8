"""``rangereg scenes``: simulate the paper's scenes (corner, wing, bowl) into a folder."""

from __future__ import annotations

from argparse import Namespace

from rangereg.app.outputs import check_output_folder


def run(a: Namespace) -> int:
    from rangereg.core.scenes import write_scenes

    out = check_output_folder(a.out, "--out")
    for path in write_scenes(out, a.seed):
        print(path)
    return 0
