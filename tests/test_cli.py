"""The command line in-process through ``main(argv)``: subcommands, --json keys, the trace round trip,
and bad input as exit status 2 with one line. (Real subprocesses: tests/test_cli_contract.py.)"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ASSETS, BUNNY

CORNER_SRC, CORNER_TGT = str(ASSETS / "corner" / "scan2.ply"), str(ASSETS / "corner" / "scan1.ply")


def test_help_lists_subcommands(rangereg):
    code, out, _ = rangereg("--help")
    assert code == 0
    for cmd in ("info", "register", "slice", "bench", "serve", "merge", "scenes"):
        assert cmd in out
    assert "--method" in rangereg("register", "--help")[1]


def test_info_json_on_a_bundled_scene(rangereg):
    code, out, err = rangereg("info", CORNER_TGT, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert {"points", "bounds", "viewpoint", "viewpoint_estimated", "grid", "triangles", "spacing"} <= set(info)
    assert info["grid"] and not info["viewpoint_estimated"] and 4000 < info["points"] < 8000


def test_info_describes_several_files_in_turn_and_says_which_could_not_be_read(rangereg, tmp_path):
    code, out, err = rangereg("info", CORNER_TGT, tmp_path / "missing.ply", CORNER_SRC, "--json")
    assert code == 2
    described = [json.loads(line) for line in out.splitlines()]
    assert [d["file"] for d in described] == [CORNER_TGT, CORNER_SRC]  # the unreadable one skipped, the rest said
    assert err.count("error:") == 1 and "missing.ply" in err
    code, out, _ = rangereg("info", CORNER_TGT, CORNER_SRC)
    assert code == 0 and out.count("  kind ") == 2 and "\n\n" in out
    code, _, err = rangereg("info", CORNER_TGT, CORNER_SRC, "--viewpoint", "1,2,3")
    assert code == 2 and "one scan" in err


def test_register_json_contract_and_trace_drawn_by_slice(rangereg, tmp_path):
    trace = tmp_path / "t.jsonl"
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--json", "--seed", "1", "--trace", trace)
    assert code == 0, err
    res = json.loads(out)
    assert {"transform", "error", "iterations", "local_minima", "evaluations", "seconds", "method", "threshold"} <= set(res)
    T = np.array(res["transform"])
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    assert {"icp", "sa"} <= set(res["iterations"])  # the default (global) adds "candidates"
    header, *events, result = [json.loads(line) for line in trace.read_text().splitlines()]
    assert header["header"]["method"] == res["method"] and header["header"]["seed"] == 1  # the run it traced
    assert result["result"]["transform"] == res["transform"]  # and closes with what it returned
    steps = [e for e in events if not e["local_minimum"]]
    assert sum(e["phase"] == "sa" for e in steps) == res["iterations"]["sa"]
    assert {"phase", "iteration", "params", "transform", "error", "temperature", "accepted", "local_minimum"} <= set(events[0])
    png, npz = tmp_path / "s.png", tmp_path / "s.npz"
    code, out, err = rangereg("slice", CORNER_SRC, CORNER_TGT, "--params", "tx,ry", "--steps", "9", "--trace", trace,
                              "--center", "end", "--png", png, "--npz", npz)
    assert code == 0, err
    assert png.stat().st_size > 10_000
    data = np.load(npz)
    assert data["values"].shape == (9, 9) and len(data["path"]) == len(events) + 1
    assert np.allclose(data["center"], res["transform"])  # --center end: the run's outcome
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz", "s.png", "t.jsonl"]  # no temporary left


def test_init_as_16_numbers_inline_or_in_a_file_gives_the_same_run(rangereg, tmp_path):
    (tmp_path / "init.txt").write_text(" ".join(map(str, np.eye(4).ravel())))
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--init", tmp_path / "init.txt", "--method", "icp", "--json")
    assert code == 0, err
    from_file = json.loads(out)
    inline = ",".join(map(str, np.eye(4).ravel()))
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--init", inline, "--method", "icp", "--json")
    assert code == 0, err
    assert from_file["method"] == "icp" and np.allclose(json.loads(out)["transform"], from_file["transform"])


@pytest.mark.parametrize("args, expect", [
    (("register", "nope.ply", CORNER_TGT), "no such file"),
    (("register", CORNER_SRC, CORNER_TGT, "--method", "magic"), "invalid choice"),
    (("register", CORNER_SRC, CORNER_TGT, "--threshold", "-3"), "--threshold: must be >= 0"),
    (("register", CORNER_SRC, CORNER_TGT, "--threshold", "abc"), "expected a number"),
    (("register", CORNER_SRC, CORNER_TGT, "--hops", "-1"), "--hops: must be >= 0"),
    (("register", CORNER_SRC, CORNER_TGT, "--recut-rounds", "0"), "--recut-rounds: must be >= 1"),
    (("register", CORNER_SRC, CORNER_TGT, "--seed", "-1"), "--seed: must be >= 0"),
    (("register", CORNER_SRC, CORNER_TGT, "--seed", "1e30"), "expected a whole number"),
    (("register", CORNER_SRC, CORNER_TGT, "--rotation-uncertainty", "inf"), "finite"),
    (("register", CORNER_SRC, CORNER_TGT, "--translation-uncertainty", "-2"), "must be > 0"),
    (("register", CORNER_SRC, CORNER_TGT, "--init", "1 2 3"), "16 numbers"),
    (("register", CORNER_SRC, CORNER_TGT, "--init", str(ASSETS)), "is a folder"),
    (("register", CORNER_SRC, CORNER_TGT, "--bogus"), "unrecognized arguments"),
    (("slice", CORNER_SRC, CORNER_TGT, "--steps", "1", "--png", "x.png"), "--steps: must be >= 2"),
    (("slice", CORNER_SRC, CORNER_TGT, "--steps", "1000000", "--png", "x.png"), "<= 201"),
    (("slice", CORNER_SRC, CORNER_TGT, "--params", "tx,qq", "--png", "x.png"), "--params"),
    (("slice", CORNER_SRC, CORNER_TGT, "--span", "1,nan", "--png", "x.png"), "--span"),
    (("slice", CORNER_SRC, CORNER_TGT, "--png", "x.foo"), "unknown suffix '.foo'"),
    (("slice", CORNER_SRC, CORNER_TGT, "--png", "x.png", "--trace", str(ASSETS)), "is a folder"),
    (("info", "pyproject.toml"), "unsupported format"),
    (("info", CORNER_TGT, "--viewpoint", "1,2"), "x,y,z"),
    (("serve", "--port", "99999"), "<= 65535"),
    (("bench", "--runs", "0"), "--runs: must be >= 1"),
])
def test_bad_input_exits_2_with_one_line(rangereg, args, expect):
    code, out, err = rangereg(*args)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and expect in lines[0], err
    assert out == ""


def test_non_rigid_init_is_refused(rangereg, tmp_path):
    bad = np.eye(4)
    bad[0, 1] = 0.5
    (tmp_path / "bad.txt").write_text(" ".join(map(str, bad.ravel())))
    code, _, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--init", tmp_path / "bad.txt")
    assert code == 2 and "not rigid" in err
    code, _, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--init", " ".join(map(str, bad.ravel())))
    assert code == 2 and "not rigid" in err


def test_an_output_never_overwrites_an_input(rangereg, tmp_path):
    init = tmp_path / "T.json"
    init.write_text(json.dumps({"transform": np.eye(4).tolist()}))
    before = init.read_bytes()
    code, _, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--init", init, "--out", init)
    assert code == 2 and "is an input file" in err
    code, _, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--out", Path(CORNER_SRC).with_suffix(".json"))
    assert code == 2 and "sidecar" in err
    assert init.read_bytes() == before


def test_a_failed_run_keeps_an_existing_trace(rangereg, tmp_path, monkeypatch):
    import importlib

    from rangereg.core.errors import InputError
    from rangereg.core.events import Event

    def failing_register(source, target, T_init, cfg, listener):
        listener(Event("icp", 1, 1, 1, np.eye(4), 1.0))
        raise InputError("the scans do not overlap (simulated)")

    monkeypatch.setattr(importlib.import_module("rangereg.core.register"), "register", failing_register)
    trace = tmp_path / "run.jsonl"
    trace.write_text("an earlier run\n")
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--trace", trace, "--out", tmp_path / "T.json")
    assert code == 2 and "do not overlap" in err and out == ""
    assert trace.read_text() == "an earlier run\n"
    assert [p.name for p in tmp_path.iterdir()] == ["run.jsonl"]  # no temporary, no --out


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_late_write_failure_prints_the_result_and_exits_2(rangereg):
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--method", "icp", "--json", "--out", "/dev/full")
    assert code == 2
    assert json.loads(out)["method"] == "icp"  # the result is not lost
    assert err.count("\n") == 1 and "--out /dev/full: cannot write it" in err


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_slice_onto_a_full_device_says_so_and_leaves_no_temporary(rangereg):
    import tempfile

    before = set(Path(tempfile.gettempdir()).iterdir())
    code, out, err = rangereg("slice", CORNER_SRC, CORNER_TGT, "--steps", "5", "--png", "/dev/full", "--npz", "/dev/null")
    assert code == 2 and out.startswith("Slice(")
    assert err.count("\n") == 1 and "--png /dev/full: cannot write it" in err
    assert not {p for p in set(Path(tempfile.gettempdir()).iterdir()) - before if p.name.startswith(".full-")}


def test_register_works_on_the_bunny_with_no_flags(rangereg):
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans are absent")
    code, out, err = rangereg("register", BUNNY / "bun045.ply", BUNNY / "bun000.ply", "--json", "--method", "icp")
    assert code == 0, err
    assert json.loads(out)["error"] < 1e-6  # metres squared: sub-millimetre residuals


def test_a_result_above_the_threshold_says_what_to_try(rangereg):
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans are absent")
    # no stored guess: identity, 45 degrees from the truth; ICP ends 30 degrees off
    code, out, _ = rangereg("register", BUNNY / "bun315.ply", BUNNY / "bun000.ply", "--method", "icp")
    assert code == 0
    assert "note: E stayed above the threshold" in out and "--rotation-uncertainty" in out
    code, out, _ = rangereg("register", BUNNY / "bun045.ply", BUNNY / "bun000.ply", "--method", "icp")  # ICP gets there
    assert code == 0 and "note:" not in out, out


def test_the_cli_defaults_make_the_config_they_made_before():
    from rangereg.app.cli import build_parser
    from rangereg.app.commands import pair
    from rangereg.core.problem import ProblemConfig
    from rangereg.core.register import Config

    a = build_parser().parse_args(["register", "s.ply", "t.ply", "--seed", "5", "--method", "icp", "--polish"])
    assert pair.config(a) == Config(method="icp", seed=5, problem=ProblemConfig(max_points=300), polish=True,
                                    hops=200, recut_rounds=1)


def test_serve_hands_the_workbench_typed_options(rangereg, monkeypatch):
    from rangereg.app import workbench  # `rangereg` here is the CLI fixture

    seen = []
    monkeypatch.setattr(workbench, "serve", lambda options: seen.append(options) or 0)
    code, _, err = rangereg("serve", "--scene", "bowl", "--port", "8123", "--upload-cap-mb", "5")
    assert code == 0, err
    assert seen == [workbench.ServeOptions(scene="bowl", port=8123, upload_cap_mb=5.0)]
    code, _, err = rangereg("serve", "--trace", "no-such-trace.jsonl")
    assert code == 2 and "no such file" in err


def test_register_with_a_lock_keeps_it_in_every_traced_event_and_slice_refuses_a_locked_axis(rangereg, tmp_path):
    trace = tmp_path / "t.jsonl"
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--json", "--lock", "rotation", "--trace", trace)
    assert code == 0, err
    assert json.loads(out)["lock"] == "rx,ry,rz"
    header, *events, _ = [json.loads(line) for line in trace.read_text().splitlines()]
    assert header["header"]["config"]["lock"]["locked"] == ["rx", "ry", "rz"]  # the header keeps every knob
    assert events and all(e["coords"][3:] == [0.0, 0.0, 0.0] for e in events)
    R0 = np.array(events[0]["transform"])[:3, :3]
    assert all(np.array_equal(np.array(e["transform"])[:3, :3], R0) for e in events)  # never turned
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--lock", "turntable:0,0,0,0,0,1")
    assert code == 0 and "locked      turntable:" in out and "free: angle" in out, err
    code, out, err = rangereg("slice", CORNER_SRC, CORNER_TGT, "--lock", "rx", "--params", "tx,rx", "--png",
                              tmp_path / "s.png")
    assert code == 2 and err.count("\n") == 1 and "--lock rx leaves tx, ty, tz, ry, rz" in err
    code, out, err = rangereg("register", CORNER_SRC, CORNER_TGT, "--lock", "rx,qq")
    assert code == 2 and err.count("\n") == 1 and "--lock: cannot lock qq" in err


def test_a_trusted_pose_beyond_the_stated_uncertainty_comes_back_and_says_where(rangereg):
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans are absent")
    # the identity stated as a guess good to 15 degrees, 45 degrees from the truth: KISS-Matcher's hypothesis
    # (start-free) is refined and trusted beyond the region; nothing inside is: it is returned, and says so
    code, out, _ = rangereg("register", BUNNY / "bun045.ply", BUNNY / "bun000.ply", "--rotation-uncertainty", 15)
    assert code == 0
    rot = float(re.search(r"vs ground truth: rotation ([0-9.]+) deg", out).group(1))
    assert rot < 1.0, out
    assert re.search(r"trust       yes: .*; found [0-9.]+ deg( / [0-9.]+ m)? beyond the stated uncertainty \(15 deg", out), out
    assert "note: the pose was found beyond the uncertainty stated for the guess" in out
    code, out, _ = rangereg("register", BUNNY / "bun045.ply", BUNNY / "bun000.ply", "--rotation-uncertainty", 15,
                            "--json")
    res = json.loads(out)
    assert res["trusted"] is True and res["within_region"] is False and res["beyond"].startswith("found ")


def test_no_guess_and_no_flags_is_no_guess_at_all(rangereg):
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans are absent")
    code, out, _ = rangereg("register", BUNNY / "bun090.ply", BUNNY / "bun000.ply")  # 90 degrees apart
    assert code == 0 and "guess       no guess" in out and "trust       yes" in out, out
    found = re.search(r"vs ground truth: rotation ([0-9.]+) deg, translation ([0-9.e-]+) m", out)
    assert float(found.group(1)) < 2.0 and float(found.group(2)) < 0.002


def test_register_says_when_a_viewpoint_was_estimated(rangereg, tmp_path):
    from rangereg.core.io import load_scan

    src = load_scan(ASSETS / "corner" / "scan2.ply")
    xyz = tmp_path / "scan2.xyz"
    np.savetxt(xyz, src.points)  # no viewpoint in the file, no sidecar: it is estimated
    code, out, _ = rangereg("register", xyz, ASSETS / "corner" / "scan1.ply", "--method", "icp")
    assert code == 0 and "viewpoint   estimated for scan2" in out, out
    code, out, _ = rangereg("register", xyz, ASSETS / "corner" / "scan1.ply", "--method", "icp", "--json")
    assert json.loads(out)["viewpoint_estimated"] == ["scan2"]


def test_merge_refuses_one_file_given_twice_by_name_or_through_a_link(tmp_path):
    # merged with itself, the scan would be placed twice (and "2 of 2 scans placed" said of one scan)
    from tests.conftest import run_cli

    link = tmp_path / "again.ply"
    link.symlink_to(CORNER_SRC)
    for other in (CORNER_SRC, link):
        r = run_cli("merge", CORNER_SRC, other, "--out", tmp_path / "m.ply", timeout=120)
        assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
        assert "are the same file: give each scan once" in r.stderr and not (tmp_path / "m.ply").exists()
