"""Scanning campaigns: a simulated turntable, merged serially, on a local Dask cluster and on a
scheduler started apart; the same seeds give bitwise-equal poses everywhere."""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest
from rangereg.app.access import free_port
from rangereg.core.errors import InputError
from rangereg.core.io import load_conf, load_scan
from rangereg.core.merge import merge
from rangereg.core.merge_progress import Step
from rangereg.core.simulate import Scanner
from rangereg.core.transforms import pose_error
from rangereg.core.turntable import TurntableConfig, make_campaign, write_campaign

from tests.conftest import ROOT

SMALL = TurntableConfig(scans=8, scanner=Scanner(rows=48, cols=48, fov_deg=(24.0, 24.0), noise=0.3, outliers=0.02))


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    write_campaign(out, seed=3, config=SMALL)
    return out


@pytest.fixture(scope="module")
def serial(folder):
    """The small campaign merged by the CLI's code with one worker: (scans, initial, report)."""
    from rangereg.app.commands.merge import run as main

    scans = sorted(folder.glob("scan*.ply"))
    a = argparse.Namespace(scans=[str(p) for p in scans], init=str(folder / "init" / "chain.conf"), truth=None,
                           out=str(folder / "model.ply"), seed=0, json=True, workers=1, scheduler=None, pairs="chain",
                           rotation_uncertainty=None, translation_uncertainty=None)
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(a) == 0
    loaded = [load_scan(p) for p in scans]
    init = load_conf(folder / "init" / "chain.conf")
    return loaded, [init[s.name] for s in loaded], json.loads(buf.getvalue())


def test_rough_pose_families_are_off_by_the_offset_where_they_say():
    from rangereg.core.transforms import from_params, invert, rotation_angle
    from rangereg.core.turntable import rough_poses

    camp = make_campaign(3, SMALL)
    truth = [s.pose for s in camp.scans]
    frame = rough_poses(truth, "frame", 15.0, 20.0, seed=4)
    axis = rough_poses(truth, "axis", 15.0, 20.0, seed=4)
    assert all(np.array_equal(T, np.eye(4)) for T in rough_poses(truth, "identity", 15.0, 20.0, seed=4))
    assert all(np.array_equal(a, b) for a, b in zip(frame, rough_poses(truth, "frame", 15.0, 20.0, seed=4)))
    for T, R, A in zip(truth, frame, axis):
        # about the scan frame's origin: the rotation is the offset, and the origin moves by the shift alone
        D = invert(T) @ R
        assert np.degrees(rotation_angle(D[:3, :3])) == pytest.approx(15.0)
        assert np.linalg.norm(R[:3, 3] - T[:3, 3]) == pytest.approx(20.0)
        # about the turntable's axis through the object: a turn about world z either way, then the shift
        W = A @ invert(T)
        turn = np.degrees(rotation_angle(W[:3, :3]))
        assert turn == pytest.approx(15.0) and np.allclose(W[:3, :3] @ [0, 0, 1.0], [0, 0, 1.0])
        sign = np.sign(W[1, 0])
        Rz = from_params(np.r_[0, 0, 0, 0, 0, sign * np.radians(15.0)])
        assert np.linalg.norm((A - Rz @ T)[:3, 3]) == pytest.approx(20.0)
    from rangereg.core.errors import InputError as Bad

    with pytest.raises(Bad, match="family"):
        rough_poses(truth, "sideways", 15.0, 20.0, seed=0)


@pytest.mark.slow
def test_a_turntable_from_identity_poses_places_every_scan():
    """No poses at all: the cue picks each scan's likely neighbours, the rounds join the groups (~1 min)."""
    from dataclasses import replace

    camp = make_campaign(3, SMALL)
    scans = [replace(s, pose=None, guess=None) for s in camp.scans]
    res = merge(scans, None, build_model=False)
    assert res.mode == "features" and all(res.placed)
    for s, T in zip(camp.scans, res.poses):
        rot, move = pose_error(T, np.linalg.inv(camp.scans[0].pose) @ s.pose, s.points.mean(0))
        assert rot < 2.0 and move < 2.0, (s.name, rot, move)
    assert all(p.start == "no guess" for p in res.pairs if p.round == 1)


def test_a_four_stop_turntable_is_placed_by_its_ring():
    """Four stops 90 degrees apart: each scan overlaps its two neighbours only, one neighbour pair is trusted and three
    are right but weakly pinned, with no triangle to corroborate them; the ring that closes does (core.merge_graph).
    Before it, two scans were placed in 28 s, after retries with every stage had ended their pairs 120-135 deg off."""
    camp = make_campaign(0, TurntableConfig(scans=4))
    res = merge(camp.scans, camp.perturbed, build_model=False)
    assert all(res.placed)
    for s, T in zip(camp.scans, res.poses):
        rot, move = pose_error(T, np.linalg.inv(camp.scans[0].pose) @ s.pose, s.points.mean(0))
        assert rot < 1.0 and move < 1.0, (s.name, rot, move)
    assert sum(re.search(r"closes the loop through scan\d+, scan\d+ within", p.reason) is not None for p in res.pairs) == 3


def test_the_campaign_is_a_closed_asymmetric_object_with_its_truth_in_a_conf(folder):
    camp = make_campaign(3, SMALL)
    import trimesh

    mesh = trimesh.Trimesh(camp.vertices, camp.faces, process=False)
    assert mesh.is_watertight
    # No turn of the table maps the object onto itself: a turntable could not tell its scans apart.
    from scipy.spatial import cKDTree

    tree = cKDTree(camp.vertices)
    for deg in (45, 90, 180):
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        turned = camp.vertices @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
        assert np.median(tree.query(turned)[0]) > 0.01 * camp.size
    truth = load_conf(folder / "campaign.conf")
    assert sorted(truth) == [s.name for s in camp.scans]
    for s in camp.scans:
        assert np.allclose(truth[s.name], s.pose, atol=1e-6)
        back = load_scan(folder / f"{s.name}.ply")  # the truth beside the scans becomes their pose
        assert np.allclose(back.pose, s.pose, atol=1e-6) and np.allclose(back.points, s.points, atol=1e-3)
        assert back.units == "mm" and np.allclose(back.viewpoint, 0.0)
    # the sensor's elevation is jittered: the true poses are not the nominal ones the initial poses start from
    heights = [s.pose[2, 3] for s in camp.scans]
    assert np.ptp(heights) > 1.0
    # initial poses are off by the seeded perturbation; the chain variant's errors add up along the table
    off = [pose_error(camp.perturbed[k], s.pose, s.points.mean(0))[0] for k, s in enumerate(camp.scans)]
    assert min(off) > 0.5
    assert make_campaign(3, SMALL).scans[5].points.tobytes() == camp.scans[5].points.tobytes()


def test_a_small_campaign_merges_within_a_degree_and_half_a_percent(serial, folder):
    scans, _, rep = serial
    size = make_campaign(3, SMALL).size
    assert max(rep["rotation_error_deg"]) < 1.0
    assert max(rep["translation_error"]) < 0.005 * size
    # the first round: a chain round the table, closed by the last scan onto the first; the next rounds
    # add the pairs that overlap under the poses found
    assert rep["graph"]["mode"] == "chain"
    first = [p for p in rep["pairs"] if p["round"] == 1]
    assert len(first) == len(scans) and all(p["start"] == "rough poses" for p in first)
    assert rep["graph"]["rounds"] >= 2 and len(rep["pairs"]) > len(first)
    assert all(p["start"] == "graph pose" for p in rep["pairs"] if p["round"] > 1)
    closing = [p for p in rep["pairs"] if {p["source"], p["target"]} == {scans[0].name, scans[-1].name}]
    assert len(closing) == 1 and closing[0]["status"] == "used" and closing[0]["trusted"]
    assert rep["graph"]["used"] + rep["graph"]["rejected"] == rep["graph"]["pairs"]
    assert all(rep["placed"]) and all(r["cycle_residual"]["rotation_deg"] < 2.0 for r in rep["scan_reports"])
    assert all(r["status"] == "placed" for r in rep["scan_reports"])
    assert all((p["rejection"] is None) == (p["status"] == "used") for p in rep["pairs"])
    # the ring round the table closes: its closing pair missed the chain by little, and by less once optimised
    ring = rep["rings"][0]
    assert len(ring["scans"]) >= 3 and ring["closing_residual"]["rotation_deg"] < 2.0
    assert ring["after"]["rotation_deg"] <= ring["closing_residual"]["rotation_deg"] + 1e-9
    assert rep["model"]["triangles"] > 0
    assert rep["workers"] == 1 and rep["threads_per_worker"] is None  # serial: the libraries' own threads


def test_merge_takes_threads_per_task_stream_from_the_command_line(folder, capsys):
    from rangereg.app.cli import main

    scans = sorted(str(p) for p in folder.glob("scan*.ply"))
    argv = ["merge", *scans, "--init", str(folder / "init" / "chain.conf"), "--workers", "1", "--threads", "1",
            "--pairs", "chain", "--json", "--out", str(folder / "threads.ply")]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["threads_per_worker"] == 1


def _open3d_threads(_item) -> int:
    import open3d as o3d

    return o3d.utility.get_max_threads()


def test_serial_and_local_cluster_give_bitwise_equal_poses(serial):
    from rangereg.app.distributed import TaskRunner

    scans, initial, rep = serial  # the serial run kept the libraries' threads (all cores)
    lines, events = [], []
    with TaskRunner(2, progress=lines.append) as runner:
        res = merge(scans, initial, pairs="chain", build_model=False, map_tasks=runner.map, progress=events.append)
        # by default a local cluster shares the cores out: each of the 2 workers gets cores // 2 threads,
        # for Open3D (set in the worker) and for OpenMP/BLAS (in its environment before it started)
        each = max(1, (os.cpu_count() or 1) // 2)
        settings = runner.threading()
        assert len(settings) == 2
        for got in settings.values():
            assert got["open3d"] == each and got["OMP_NUM_THREADS"] == got["OPENBLAS_NUM_THREADS"] == str(each)
        assert runner.map(_open3d_threads, range(4)) == [each] * 4  # what the tasks themselves see
    assert any(f"2 workers on a local cluster, {each} thread(s) each" in line for line in lines)
    assert any("dashboard http://127.0.0.1:" in line for line in lines)
    assert any(e.step is Step.PAIRS and e.round == 1 and e.done == e.total == len(scans) for e in events)
    for T, ref in zip(res.poses, rep["poses"]):
        assert np.array_equal(T, np.array(ref))  # JSON floats round-trip exactly


def test_one_thread_per_task_stream_reaches_the_tasks_and_leaves_the_poses_unchanged(serial):
    import open3d as o3d
    from rangereg.app.distributed import TaskRunner

    scans, initial, rep = serial
    before = o3d.utility.get_max_threads()
    events = []
    with TaskRunner(1, threads=1) as runner:
        assert runner.threading()["this process"]["open3d"] == 1
        assert runner.map(_open3d_threads, range(3)) == [1, 1, 1]
        res = merge(scans, initial, pairs="chain", build_model=False, map_tasks=runner.map, progress=events.append)
    assert o3d.utility.get_max_threads() == before  # the limit holds for the tasks only
    # one progress count over every round: the second round's pairs add to the first's total
    n1 = len(scans)
    total = rep["graph"]["registrations"]
    counts = [e for e in events if e.step is Step.PAIRS and not e.note]
    assert any(e.round == 1 and e.done == e.total == n1 for e in counts)
    last = counts[-1]
    assert (last.round, last.done, last.total, last.estimate) == (rep["graph"]["rounds"], total, total, None)
    assert str(last).startswith(f"pairs, round {last.round} {total}/{total}") and str(last).endswith("done")
    assert all(0 <= e.done <= e.total and e.elapsed >= 0 for e in events)
    # each closest point and ray is computed alone: the thread count does not change a bit of the result
    for T, ref in zip(res.poses, rep["poses"]):
        assert np.array_equal(T, np.array(ref))


def test_an_explicit_thread_count_reaches_every_worker():
    from rangereg.app.distributed import TaskRunner

    with TaskRunner(2, threads=1) as runner:
        assert runner.map(_open3d_threads, range(4)) == [1, 1, 1, 1]
        assert all(got["open3d"] == 1 and got["MKL_NUM_THREADS"] == "1" for got in runner.threading().values())


def test_a_scheduler_started_apart_gives_the_same_poses(serial):
    from rangereg.app.distributed import TaskRunner

    scans, initial, rep = serial
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    dask = [sys.executable, "-m", "dask"]
    procs = []
    try:
        procs.append(subprocess.Popen([*dask, "scheduler", "--host", "127.0.0.1", "--port", str(port),
                                       "--dashboard-address", f"127.0.0.1:{free_port()}", "--no-show"],
                                      env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        procs.append(subprocess.Popen([*dask, "worker", address, "--nworkers", "2", "--nthreads", "1",
                                       "--no-dashboard", "--host", "127.0.0.1"],
                                      env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        deadline = time.monotonic() + 120
        client = None
        while client is None:
            try:
                client = Client(address, timeout="5s")
            except OSError:
                assert time.monotonic() < deadline, "the scheduler did not start in 120 s"
                time.sleep(0.5)
        try:
            client.wait_for_workers(2, timeout=120)
        finally:
            client.close()
        lines = []
        with TaskRunner(scheduler=address, progress=lines.append) as runner:
            res = merge(scans, initial, pairs="chain", build_model=False, map_tasks=runner.map)
        assert any(address in line and "2 workers" in line for line in lines)
        for T, ref in zip(res.poses, rep["poses"]):
            assert np.array_equal(T, np.array(ref))
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


def test_bad_runner_settings_are_one_clear_error():
    from rangereg.app.distributed import TaskRunner

    for kw, words in (({"workers": 0}, "--workers"), ({"scheduler": "localhost:8786"}, "tcp://HOST:PORT"),
                      ({"threads": 0}, "--threads"), ({"threads": 1.5}, "--threads")):
        with pytest.raises(InputError, match=words):
            TaskRunner(**kw)
    port = free_port()  # nobody listens there
    with pytest.raises(InputError, match="cannot reach the Dask scheduler"):
        with TaskRunner(scheduler=f"tcp://127.0.0.1:{port}", connect_timeout=1.0) as runner:
            runner.start()


@pytest.mark.parametrize("answer, words", [(None, "gives no Dask handshake within"),
                                            (b"HTTP/1.1 400 Bad Request\r\ncontent-length: 0\r\n\r\n",
                                             "does not answer as a Dask scheduler")])
def test_a_service_that_is_no_dask_scheduler_is_one_clear_error_in_seconds(answer, words):
    # Dask's own connect waits on the handshake for ever (a silent service held a merge past 600 s) and read an
    # HTTP answer as a frame of 3 EiB (a MemoryError, said as "out of memory")
    import socket
    import threading

    from rangereg.app.distributed import TaskRunner

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held = []

    def serve():
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            held.append(conn)
            if answer is not None:
                conn.sendall(answer)
                conn.close()

    threading.Thread(target=serve, daemon=True).start()
    try:
        t0 = time.monotonic()
        with pytest.raises(InputError, match=words):
            TaskRunner(scheduler=f"tcp://127.0.0.1:{server.getsockname()[1]}")
        assert time.monotonic() - t0 < 30
    finally:
        server.close()
        for conn in held:
            conn.close()


def test_map_tasks_keeps_the_order_serially_and_on_a_cluster():
    from rangereg.app.distributed import map_tasks

    items = list(range(7))
    assert map_tasks(abs, [-i for i in items], workers=1) == items
    assert map_tasks(abs, [-i for i in items], workers=2) == items


def _slow_abs(x: int) -> int:
    time.sleep(0.3)
    return abs(x)


def test_the_default_runner_starts_a_cluster_only_when_the_work_pays(monkeypatch):
    import rangereg.app.distributed as dist
    import rangereg.app.payback as pb

    pays = pb.cluster_pays
    payback = pb.payback_seconds(2)
    assert not pays(0.5 * payback, cores=2, load=0.1)[0]
    assert pays(2 * payback, cores=2, load=0.1)[0]
    # no more workers than tasks run at once: 3 tasks left on 8 cores pay as 3 workers would
    assert pb.payback_seconds(8, tasks=3) == pb.payback_seconds(3) > pb.payback_seconds(8)
    assert not pays(1000.0, cores=8, load=0.1, tasks=1)[0]
    # a loop that keeps more cores busy leaves a cluster less to gain: it pays later, or never
    assert pb.payback_seconds(2, busy=1.45) > 3 * payback
    assert not pays(2 * payback, cores=2, load=0.1, busy=1.45)[0]
    full, why = pays(1000.0, cores=2, load=0.1, busy=1.9)
    assert not full and "busy already" in why
    assert not pays(100.0, cores=1, load=0.0)[0]
    busy, why = pays(100.0, cores=2, load=3.0)
    assert not busy and "busy" in why
    # little work: the plain loop, and it says why
    with dist.TaskRunner(progress=[].append) as runner:
        assert runner.map(abs, [-1, -2, -3]) == [1, 2, 3]
        assert runner.serial and runner.client is None
        assert runner.choice.startswith("plain loop in this process")
    # no decision before the loop's busy cores are measured (past its first 3 tasks): the third task alone never starts
    # a cluster, whatever the work left
    runner = dist.TaskRunner()
    meter = pb.BusyCores()
    assert meter.cores is None and not runner._pays(1e6, 100, meter)
    assert runner.map(abs, []) == []  # an empty map: nothing to run, nothing started
    # a local cluster asked for, but every map one task: it ran here, and the report says so
    with dist.TaskRunner(workers=2) as runner:
        assert runner.map(abs, [-4]) == [4] and runner.map(abs, [-5]) == [5]
        assert not runner.used_cluster and runner.ran_on.startswith("plain loop in this process: one task at a time")
    # work that pays (the bound lowered, a quiet machine): the rest of the map goes to a local cluster
    monkeypatch.setattr(pb, "START_SECONDS", 0.2)
    monkeypatch.setattr(pb.BusyCores, "cores", property(lambda self: 0.9))  # the sleeps keep no core busy

    monkeypatch.setattr(pb.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setattr(dist, "default_workers", lambda: 2)
    monkeypatch.setattr(pb, "default_workers", lambda: 2)
    lines = []
    with dist.TaskRunner(progress=lines.append) as runner:
        assert runner.map(_slow_abs, [-k for k in range(8)]) == list(range(8))
        assert not runner.serial and runner.client is not None
        assert runner.choice.startswith("a local cluster of 2 workers: about")
    assert any(line.startswith("starting a local cluster") for line in lines)
    assert any(line.startswith("_slow_abss 8/8") and line.endswith("done") for line in lines)


def test_the_busy_cores_are_the_system_cpu_time_over_the_steady_tasks_wall_time(monkeypatch):
    import rangereg.app.payback as pb

    ticks = iter([(0.0, 0.0), (1.0, 9.9)] * 3 + [(10.0, 100.0), (12.0, 102.5), (20.0, 200.0), (22.0, 203.5)])
    monkeypatch.setattr(pb.BusyCores, "_now", staticmethod(lambda: next(ticks)))
    meter = pb.BusyCores()
    for _ in range(3):  # the first three tasks (a process's builds) are left out
        meter.start()
        meter.stop()
    assert meter.cores is None
    for _ in range(2):
        meter.start()
        meter.stop()
    assert meter.cores == pytest.approx((2.5 + 3.5) / 4.0)
    meter.stop()  # a stop without a start counts nothing
    assert meter.cores == pytest.approx(1.5)


def test_weakly_pinned_pairs_end_early_and_are_used_where_a_loop_corroborates_them():
    # the 10-scan campaign of the benchmark in miniature (1.6-1.9k points a scan, rough poses 15 deg about each
    # sensor): pairs two stops apart pin their motion weakly; a registration from a guess (round 1's rough poses, a
    # later round's graph pose) ends at the first such pose (core.merge.MergeConfig.guess_ends_on_weak) and the graph
    # uses those its loops corroborate
    from rangereg.core.guess import Guess
    from rangereg.core.merge_result import PairStatus, Start
    from rangereg.core.result import StopReason
    from rangereg.core.transforms import invert
    from rangereg.core.turntable import rough_poses

    camp = make_campaign(0, TurntableConfig(scans=10))
    truth = [s.pose for s in camp.scans]
    initial = rough_poses(truth, "frame", 15.0, 0.1 * camp.size, 0)
    res = merge(camp.scans, initial, build_model=False, stated=Guess.identity(15.0))
    weak = [p for p in res.pairs if p.stop is not None and p.stop.reason is StopReason.WEAKLY_PINNED]
    assert weak and not any(p.trusted for p in weak)
    assert all((p.start is Start.ROUGH_POSES) == (p.round == 1) for p in weak)
    assert any(p.start is Start.GRAPH_POSE for p in weak)  # a later round's retries from the graph end there too
    assert any(p.status is PairStatus.USED and "closes the loop" in p.reason for p in weak)
    for k, T in enumerate(res.poses):
        rot, move = pose_error(T, invert(truth[0]) @ truth[k], camp.scans[k].centroid)
        assert rot < 2.0 and move < 2.0, (k, rot, move)
