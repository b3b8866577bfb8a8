"""rangereg from Python (rangereg.api): the one call gives the CLI's pose on the same inputs and seed, whatever
form the scans come in; a prepared target gives the same pose; bad input is one InputError; inputs come back
unmodified; events arrive; docs/python.md's examples run; the wheel installs under the one name."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from contextlib import redirect_stdout
from io import StringIO
from pathlib import Path

import numpy as np
import pytest
from rangereg.app.options import Settings
from rangereg.core.scan import Scan

import rangereg
from tests.conftest import ASSETS, ROOT

LIMIT = 120.0

SRC, TGT = str(ASSETS / "corner" / "scan2.ply"), str(ASSETS / "corner" / "scan1.ply")


@pytest.fixture
def cli(capsys):
    """``rangereg ARGS --json`` in this process: the printed JSON object (the exit status must be 0). The pose
    comparisons give both sides ``time_limit`` LIMIT: the global method's bound counts seconds, so on a loaded
    machine a run may stop early and the comparison would be of the clock, not of the two front ends."""
    from rangereg.app.cli import main

    def run(*args) -> dict:
        code = main([str(a) for a in args] + ["--json"])
        out = capsys.readouterr()
        assert code == 0, out.err
        return json.loads(out.out)

    return run


def _text(T: np.ndarray) -> str:
    """16 numbers as ``--init`` takes them, exactly (repr round-trips a float64)."""
    return " ".join(repr(float(v)) for v in np.asarray(T).ravel())


@pytest.fixture(scope="module")
def corner():
    """The bundled corner's scans and the relative guess their sidecars store."""
    from rangereg.core.problem import relative_guess

    s, t = rangereg.as_scan(SRC), rangereg.as_scan(TGT)
    return s, t, relative_guess(s, t)


# ---- the same pose as the CLI --------------------------------------------------------------------------------


def test_paths_give_the_cli_pose_with_the_stored_guess(cli):
    res = rangereg.register(SRC, TGT, seed=3, time_limit=LIMIT)
    out = cli("register", SRC, TGT, "--seed", "3", "--time-limit", LIMIT)
    assert np.array_equal(res.T_target_source, np.array(out["transform"]))
    assert res.below_threshold and out["below_threshold"] and res.found_by == out["found_by"]
    assert res.error == out["error"] and res.threshold == out["threshold"] and res.stop_text == out["stop_reason"]


@pytest.mark.parametrize("method", ["global", "hybrid"])
def test_arrays_and_open3d_clouds_give_the_cli_pose_on_the_same_points(cli, corner, tmp_path, method):
    import open3d as o3d

    s, t, guess = corner
    files = []
    for name, scan in (("s.xyz", s), ("t.xyz", t)):
        np.savetxt(tmp_path / name, scan.points, fmt="%.17g")
        files.append(tmp_path / name)
    vps = dict(viewpoint_source=s.viewpoint, viewpoint_target=t.viewpoint, time_limit=LIMIT)
    out = cli("register", *files, "--seed", "1", "--method", method, "--init", _text(guess), "--rotation-uncertainty", "10",
              "--time-limit", LIMIT,
              "--viewpoint-source", ",".join(map(repr, s.viewpoint.tolist())),
              "--viewpoint-target", ",".join(map(repr, t.viewpoint.tolist())))
    want = np.array(out["transform"])
    arrays = rangereg.register(s.points, t.points, guess, seed=1, method=method, rotation_uncertainty=10, **vps)
    assert np.array_equal(arrays.T_target_source, want)
    legacy = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(x.points)) for x in (s, t)]
    assert np.array_equal(rangereg.register(*legacy, guess, seed=1, method=method, rotation_uncertainty=10,
                                            **vps).T_target_source, want)
    tensor = [o3d.t.geometry.PointCloud(o3d.core.Tensor(x.points)) for x in (s, t)]
    assert np.array_equal(rangereg.register(*tensor, guess, seed=1, method=method, rotation_uncertainty=10,
                                            **vps).T_target_source, want)
    assert arrays.below_threshold


def test_arrays_without_a_viewpoint_are_estimated_as_a_file_without_one_is(cli, corner, tmp_path):
    s, t, _ = corner
    for name, scan in (("s.xyz", s), ("t.xyz", t)):
        np.savetxt(tmp_path / name, scan.points, fmt="%.17g")
    out = cli("register", tmp_path / "s.xyz", tmp_path / "t.xyz", "--seed", "2", "--method", "hybrid")
    res = rangereg.register(s.points, t.points, seed=2, method="hybrid")
    assert np.array_equal(res.T_target_source, np.array(out["transform"]))
    assert rangereg.as_scan(s.points).viewpoint_estimated


def test_no_guess_means_what_the_cli_means(cli, corner, tmp_path):
    """Arrays carry no rough poses: with no init and no uncertainty the global method searches every pose (the
    CLI's xyz files, which hold none either, the same); stating an uncertainty keeps the identity as the guess."""
    s, t, _ = corner
    for name, scan in (("s.xyz", s), ("t.xyz", t)):
        np.savetxt(tmp_path / name, scan.points, fmt="%.17g")
    none = rangereg.register(s.points, t.points, seed=0, time_limit=LIMIT)
    assert none.details.region.stated_rotation_deg == 180.0
    out = cli("register", tmp_path / "s.xyz", tmp_path / "t.xyz", "--time-limit", LIMIT)
    assert np.array_equal(none.T_target_source, np.array(out["transform"]))
    stated = rangereg.register(s.points, t.points, seed=0, rotation_uncertainty=20, candidates=False)
    assert stated.details.region.stated_rotation_deg == 20.0


def test_scans_and_prepared_scans_give_the_one_call_pose(corner):
    s, t, _ = corner
    want = rangereg.register(SRC, TGT, seed=4, time_limit=LIMIT).T_target_source
    assert np.array_equal(rangereg.register(s, t, seed=4, time_limit=LIMIT).T_target_source, want)
    target = rangereg.prepare(TGT)
    assert target.surface.n_triangles > 1000 and target.surface._built is not None  # the query structure is built
    for _ in range(2):  # and reused, read only
        assert np.array_equal(rangereg.register(s, target, seed=4, time_limit=LIMIT).T_target_source, want)
    assert np.array_equal(rangereg.register(rangereg.prepare(s), target, seed=4, time_limit=LIMIT).T_target_source, want)
    hybrid = rangereg.register(SRC, TGT, method="hybrid", seed=4).T_target_source
    assert np.array_equal(rangereg.register(s, target, method="hybrid", seed=4).T_target_source, hybrid)
    assert rangereg.prepare(target) is target
    assert "6550 points" in repr(target) and "triangles" in repr(target)


def test_the_result_reads_as_the_cli_prints_it():
    res = rangereg.register(SRC, TGT, seed=0)
    text = repr(res)
    assert text.startswith("Result(global: trusted yes, E=") and "found by guess" in text and "within the stated region" in text
    assert "stopped: a candidate refined below the pair threshold" in text and "T_target_source=[[" in text
    assert res.T_target_source is res.transform and res.T_target_source.shape == (4, 4)
    assert res.within_region is True and res.trusted is True and res.seconds > 0


# ---- bad input ---------------------------------------------------------------------------------------------------

GOOD = np.random.default_rng(0).normal(size=(200, 3)) * [100, 80, 30]


@pytest.mark.parametrize("kwargs, message", [
    (dict(source=np.zeros((50, 2))), r"^source: expected an \(N, 3\) array of x y z points, got shape \(50, 2\)$"),
    (dict(target=np.zeros((5, 3, 1))), r"^target: expected an \(N, 3\) array .* got shape \(5, 3, 1\)$"),
    (dict(source=np.r_[GOOD, [[np.nan, 0, 0]]]), r"^source: 1 of 201 points are not finite \(NaN or inf; the first is row 200\)"),
    (dict(target=GOOD[:2]), r"^target: only 2 usable points; a scan needs at least 3$"),
    (dict(source=GOOD[:10]), r"^source: only 10 points; registering needs at least 24"),
    (dict(source=[[1, 2, 3], [4, 5]]), r"^source: expected an \(N, 3\) array of x y z points, got rows of different lengths$"),
    (dict(source=np.array([["a", "b", "c"]] * 30)), r"^source: expected an \(N, 3\) array of x y z numbers, got ndarray of <U1$"),
    (dict(source={"x": 1}), r"^source: expected an \(N, 3\) array of x y z numbers, got dict of object$"),
    (dict(source="/no/such/scan.ply"), r"^/no/such/scan.ply: no such file$"),
    (dict(method="simplex"), r"^method: unknown method 'simplex'; choose one of hybrid, icp, sa"),
    (dict(seed=-1), r"^seed: must be >= 0 and <= 4294967295, got -1$"),
    (dict(seed=1.5), r"^seed: expected a whole number, got 1.5$"),
    (dict(rotation_uncertainty=500), r"^rotation_uncertainty: must be >= 0.01 and <= 180, got 500$"),
    (dict(translation_uncertainty=-1), r"^translation_uncertainty: must be > 0, got -1$"),
    (dict(max_points=True), r"^max_points: expected a whole number >= 3 and <= 100000, got True$"),
    (dict(lock="rq"), r"^lock: "),
    (dict(frustum="round"), r"^frustum: choose one of "),
    (dict(rotation_uncertanty=5), r"^unknown option 'rotation_uncertanty' \(did you mean 'rotation_uncertainty'\?\)$"),
    (dict(init=np.eye(3)), r"^init must be a 4 x 4 matrix, got shape \(3, 3\)$"),
    (dict(init=np.diag([2.0, 1, 1, 1])), r"^init is not rigid"),
    (dict(init="1 2 3"), r"^init: "),
    (dict(viewpoint_source=[0, 0]), r"^source: the viewpoint should be three numbers x, y, z"),
    (dict(viewpoint_target=[np.inf, 0, 0]), r"^target: the viewpoint \[inf, 0.0, 0.0\] is not finite$"),
])
def test_bad_input_is_one_clear_input_error(kwargs, message):
    args = {"source": GOOD, "target": GOOD + 1.0, **kwargs}
    with pytest.raises(rangereg.InputError) as exc:
        rangereg.register(**args)
    text = str(exc.value)
    assert "\n" not in text and "--" not in text, text  # one line, in Python's names (not the CLI's flags)
    assert re.search(message, text), text


def test_a_prepared_scan_refuses_a_new_viewpoint():
    with pytest.raises(rangereg.InputError, match="a prepared scan keeps the viewpoint"):
        rangereg.register(GOOD, rangereg.prepare(GOOD), viewpoint_target=[0, 0, 1000])


def test_every_setting_of_the_table_is_an_option():
    """register() takes the settings table's names and nothing else (no second mapping to drift)."""
    from rangereg.api import OPTIONS

    assert set(OPTIONS) == {f for f in Settings.__dataclass_fields__}
    res = rangereg.register(SRC, TGT, method="icp", icp_max_iterations=3, max_points=120, frustum="nonconvex",
                            recut_rounds=1, polish=True)
    assert res.method == "icp" and res.iterations.icp <= 3 + 3 + 30  # a leg of 3, a re-cut's, the polish


def test_inputs_come_back_unmodified():
    import open3d as o3d

    a, b = GOOD.copy(), (GOOD @ np.diag([1.0, -1.0, -1.0])).copy()
    a_before, b_before = a.copy(), b.copy()
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(b))
    vp = np.array([0.0, 0.0, 500.0])
    init = np.eye(4)
    rangereg.register(a, cloud, init, method="icp", viewpoint_source=vp)
    assert np.array_equal(a, a_before) and a.flags.writeable
    assert np.array_equal(np.asarray(cloud.points), b_before)
    assert np.array_equal(vp, [0.0, 0.0, 500.0]) and np.array_equal(init, np.eye(4))
    scan = rangereg.as_scan(a)
    a[0] = 1e6  # the scan holds a copy: changing the array later changes nothing
    assert not np.shares_memory(scan.points, a) and scan.points[0, 0] != 1e6
    s = rangereg.as_scan(SRC)
    points = s.points.copy()
    rangereg.register(s, rangereg.prepare(TGT), seed=0)
    assert np.array_equal(s.points, points)


# ---- events ------------------------------------------------------------------------------------------------------


def test_a_listener_gets_every_event_and_legs_group_them():
    from rangereg.core.scenes import LESSON

    source, target = LESSON.scans(ASSETS)
    start = LESSON.start(source, target, 0)
    events = []
    res = rangereg.register(source, target, start, method="hybrid", seed=0, listener=events.append)
    assert all(isinstance(e, rangereg.Event) for e in events)
    steps = [e for e in events if e.phase_iteration > 0 and not e.local_minimum]  # markers are not steps
    assert sum(e.phase == "icp" for e in steps) == res.iterations.icp and sum(e.phase == "sa" for e in steps) == res.iterations.sa
    legs = rangereg.legs(events)
    assert [leg.phase for leg in legs][:2] == ["icp", "sa"] and legs[0].local_minimum  # ICP stuck, annealing frees it
    assert sum(len(leg.iterations) for leg in legs) == len(steps)
    assert all(np.all(np.diff(leg.iterations) > 0) for leg in legs)
    sa = next(leg for leg in legs if leg.phase == "sa")
    assert np.all(np.isfinite(sa.temperatures)) and np.all(np.isnan(legs[0].temperatures))
    # the stream yields the same events, and holds the same result
    run = rangereg.stream(source, target, start, method="hybrid", seed=0)
    streamed = list(run)
    assert [(e.phase, e.iteration, e.error) for e in streamed] == [(e.phase, e.iteration, e.error) for e in events]
    assert np.array_equal(run.result.T_target_source, res.T_target_source)


def test_a_listener_may_cancel_and_leaving_a_stream_early_cancels_it():
    def stop_at_20(e):
        if e.iteration >= 20:
            raise rangereg.Cancelled()

    res = rangereg.register(SRC, TGT, method="sa", seed=0, listener=stop_at_20)
    assert res.stop_reason == rangereg.StopReason.CANCELLED
    run = rangereg.stream(SRC, TGT, method="sa", seed=0)
    for e in run:
        if e.iteration == 30:
            break
    assert run.result.stop_reason == rangereg.StopReason.CANCELLED and run.result.iterations.sa < 100
    with pytest.raises(rangereg.InputError, match="yielded once"):
        list(run)


def test_a_stream_checks_its_inputs_before_it_starts():
    with pytest.raises(rangereg.InputError, match="^method: unknown method"):
        rangereg.stream(SRC, TGT, method="nope")


# ---- campaigns -------------------------------------------------------------------------------------------------


def test_merge_as_the_cli_merges(tmp_path, capsys):
    from rangereg.app.cli import main

    res = rangereg.merge([TGT, SRC], seed=1, build_model=False)
    assert all(res.placed)
    code = main(["merge", TGT, SRC, "--seed", "1", "--json", "--out", str(tmp_path / "m.ply")])
    out = json.loads(capsys.readouterr().out)
    assert code == 0 and out["placed"] == res.placed and len(out["pairs"]) == len(res.pairs)
    # a campaign's pairs are bounded by their work, not by seconds: the same pose however busy the machine
    assert np.array_equal(np.array(out["poses"][1]), res.poses[1])
    with pytest.raises(rangereg.InputError, match=r"^merge: two scans share a name \(scan1, scan1\)"):
        rangereg.merge([rangereg.as_scan(TGT), rangereg.as_scan(SRC).points])  # the file's stem, the 2nd array's name
    arrays = [rangereg.as_scan(TGT, name="reference"), rangereg.as_scan(SRC).points]  # "reference", "scan1"
    with pytest.raises(rangereg.InputError, match="^rotation_uncertainty and translation_uncertainty say how far"):
        rangereg.merge(arrays, rotation_uncertainty=10)  # no poses to be uncertain about
    with pytest.raises(rangereg.InputError, match="^merge needs at least two scans$"):
        rangereg.merge([TGT])
    with pytest.raises(rangereg.InputError, match="^init: 1 initial poses for 2 scans$"):
        rangereg.merge([TGT, SRC], init=[np.eye(4)])


# ---- the docs, the import, the wheel -----------------------------------------------------------------------------


def test_docs_python_md_examples_run_and_print_what_they_say(monkeypatch):
    """Every ```python block of docs/python.md, in order, in one namespace, from the repository's folder; a
    ```text block right after one holds lines it prints."""
    monkeypatch.chdir(ROOT)
    blocks = re.findall(r"```(\w+)\n(.*?)```", (ROOT / "docs" / "python.md").read_text(), re.S)
    assert sum(lang == "python" for lang, _ in blocks) >= 6
    namespace: dict = {}
    printed = ""
    for lang, code in blocks:
        if lang == "python":
            out = StringIO()
            with redirect_stdout(out):
                exec(compile(code, "docs/python.md", "exec"), namespace)
            printed = out.getvalue()
        elif lang == "text":
            for line in code.strip().splitlines():
                assert line in printed.splitlines(), f"docs/python.md says it prints {line!r}; it printed:\n{printed}"


def test_importing_rangereg_loads_neither_viser_nor_the_engine_until_asked():
    code = ("import sys, rangereg; assert 'numpy' not in sys.modules, 'numpy'; rangereg.register; "
            "assert 'viser' not in sys.modules and 'open3d' not in sys.modules; print(sorted(rangereg.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/", timeout=120)
    assert out.returncode == 0, out.stderr
    assert "register" in out.stdout and "prepare" in out.stdout


@pytest.mark.slow
def test_the_wheel_installs_rangereg_alone_with_its_scenes(tmp_path):
    """A non-editable install: every file under rangereg/ (no top-level core or app), the default scenes where
    app/cli.py and app/workbench.py look for them (Path(__file__).parent.parent / "assets")."""
    env = {**os.environ, "PIP_DISABLE_PIP_VERSION_CHECK": "1"}
    had_build = (ROOT / "build").exists()
    try:
        built = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp_path), str(ROOT)],
                               capture_output=True, text=True, timeout=600, env=env)
    finally:
        if not had_build:  # setuptools builds in the checkout's build/: leave the checkout as it was
            shutil.rmtree(ROOT / "build", ignore_errors=True)
    if built.returncode != 0 and re.search(r"(?i)connection|resolve|network|index", built.stderr):
        pytest.skip(f"the build's isolated environment needs PyPI: {built.stderr.strip().splitlines()[-1]}")
    assert built.returncode == 0, built.stderr
    (wheel,) = tmp_path.glob("rangereg-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    tops = {n.split("/")[0] for n in names}
    assert tops == {"rangereg", next(t for t in tops if t.endswith(".dist-info"))}, tops
    assert not any(n.startswith(("core/", "app/")) for n in names)
    assert {"rangereg/__init__.py", "rangereg/api.py", "rangereg/core/register.py", "rangereg/app/cli.py",
            "rangereg/app/workbench.py"} <= set(names)
    scenes = {n for n in names if n.startswith("rangereg/assets/")}
    for scene in ("corner", "wing", "bowl", "ribbed"):  # app/cli.py's and app/workbench.py's ASSETS, installed
        assert {f"rangereg/assets/{scene}/scan{k}.{ext}" for k in (1, 2) for ext in ("ply", "json")} <= scenes
    entry = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "rangereg = rangereg.app.cli:main" in entry
    assert Scan is rangereg.Scan


def test_python_started_in_the_checkout_finds_the_subpackages_without_an_editable_install():
    """``python`` run in the repository's folder imports its rangereg/ folder before any installed copy; with no
    editable install's finder (``-S``: no .pth files) rangereg.core and rangereg.app are the folders beside it."""
    deps = os.path.dirname(os.path.dirname(np.__file__))
    code = (f"import sys; sys.path.append({deps!r}); import rangereg.core, rangereg.app.cli; "
            "print(rangereg.core.__file__); print(rangereg.app.cli.ASSETS)")
    out = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert out.returncode == 0, out.stderr
    core_file, assets = out.stdout.split()
    assert Path(core_file) == ROOT / "core" / "__init__.py" and Path(assets) == ASSETS
