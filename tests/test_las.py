"""LAS/LAZ files: points with scale and offset applied, the sensor from scan-origin fields, a sidecar or
an estimate (and said so), bad files as one line, and a LAS copy of a bunny scan registering as its PLY does.
Files are built here, in tmp_path, from the shared bunny scans."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.io import load_scan
from rangereg.core.las import ORIGIN_PREFIXES
from rangereg.core.sidefiles import load_conf
from rangereg.core.transforms import from_params, invert, pose_error

from tests.conftest import BUNNY

laspy = pytest.importorskip("laspy")

SCALE = 1e-6  # metres per LAS integer: finer than the bunny's float32 coordinates need


def write_las(path, points: np.ndarray, origin_names: tuple[str, str, str] | None = None,
              origin: np.ndarray | None = None, version: str = "1.4") -> None:
    """``points`` (N, 3) as LAS/LAZ (by the suffix) with offsets at their floor; ``origin`` (3,) or
    (N, 3) written to the extra fields ``origin_names``."""
    header = laspy.LasHeader(point_format=3, version=version)
    header.scales = np.full(3, SCALE)
    header.offsets = np.floor(points.min(0)) if len(points) else np.zeros(3)
    if origin_names:
        header.add_extra_dims([laspy.ExtraBytesParams(name=n, type=np.float64) for n in origin_names])
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    if origin_names:
        o = np.broadcast_to(np.asarray(origin, dtype=np.float64), points.shape)
        for name, column in zip(origin_names, o.T):
            las[name] = column
    las.write(str(path))


def test_points_come_back_with_scale_and_offset_applied(bunny, tmp_path):
    ply = bunny("bun045")
    shifted = ply.points + np.array([512000.0, 4100000.0, 250.0])  # a projected frame's large coordinates
    for suffix in (".las", ".laz"):
        write_las(tmp_path / f"s{suffix}", shifted)
        s = load_scan(tmp_path / f"s{suffix}")
        np.testing.assert_allclose(s.points, shifted, rtol=0, atol=SCALE / 2 + 1e-9)
        assert s.units == "m" and s.name == "s" and s.grid is None and s.viewpoint_estimated


@pytest.mark.parametrize("names", [("scan_origin_x", "scan_origin_y", "scan_origin_z"), ("OriginX", "OriginY", "OriginZ"),
                                   ("sensor x", "sensor y", "sensor z"), ("Viewpoint_X", "Viewpoint_Y", "Viewpoint_Z")])
def test_scan_origin_fields_give_the_viewpoint(names, bunny, tmp_path, rangereg):
    assert any(names[0].lower().replace(" ", "").replace("_", "").startswith(p) for p in ORIGIN_PREFIXES)
    ply = bunny("bun045")
    write_las(tmp_path / "s.laz", ply.points, names, ply.viewpoint)
    s = load_scan(tmp_path / "s.laz")
    np.testing.assert_allclose(s.viewpoint, ply.viewpoint)
    assert not s.viewpoint_estimated and s.viewpoint_from == "file" and s.viewpoint_spread == 0.0
    code, out, _ = rangereg("info", tmp_path / "s.laz")
    assert code == 0 and "(estimated)" not in out


def test_without_origin_fields_the_viewpoint_is_estimated_and_said_so(bunny, tmp_path, rangereg):
    ply = bunny("bun045")
    write_las(tmp_path / "s.las", ply.points, ("intensity_x", "intensity_y", "intensity_z"), np.zeros(3))  # not origins
    s = load_scan(tmp_path / "s.las")
    assert s.viewpoint_estimated
    assert np.dot(s.viewpoint - s.points.mean(0), ply.viewpoint - ply.points.mean(0)) > 0  # the scanned side
    code, out, _ = rangereg("info", tmp_path / "s.las")
    assert code == 0 and "(estimated)" in out
    (tmp_path / "s.json").write_text(json.dumps({"viewpoint": ply.viewpoint.tolist(), "units": "m"}))
    s = load_scan(tmp_path / "s.las")  # a sidecar's viewpoint, as for any scan
    np.testing.assert_allclose(s.viewpoint, ply.viewpoint)
    assert not s.viewpoint_estimated
    moving = np.c_[ply.points[:, :2] * 0, np.linspace(0, 1, len(ply.points))] + ply.viewpoint  # a moving sensor
    write_las(tmp_path / "m.las", ply.points, ("origin_x", "origin_y", "origin_z"), moving)
    m = load_scan(tmp_path / "m.las")
    np.testing.assert_allclose(m.viewpoint, np.median(moving, axis=0), atol=1e-9)
    assert m.viewpoint_spread == pytest.approx(1.0)


@pytest.mark.parametrize("case, words", [
    ("no points", "holds 0 points"), ("corrupt laz", "compressed points are corrupt"), ("cut las", "cut short"),
    ("cut laz", "cannot read it as LAZ"), ("junk", "cannot read it as LAS"), ("header only", "cannot read it as LAS"),
    ("nan", "only 0 usable points"),
])
def test_a_bad_las_gives_one_line(case, words, bunny, tmp_path, rangereg):
    pts = bunny("bun045").points
    suffix = ".laz" if "laz" in case else ".las"
    path = tmp_path / f"bad{suffix}"
    if case == "no points":
        write_las(path, np.zeros((0, 3)))
    elif case == "nan":
        write_las(path, pts[:10])
        las = laspy.read(str(path))
        las.header.scales = np.array([np.nan, 1.0, 1.0])
        with np.errstate(invalid="ignore"):  # laspy re-scales the coordinates with the NaN while writing
            las.write(str(path))
    else:
        write_las(path, pts)
        raw = bytearray(path.read_bytes())
        if case == "corrupt laz":
            mid = len(raw) // 2
            raw[mid:mid + 4000] = np.random.default_rng(0).integers(0, 256, 4000, dtype=np.uint8).tobytes()
        elif case.startswith("cut"):
            raw = raw[: len(raw) // 2]
        elif case == "junk":
            raw = bytearray(b"not a LAS file " * 50)
        elif case == "header only":
            raw = raw[:60]
        path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match=words):
        load_scan(path)
    code, out, err = rangereg("register", path, BUNNY / "bun000.ply")
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1 and words in err


def test_the_las_copy_of_a_scan_registers_as_its_ply_does(bunny, tmp_path, rangereg):
    ply = bunny("bun045")
    write_las(tmp_path / "bun045.laz", ply.points, ("scan_origin_x", "scan_origin_y", "scan_origin_z"), ply.viewpoint)
    write_las(tmp_path / "bun045.las", ply.points)  # no origin: the viewpoint estimated from the points alone
    conf = load_conf(BUNNY / "bun.conf")
    truth = invert(conf["bun000"]) @ conf["bun045"]
    axis = np.random.default_rng(0).normal(size=3)
    init = truth @ from_params(np.r_[0.0, 0.0, 0.0, np.radians(10.0) * axis / np.linalg.norm(axis)])  # 10 deg off
    found = {}
    for source in (BUNNY / "bun045.ply", tmp_path / "bun045.laz", tmp_path / "bun045.las"):
        code, out, err = rangereg("register", source, BUNNY / "bun000.ply", "--init", " ".join(map(str, init.ravel())),
                                  "--json")
        assert code == 0, err
        res = json.loads(out)
        found[source.suffix] = np.array(res["transform"]), res["below_threshold"]
    c = ply.points.mean(0)
    for suffix, (T, trusted) in found.items():
        rot, tr = pose_error(T, truth, c)
        assert rot < 2.0 and tr < 0.002, (suffix, rot, tr)
        assert trusted == found[".ply"][1]
        rot, tr = pose_error(T, found[".ply"][0], c)
        assert rot < 0.3 and tr < 0.0003, (suffix, rot, tr)  # the same answer as the PLY's, within its noise
