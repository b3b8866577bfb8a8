"""The sweep's proxy for unseen guesses (app.sweep): starts made the way users' guesses are wrong, the
method told only what a user would know, crops as families of their own, every family reported."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.app.sweep import FAMILIES, MODES, PEERS, SweepTask, View, start_pose, sweep_table, sweep_tasks, told
from rangereg.core.errors import InputError
from rangereg.core.transforms import invert, pose_error, rotation_angle


def _task(mode, rot=60.0, trans=0.05):
    return SweepTask("whole", View("s.ply"), View("t.ply"), mode, rot, trans, 3)


def test_each_mode_rotates_about_its_own_point_and_tells_only_what_a_user_knows(bunny):
    s, t = bunny("bun045"), bunny("bun000")
    T_true = invert(t.pose) @ s.pose
    c = s.centroid
    for mode in ("origin", "turntable", "centroid"):
        T0 = start_pose(_task(mode), s, t)
        assert abs(np.degrees(rotation_angle(T0[:3, :3] @ T_true[:3, :3].T)) - 60.0) < 1e-6
        moved = pose_error(T0, T_true, c)[1]
        if mode == "origin":  # rotated about the frame's origin, 0.1 m away: the centroid moves by more than the shift
            assert moved > 0.05
        else:  # about the centroid, or a vertical axis through it (the object on a turntable): the shift alone
            assert abs(moved - 0.05) < 1e-9
    # the turntable turns about the world's vertical: the relative rotation's axis is the target's y
    D = start_pose(_task("turntable", trans=0.0), s, t) @ invert(T_true)
    axis = np.array([D[2, 1] - D[1, 2], D[0, 2] - D[2, 0], D[1, 0] - D[0, 1]])
    assert abs(abs(axis / np.linalg.norm(axis) @ (t.pose[:3, :3].T @ [0, 1, 0])) - 1) < 1e-9
    assert np.array_equal(start_pose(_task("no-guess"), s, t), np.eye(4))
    assert told(_task("origin")).translation is None  # the rotation only
    assert told(_task("origin", rot=5.0)).rotation_deg == 15.0
    assert told(_task("no-guess")).is_none
    assert told(_task("centroid")).translation == 0.05


def test_the_tasks_cover_every_family_mode_and_level_and_the_table_reports_each():
    pairs = [(f, View(f"{f}-s.ply"), View(f"{f}-t.ply"), 0.5) for f in FAMILIES]
    levels = ((5.0, 0.01), (90.0, 0.075))
    tasks = sweep_tasks(pairs, MODES, levels, 2)
    assert len(tasks) == 2 * len(pairs) * (3 * len(levels) + 1)  # no guess: one level
    rows = []
    for k, task in enumerate(tasks):
        ok = k % 7 != 0
        rows.append({"family": task.family, "mode": task.mode, "offset": task.rot, "pair": task.pair, "method": "global",
                     "ok": ok, "trusted": ok and k % 5 != 0, "within_region": True, "seconds": 0.1 * (k % 9 + 1),
                     "load_seconds": 0.1})
        rows += [{"family": task.family, "mode": task.mode, "offset": task.rot, "pair": task.pair, "method": p,
                  "ok": k % 2 == 0} for p in PEERS]
    table = sweep_table(rows)
    for f in FAMILIES:
        for m in MODES:
            assert f"| {f} | {m} |" in table
    assert "trusted -> right" in table and f"all {len(tasks)} runs" in table


def test_a_row_of_the_table_counts_right_trusted_flagged_and_doubted():
    def row(ok, trusted, seconds):
        return {"family": "whole", "mode": "origin", "offset": 30.0, "pair": "a->b", "method": "global", "ok": ok,
                "trusted": trusted, "within_region": True, "seconds": seconds, "load_seconds": 0.1}

    rows = [row(True, True, 1.0), row(True, False, 2.0), row(False, False, 3.0), row(False, True, 4.0)]
    rows += [{"family": "whole", "mode": "origin", "offset": 30.0, "pair": "a->b", "method": p, "ok": p == PEERS[0]}
             for p in PEERS]
    line = next(x for x in sweep_table(rows).splitlines() if x.startswith("| whole | origin | 30 deg"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[3] == "2/4 = 50%" and cells[4] == "15%-85%"  # Wilson's 95 % interval of 2 in 4
    assert cells[5] == "1/2"  # trusted -> right: one of the two trusted runs was right
    assert cells[6] == "1/2"  # wrong, flagged: one wrong run said 'trust no'
    assert cells[7] == "1/2"  # right, doubted
    assert cells[8] == "2.50 / 3.70 / 4.00"
    assert cells[9:] == ["100%", "0%", "0%"]


def test_bench_sweep_takes_a_scheduler_without_workers_and_refuses_both(monkeypatch):
    # bench gave the sweep --workers 1 by default, which a --scheduler then contradicted: every sweep on a cluster
    # was refused
    from argparse import Namespace

    import rangereg.app.commands.bench as bench
    import rangereg.app.sweep as sweep_module

    seen = []
    monkeypatch.setattr(bench, "reach_scheduler", lambda address: None)
    monkeypatch.setattr(sweep_module, "sweep", lambda a: seen.append((a.workers, a.scheduler)) or 0)
    a = Namespace(sweep=True, workers=None, scheduler="tcp://127.0.0.1:8786", json=None)
    assert bench.run(a) == 0 and seen == [(None, "tcp://127.0.0.1:8786")]
    assert bench.run(Namespace(sweep=True, workers=None, scheduler=None, json=None)) == 0 and seen[-1] == (1, None)
    with pytest.raises(InputError, match="give one"):
        bench.run(Namespace(sweep=True, workers=2, scheduler="tcp://127.0.0.1:8786", json=None))
