"""E57 files: every scan read in its own frame with its pose as the rough guess, its grid and intensity;
choosing a scan (#K, #NAME); bad files as one line; registering and merging a two-scan bunny E57 and
writing the registered poses back. Files are built here, in tmp_path, from the shared bunny scans."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.core.e57 import choose, list_scans, read_e57, read_e57_all, split_selection
from rangereg.core.e57_write import world_poses, write_e57
from rangereg.core.errors import InputError
from rangereg.core.io import load_scan, load_scans
from rangereg.core.scan import RangeGrid, Scan
from rangereg.core.surface import Surface
from rangereg.core.transforms import apply, from_params, invert, pose_error
from rangereg.core.viewpoint import grid_normals

from tests.conftest import run_cli

pye57 = pytest.importorskip("pye57")
libe57 = pye57.libe57


# ---- building files ----

def sensor_frame(scan: Scan) -> tuple[Scan, np.ndarray]:
    """A bunny scan as an E57 scanner would store it: points in a frame whose origin is the sensor
    (the PLY's viewpoint), axes as the PLY's; returns it with its true T_world_scan."""
    Tv = np.eye(4)
    Tv[:3, 3] = scan.viewpoint
    moved = Scan(points=scan.points - scan.viewpoint, viewpoint=np.zeros(3), name=scan.name, units="m",
                 grid=scan.grid, intensity=np.linspace(0.0, 1.0, len(scan.points)))
    return moved, scan.pose @ Tv


def rotated_about_centroid(T_world_scan: np.ndarray, scan: Scan, deg: float, seed: int) -> np.ndarray:
    """T_world_scan turned by ``deg`` about the scan's centroid, on a seeded random axis.

    About the centroid, not the frame's origin: the origin is the sensor, ~1.2 m from a 0.15 m bunny,
    where 10 degrees would move the bunny by ~0.2 m: not a rough pose of this object."""
    axis = np.random.default_rng(seed).normal(size=3)
    axis /= np.linalg.norm(axis)
    c = apply(T_world_scan, scan.points.mean(0)[None])[0]
    D = from_params(np.r_[0.0, 0.0, 0.0, np.radians(deg) * axis])
    D[:3, 3] = c - D[:3, :3] @ c
    return D @ T_world_scan


def bunny_e57(bunny, path, names=("bun000", "bun045"), off_deg=10.0, seed=0) -> list[np.ndarray]:
    """An E57 of the bunny scans ``names``: the first at its true pose, the others ``off_deg`` off.
    Returns the true T_world_scan of each."""
    scans, truth, stored = [], [], []
    for k, n in enumerate(names):
        s, T = sensor_frame(bunny(n))
        scans.append(s)
        truth.append(T)
        stored.append(T if k == 0 else rotated_about_centroid(T, s, off_deg, seed + k))
    write_e57(path, scans, stored)
    return truth


def write_raw(path, scans: list[dict]) -> None:
    """An E57 written field by field with libE57: each scan a dict of ``fields`` {name: (kind, array)}
    (kind: "double", "single", "int" or a scale for scaled integers), ``name`` and ``pose`` ((w, x, y, z), t)."""
    imf = libe57.ImageFile(str(path), "w")
    root = imf.root()
    imf.extensionsAdd("", libe57.E57_V1_0_URI)
    root.set("formatName", libe57.StringNode(imf, "ASTM E57 3D Imaging Data File"))
    root.set("guid", libe57.StringNode(imf, "{test}"))
    root.set("versionMajor", libe57.IntegerNode(imf, 1))
    root.set("versionMinor", libe57.IntegerNode(imf, 0))
    root.set("data3D", libe57.VectorNode(imf, True))
    data3d = libe57.VectorNode(root.get("data3D"))
    for spec in scans:
        node = libe57.StructureNode(imf)
        node.set("guid", libe57.StringNode(imf, "{scan}"))
        if "name" in spec:
            node.set("name", libe57.StringNode(imf, spec["name"]))
        if "pose" in spec:
            (w, x, y, z), t = spec["pose"]
            pose, rot, tr = libe57.StructureNode(imf), libe57.StructureNode(imf), libe57.StructureNode(imf)
            for key, v in (("w", w), ("x", x), ("y", y), ("z", z)):
                rot.set(key, libe57.FloatNode(imf, float(v)))
            for key, v in zip("xyz", t):
                tr.set(key, libe57.FloatNode(imf, float(v)))
            pose.set("rotation", rot)
            pose.set("translation", tr)
            node.set("pose", pose)
        proto, arrays = libe57.StructureNode(imf), {}
        for name, (kind, arr) in spec["fields"].items():
            if kind == "double":
                proto.set(name, libe57.FloatNode(imf, 0.0, libe57.FloatPrecision.E57_DOUBLE))
                arrays[name] = np.ascontiguousarray(arr, dtype=np.float64)
            elif kind == "single":
                proto.set(name, libe57.FloatNode(imf, 0.0, libe57.FloatPrecision.E57_SINGLE))
                arrays[name] = np.ascontiguousarray(arr, dtype=np.float32)
            elif kind == "int":
                proto.set(name, libe57.IntegerNode(imf, 0, 0, int(max(np.max(arr, initial=1), 1))))
                arrays[name] = np.ascontiguousarray(arr, dtype="q")
            else:  # scaled integers: stored as round(value / scale)
                proto.set(name, libe57.ScaledIntegerNode(imf, 0, -(2 ** 40), 2 ** 40, float(kind), 0.0))
                arrays[name] = np.ascontiguousarray(arr, dtype=np.float64)
        points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
        node.set("points", points)
        data3d.append(node)
        n = len(next(iter(arrays.values()))) if arrays else 0
        if n:
            bufs = libe57.VectorSourceDestBuffer()
            for name, arr in arrays.items():
                bufs.append(libe57.SourceDestBuffer(imf, name, arr, n, True, True))
            writer = points.writer(bufs)
            writer.write(n)
            writer.close()
    imf.close()


def cropped(grid: np.ndarray) -> np.ndarray:
    """The grid cut to the rows and columns its points occupy."""
    r, c = np.nonzero(grid >= 0)
    return grid[r.min():r.max() + 1, c.min():c.max() + 1]


def pye57_file(bunny, path) -> tuple[list[Scan], list[np.ndarray]]:
    """Two bunny scans written by pye57's own writer (single precision, rowIndex/columnIndex, intensity),
    records in row-major grid order; returns the scans as they should read back and the poses written."""
    expected, poses = [], []
    with pye57.E57(str(path), mode="w") as e:
        for k, n in enumerate(("bun000", "bun045")):
            s, _ = sensor_frame(bunny(n))
            r, c = np.nonzero(s.grid.index >= 0)
            idx = s.grid.index[r, c]  # record k holds vertex idx[k]
            T = from_params(np.r_[1.0 + k, 2.0, 3.0, 0.1, -0.2, 0.3 * k])
            e.write_scan_raw({"cartesianX": s.points[idx, 0], "cartesianY": s.points[idx, 1],
                              "cartesianZ": s.points[idx, 2], "intensity": np.arange(len(idx), dtype=np.float32),
                              "rowIndex": r.astype(np.uint16), "columnIndex": c.astype(np.uint16)},
                             name=n, rotation=np.array(_quat(T)), translation=T[:3, 3])
            grid = np.full(s.grid.shape, -1)
            grid[r, c] = np.arange(len(idx))
            expected.append(Scan(points=s.points[idx], viewpoint=np.zeros(3), name=n, grid=RangeGrid(cropped(grid))))
            poses.append(T)
    return expected, poses


def _quat(T: np.ndarray) -> tuple[float, float, float, float]:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    return w, x, y, z


# ---- reading ----

def test_every_scan_is_read_in_its_own_frame_with_its_pose_grid_and_intensity(bunny, tmp_path):
    path = tmp_path / "two.e57"
    expected, poses = pye57_file(bunny, path)
    scans = read_e57_all(path)
    assert [s.name for s in scans] == ["bun000", "bun045"]
    for s, e, T in zip(scans, expected, poses):
        np.testing.assert_allclose(s.points, e.points, atol=1e-6)  # pye57 writes single precision
        np.testing.assert_array_equal(s.grid.index, e.grid.index)
        np.testing.assert_allclose(s.guess, T, atol=1e-12)
        np.testing.assert_array_equal(s.viewpoint, np.zeros(3))
        assert not s.viewpoint_estimated and s.units == "m" and s.pose is None
        np.testing.assert_array_equal(s.intensity, np.arange(len(s.points)))
    # pye57's read_scan (transform=True) returns the points in the file's frame: our pose maps ours there
    with pye57.E57(str(path)) as e:
        d = e.read_scan(1, ignore_missing_fields=True)
    theirs = np.c_[d["cartesianX"], d["cartesianY"], d["cartesianZ"]]
    np.testing.assert_allclose(apply(scans[1].guess, scans[1].points), theirs, atol=1e-6)


def test_the_grid_is_triangulated_like_the_ply_range_grid(bunny, tmp_path):
    path = tmp_path / "b.e57"
    bunny_e57(bunny, path, names=("bun045",))
    e, ply = read_e57(path), bunny("bun045")
    assert e.grid is not None
    assert Surface.from_scan(e).n_triangles == Surface.from_scan(ply).n_triangles
    np.testing.assert_allclose(e.points + ply.viewpoint, ply.points, atol=1e-12)


def test_a_grid_whose_columns_run_the_other_way_is_mirrored_to_face_the_sensor(bunny, tmp_path):
    s, _ = sensor_frame(bunny("bun000"))
    mirrored = Scan(points=s.points, viewpoint=s.viewpoint, name="m", grid=RangeGrid(s.grid.index[:, ::-1].copy()))
    facing = lambda scan: np.einsum("ij,ij->i", grid_normals(scan.points, scan.grid), -scan.points[  # noqa: E731
        scan.grid.index[:-1, :-1][(scan.grid.index[:-1, :-1] >= 0) & (scan.grid.index[:-1, 1:] >= 0)
                                  & (scan.grid.index[1:, :-1] >= 0)]])
    assert np.mean(facing(mirrored) > 0) < 0.1  # as written, the cells face away from the sensor
    write_e57(tmp_path / "m.e57", [mirrored], [np.eye(4)])
    back = read_e57(tmp_path / "m.e57")
    assert np.mean(facing(back) > 0) > 0.9
    assert Surface.from_scan(back).n_triangles == Surface.from_scan(bunny("bun000")).n_triangles


def test_spherical_records_become_cartesian_and_invalid_records_are_left_out(tmp_path):
    rows, cols = np.mgrid[0:40, 0:50]
    az, el = np.radians(cols.ravel() * 0.5 - 12.0), np.radians(rows.ravel() * 0.5 - 10.0)
    r = 5.0 + 0.2 * np.sin(3 * az)
    state = np.zeros(r.size, dtype=int)
    state[[7, 300, 1999]] = [1, 2, 1]  # direction only, nothing: both left out
    write_raw(tmp_path / "s.e57", [{"name": "station 1", "pose": ((1, 0, 0, 0), (10.0, 20.0, 30.0)), "fields": {
        "sphericalRange": ("0.0001", r), "sphericalAzimuth": ("double", az), "sphericalElevation": ("double", el),
        "sphericalInvalidState": ("int", state), "rowIndex": ("int", rows.ravel()), "columnIndex": ("int", cols.ravel())}}])
    s = read_e57(tmp_path / "s.e57")
    keep = state == 0
    rq = np.round(r / 1e-4) * 1e-4  # scaled integers hold multiples of the scale
    want = np.c_[rq * np.cos(el) * np.cos(az), rq * np.cos(el) * np.sin(az), rq * np.sin(el)][keep]
    np.testing.assert_allclose(s.points, want, atol=1e-9)
    assert s.grid.shape == (40, 50) and (s.grid.index >= 0).sum() == keep.sum()
    assert s.e57.invalid == 3 and s.e57.coordinates == "spherical"
    np.testing.assert_allclose(s.guess[:3, 3], (10, 20, 30))
    assert s.name == "station 1" and s.intensity is None


def test_a_scan_is_chosen_by_index_from_0_or_by_name(bunny, tmp_path):
    path = tmp_path / "site.e57"
    bunny_e57(bunny, path, names=("bun000", "bun045", "bun090"))
    entries = list_scans(path)
    assert [(e.index, e.name, e.grid) for e in entries] == [(0, "bun000", (400, 512)), (1, "bun045", (400, 512)),
                                                           (2, "bun090", (400, 512))]
    assert all(e.pose is not None and e.coordinates == "cartesian" and e.intensity for e in entries)
    assert load_scan(f"{path}#2").name == "bun090"
    assert load_scan(f"{path}#bun045").name == "bun045"
    assert load_scan(f"{path}#BUN045").name == "bun045"  # a name matched regardless of case when unambiguous
    for selector, words in ((None, "holds 3 scans"), ("3", "no scan #3"), ("bun999", "no scan of that name"),
                            ("", "name a scan after '#'")):
        with pytest.raises(InputError, match=words):
            choose(entries, selector, path)
    with pytest.raises(InputError, match=r"holds 3 scans .*#0 'bun000', #1 'bun045', #2 'bun090'.*#K"):
        load_scan(path)
    assert split_selection(f"{path}#12") == (path, "12")
    assert split_selection("x.ply#2") == (type(path)("x.ply#2"), None)
    odd = tmp_path / "a#1.e57"  # a '#' inside a real file's name is part of the name
    bunny_e57(bunny, odd, names=("bun000",))
    assert split_selection(odd) == (odd, None) and load_scan(odd).name == "bun000"


def test_scans_without_names_are_named_by_file_and_index(tmp_path):
    rows, cols = np.mgrid[0:10, 0:10]
    pts = np.c_[cols.ravel() * 0.01, rows.ravel() * 0.01, 1.0 + 0.001 * (cols.ravel() % 3)]
    f = {"cartesianX": ("double", pts[:, 0]), "cartesianY": ("double", pts[:, 1]), "cartesianZ": ("double", pts[:, 2])}
    write_raw(tmp_path / "site.e57", [{"fields": f}, {"fields": f}])
    write_raw(tmp_path / "one.e57", [{"fields": f}])
    assert [s.name for s in read_e57_all(tmp_path / "site.e57")] == ["site#0", "site#1"]
    assert read_e57(tmp_path / "one.e57").name == "one"
    assert all(s.guess is None for s in read_e57_all(tmp_path / "site.e57"))  # no pose stored: no guess
    write_raw(tmp_path / "other.e57", [{"name": "Scan 0", "fields": f}])
    write_raw(tmp_path / "again.e57", [{"name": "Scan 0", "fields": f}])
    assert [s.name for s in load_scans([tmp_path / "other.e57", tmp_path / "again.e57"])] == ["other:Scan 0", "again:Scan 0"]


def test_two_single_scan_files_give_the_relative_guess_from_their_stored_poses(bunny, tmp_path):
    from argparse import Namespace

    from rangereg.app.commands import pair

    truth = []
    for n in ("bun000", "bun045"):
        truth += bunny_e57(bunny, tmp_path / f"{n}.e57", names=(n,))
    a = Namespace(source=str(tmp_path / "bun045.e57"), target=str(tmp_path / "bun000.e57"), init=None,
                  viewpoint_source=None, viewpoint_target=None)
    source, target, T_init = pair.load(a)
    np.testing.assert_allclose(T_init, invert(truth[0]) @ truth[1], atol=1e-12)


# ---- bad files: one line, exit 2 ----

def _fields(n: int) -> dict:
    pts = np.random.default_rng(0).random((n, 3))
    return {k: ("double", pts[:, i]) for i, k in enumerate(("cartesianX", "cartesianY", "cartesianZ"))}


@pytest.mark.parametrize("case, words", [
    ("truncated", "cut short"), ("junk", "corrupt"), ("tiny", "ends early"), ("no points", "holds no points"),
    ("unknown coordinates", "unknown coordinates: none of cartesianX"), ("all invalid", "flagged invalid"),
    ("out of range", "no scan #5"), ("zero quaternion", "pose is not a rigid transform"), ("empty", "empty"),
    ("folder", "folder"), ("missing", "no such file"), ("no data3D", "no data3D"),
])
def test_a_bad_e57_gives_one_line(case, words, tmp_path, rangereg):
    path, arg = tmp_path / "bad.e57", None
    if case in ("truncated", "junk", "tiny"):
        write_raw(path, [{"fields": _fields(5000)}])
        raw = path.read_bytes()
        path.write_bytes({"truncated": raw[: len(raw) // 2], "junk": b"E57 is not this" * 100, "tiny": raw[:100]}[case])
    elif case == "no points":
        write_raw(path, [{"fields": _fields(0)}])
    elif case == "unknown coordinates":
        write_raw(path, [{"fields": {"x": ("double", np.zeros(5)), "intensity": ("double", np.ones(5))}}])
    elif case == "all invalid":
        write_raw(path, [{"fields": {**_fields(50), "cartesianInvalidState": ("int", np.full(50, 2))}}])
    elif case == "out of range":
        write_raw(path, [{"fields": _fields(50)}, {"fields": _fields(50)}])
        arg = f"{path}#5"
    elif case == "zero quaternion":
        write_raw(path, [{"fields": _fields(50), "pose": ((0, 0, 0, 0), (0, 0, 0))}])
    elif case == "empty":
        path.write_bytes(b"")
    elif case == "folder":
        path.mkdir()
    elif case == "no data3D":
        imf = libe57.ImageFile(str(path), "w")
        imf.extensionsAdd("", libe57.E57_V1_0_URI)
        imf.root().set("formatName", libe57.StringNode(imf, "ASTM E57 3D Imaging Data File"))
        imf.close()
    with pytest.raises(InputError, match=words):
        load_scan(arg or path)
    import shutil

    from tests.conftest import ASSETS

    other = shutil.copy(ASSETS / "corner" / "scan1.ply", tmp_path / "other.ply")  # a good target: the E57 is the cause
    for command in ("info", "register"):  # info of the file alone lists its headers: name the scan
        args = [arg or f"{path}#0"] + ([other] if command == "register" else [])
        code, out, err = rangereg(command, *args)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, err
        assert words.split(":")[0] in err or case == "missing"


def test_a_truncated_e57_is_one_line_from_the_real_command(tmp_path):
    path = tmp_path / "cut.e57"
    write_raw(path, [{"fields": _fields(5000)}])
    path.write_bytes(path.read_bytes()[:-1000])
    res = run_cli("info", path)
    assert res.returncode == 2 and res.stdout == ""
    assert res.stderr.count("\n") == 1 and "Traceback" not in res.stderr and "ErrorBadFileLength" in res.stderr


def test_merge_needs_two_scans_and_a_one_scan_e57_is_one(bunny, tmp_path, rangereg):
    bunny_e57(bunny, tmp_path / "one.e57", names=("bun000",))
    code, _, err = rangereg("merge", tmp_path / "one.e57", "--out", tmp_path / "m.ply")
    assert code == 2 and "at least two scans" in err
    code, _, err = rangereg("merge", tmp_path / "one.e57", tmp_path / "one.e57#0", "--out", tmp_path / "one.e57")
    assert code == 2 and "input file" in err  # never overwrite an input, named with or without '#'


# ---- listing ----

def test_info_lists_the_scans_of_a_file(bunny, tmp_path, rangereg):
    path = tmp_path / "site.e57"
    bunny_e57(bunny, path)
    code, out, _ = rangereg("info", path)
    assert code == 0
    lines = out.splitlines()
    assert "2 scans" in lines[0] and "#K" in lines[0]
    assert lines[1].split()[:3] == ["#0", "bun000", "40256"] and "grid 400x512" in lines[1] and "pose t=" in lines[1]
    code, out, _ = rangereg("info", path, "--json")
    listed = json.loads(out)["scans"]
    assert [(s["index"], s["name"], s["points"], s["grid"]) for s in listed] == [
        (0, "bun000", 40256, [400, 512]), (1, "bun045", 40097, [400, 512])]
    code, out, _ = rangereg("info", f"{path}#1")
    assert code == 0 and "range grid  221x296" in out and "stored pose" in out and "(estimated)" not in out


# ---- registration, merge, writing back ----

def test_the_bunny_e57_registers_both_ways_from_its_stored_poses(bunny, tmp_path, rangereg):
    path = tmp_path / "site.e57"
    truth = bunny_e57(bunny, path, off_deg=10.0)
    for s, t in ((1, 0), (0, 1)):
        source = read_e57(path, str(s))
        guess = invert(read_e57(path, str(t)).guess) @ source.guess
        right = invert(truth[t]) @ truth[s]
        assert pose_error(guess, right, source.points.mean(0))[0] == pytest.approx(10.0, abs=1e-6)
        code, out, err = rangereg("register", f"{path}#{s}", f"{path}#{t}", "--json")
        assert code == 0, err
        rot, tr = pose_error(np.array(json.loads(out)["transform"]), right, source.points.mean(0))
        assert rot < 2.0 and tr < 0.002, (s, t, rot, tr)


def test_merge_of_the_bunny_e57_lands_both_and_writes_them_back(bunny, tmp_path, rangereg):
    path, out_path = tmp_path / "site.e57", tmp_path / "site-registered.e57"
    truth = bunny_e57(bunny, path, off_deg=10.0)
    code, out, err = rangereg("merge", path, "--out", out_path, "--workers", "1", "--json")
    assert code == 0, err
    report = json.loads(out)
    assert report["scans"] == ["bun000", "bun045"] and report["scans_out"] == str(out_path)
    scans = read_e57_all(path)
    for k, T in enumerate(report["poses"]):
        rot, tr = pose_error(np.array(T), invert(truth[0]) @ truth[k], scans[k].points.mean(0))
        assert rot < 2.0 and tr < 0.002, (k, rot, tr)
    # written back: the points, grid and intensity untouched, the first pose kept, the second registered
    with pye57.E57(str(path)) as before, pye57.E57(str(out_path)) as after:
        assert after.scan_count == 2
        for k in range(2):
            a, b = before.read_scan_raw(k), after.read_scan_raw(k)
            assert sorted(a) == sorted(b) == sorted(["cartesianX", "cartesianY", "cartesianZ", "rowIndex",
                                                     "columnIndex", "intensity"])
            for field in a:
                np.testing.assert_array_equal(a[field], b[field])
            assert after.get_header(k)["name"].value() == before.get_header(k)["name"].value()
    back = read_e57_all(out_path)
    np.testing.assert_allclose(back[0].guess, scans[0].guess, atol=1e-12)
    rot, tr = pose_error(back[1].guess, truth[1], scans[1].points.mean(0))
    assert rot < 2.0 and tr < 0.002
    assert np.array_equal(back[1].grid.index, scans[1].grid.index)


def test_written_records_are_copied_exactly_even_as_scaled_integers(tmp_path):
    rows, cols = np.mgrid[0:30, 0:30]
    pts = np.c_[cols.ravel() * 0.013 - 0.2, rows.ravel() * 0.011 - 0.15, 2.0 + 0.01 * np.sin(cols.ravel())]
    write_raw(tmp_path / "s.e57", [{"name": "a", "pose": ((1, 0, 0, 0), (1, 2, 3)), "fields": {
        "cartesianX": ("0.0005", pts[:, 0]), "cartesianY": ("single", pts[:, 1]), "cartesianZ": ("double", pts[:, 2]),
        "rowIndex": ("int", rows.ravel()), "columnIndex": ("int", cols.ravel())}}])
    s = read_e57(tmp_path / "s.e57")
    T = from_params(np.r_[5.0, 6.0, 7.0, 0.3, 0.2, 0.1])
    write_e57(tmp_path / "out.e57", [s], [T])
    with pye57.E57(str(tmp_path / "s.e57")) as a, pye57.E57(str(tmp_path / "out.e57")) as b:
        ra, rb = a.read_scan_raw(0), b.read_scan_raw(0)
        for field in ra:
            np.testing.assert_array_equal(ra[field], rb[field])
        proto = libe57.StructureNode(b.get_header(0).points.prototype())
        assert isinstance(libe57.ScaledIntegerNode(proto.get("cartesianX")), libe57.ScaledIntegerNode)
    np.testing.assert_allclose(read_e57(tmp_path / "out.e57").guess, T, atol=1e-12)


def test_scans_from_other_formats_are_written_with_the_sensor_at_their_origin(bunny, tmp_path):
    ply = bunny("bun045")
    T = from_params(np.r_[0.1, 0.2, 0.3, 0.0, 0.5, 0.0])
    write_e57(tmp_path / "p.e57", [ply], world_poses([ply], [T]))  # no stored pose: nothing to anchor to
    back = read_e57(tmp_path / "p.e57")
    np.testing.assert_array_equal(back.points, ply.points - ply.viewpoint)  # double precision: exactly
    np.testing.assert_allclose(apply(back.guess, back.points), apply(T, ply.points), atol=1e-12)
    np.testing.assert_array_equal(back.grid.index, cropped(ply.grid.index))
    assert Surface.from_scan(back).n_triangles == Surface.from_scan(ply).n_triangles


# ---- the page's Scans tab ----

def test_the_scans_tab_offers_each_scan_of_an_e57(bunny, tmp_path):
    from rangereg.app.tab.scans import choice_labels, data_choices, load_upload_all

    bunny_e57(bunny, tmp_path / "site.e57")
    write_raw(tmp_path / "plain.e57", [{"fields": _fields(50)}, {"fields": _fields(50)}])  # scans without names
    (tmp_path / "broken.e57").write_bytes(b"no")
    files = ["broken.e57", "plain.e57", "site.e57", "x.ply"]
    assert data_choices(tmp_path, files) == ["broken.e57", "plain.e57#0", "plain.e57#1", "site.e57#bun000",
                                             "site.e57#bun045", "x.ply"]
    assert load_scan(tmp_path / "site.e57#bun045").name == "bun045"  # each choice loads as it reads
    scans = load_upload_all("my site.e57", (tmp_path / "site.e57").read_bytes())
    assert [s.name for s in scans] == ["bun000", "bun045"] and scans[1].source == "upload:my site.e57#1"
    assert all(s.e57 is None for s in scans)  # the upload's temporary file is not referred to
    assert choice_labels(scans) == ["#0 bun000 (40256 points)", "#1 bun045 (40097 points)"]
    with pytest.raises(InputError, match=r"^my site.e57: cannot read it as E57") as err:
        load_upload_all("my site.e57", b"no")
    assert "tmp" not in str(err.value)


@pytest.mark.browser
def test_the_page_opens_scans_of_an_e57_from_the_data_folder_and_from_an_upload(bunny, tmp_path, browser):
    import re
    import subprocess
    import sys

    from rangereg.app.access import free_port

    from tests.conftest import ROOT
    from tests.test_workbench import open_page, show_tab

    folder = tmp_path / "data"
    folder.mkdir()
    bunny_e57(bunny, folder / "site.e57", names=("bun000", "bun045", "bun090"))
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "rangereg.app.cli", "serve", "--port", str(port), "--data-dir", str(folder)],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        while "rangereg workbench:" not in proc.stdout.readline():
            assert proc.poll() is None, proc.stdout.read()
        page = open_page(browser, f"http://127.0.0.1:{port}")
        show_tab(page, "Scans")
        # the data folder's E57 is offered scan by scan (source #1, target #0 by default)
        page.get_by_role("button", name="Open files", exact=True).click()
        page.wait_for_function("() => document.body.innerText.includes('bun045 → bun000')", timeout=60_000)
        # an uploaded E57 of three scans opens #1 onto #0 and lists its scans to choose from
        page.locator("input[type=file]").first.set_input_files(str(folder / "site.e57"))
        page.get_by_text("3 scans, #1 onto #0").first.wait_for(timeout=60_000)
        page.get_by_text("Source in E57").first.wait_for(timeout=10_000)
        page.get_by_role("combobox", name="Source in E57").click()
        page.get_by_role("option", name=re.compile(r"^#2 bun090")).click()
        page.get_by_role("button", name="Open these scans", exact=True).click()
        page.wait_for_function("() => document.body.innerText.includes('bun090 → bun000')", timeout=60_000)
        page.close()
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_panorama_is_read_and_said_to_surround_its_sensor(tmp_path, rangereg):
    rows, cols = np.mgrid[0:20, 0:180]
    az, el = np.radians(cols.ravel() * 2.0 - 180.0), np.radians(rows.ravel() * 2.0 - 20.0)
    r = 4.0 + 0.5 * np.cos(3 * az)  # a room around the scanner, all the way round
    write_raw(tmp_path / "p.e57", [{"fields": {"sphericalRange": ("double", r), "sphericalAzimuth": ("double", az),
                                               "sphericalElevation": ("double", el), "rowIndex": ("int", rows.ravel()),
                                               "columnIndex": ("int", cols.ravel())}}])
    s = read_e57(tmp_path / "p.e57")
    assert s.grid.shape == (20, 180) and s.kind == "panorama" and s.viewpoint_from == "file"
    code, out, _ = rangereg("info", tmp_path / "p.e57#0")
    assert code == 0 and "kind        panorama (the points lie all around the viewpoint)" in out


def test_merge_of_ply_scans_into_an_e57_keeps_the_project_frame_of_init(bunny, tmp_path, rangereg):
    from rangereg.core.sidefiles import load_conf
    from scipy.spatial.transform import Rotation

    from tests.conftest import BUNNY

    truth = load_conf(BUNNY / "bun.conf")
    G = from_params(np.r_[100.0, 200.0, 30.0, 0.0, 0.0, 1.0])  # the project's frame: far from the first scan's
    lines = []
    for k, n in enumerate(("bun000", "bun045")):
        T = G @ truth[n] @ from_params(np.r_[0.0, 0.0, 0.0, 0.0, np.radians(8.0 * k), 0.0])
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        values = [T[0, 3], T[1, 3], T[2, 3], -x, -y, -z, w]  # .conf holds the conjugate quaternion
        lines.append(f"bmesh {n}.ply " + " ".join(repr(float(v)) for v in values))
    (tmp_path / "init.conf").write_text("\n".join(lines) + "\n")
    code, _, err = rangereg("merge", BUNNY / "bun000.ply", BUNNY / "bun045.ply", "--init", tmp_path / "init.conf",
                            "--out", tmp_path / "out.e57", "--workers", "1")
    assert code == 0, err
    for n, back in zip(("bun000", "bun045"), read_e57_all(tmp_path / "out.e57")):
        ply = bunny(n)
        np.testing.assert_array_equal(back.points, ply.points - ply.viewpoint)
        sensor = from_params(np.r_[ply.viewpoint, 0.0, 0.0, 0.0])  # the written frame: origin at the viewpoint
        rot, tr = pose_error(back.guess, G @ truth[n] @ sensor, back.points.mean(0))
        assert rot < 2.0 and tr < 0.002, (n, rot, tr)


def test_the_selector_offered_for_a_scan_picks_that_scan(tmp_path):
    from rangereg.core.e57 import selector_for

    names = ["Station 1", "2", "a#b", " padded ", "twin", "TWIN", "", "Station 8"]
    write_raw(tmp_path / "s.e57", [{"name": n, "fields": _fields(20)} for n in names])
    entries = list_scans(tmp_path / "s.e57")
    offered = [selector_for(e, entries) for e in entries]
    assert offered == ["Station 1", "1", "2", "3", "4", "5", "6", "Station 8"]
    for k, sel in enumerate(offered):
        assert choose(entries, sel, tmp_path / "s.e57") == k
