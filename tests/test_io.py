"""Loaders and writers of scan files (core.io, core.ply) and their bad-input messages."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.io import load_scan, save_scan
from rangereg.core.ply import write_ply


def test_bunny_loads_with_grid_and_truth(bunny):
    s = bunny("bun000")
    assert len(s.points) == 40256
    assert s.grid is not None and s.grid.shape == (400, 512)
    assert (s.grid.index >= 0).sum() == 40256
    assert s.units == "m"
    assert s.viewpoint_estimated and s.viewpoint[2] > 0.5  # on +z, as the bunny README measured
    np.testing.assert_allclose(s.pose, np.eye(4))


def _cube_points(n=500, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-1, 1, (n, 3))
    p[:, 2] = 0.2 * np.sin(p[:, 0] * 2) + 0.1 * p[:, 1] ** 2 - 3.0
    return p


@pytest.mark.parametrize("fmt", ["ply", "xyz", "txt", "csv"])
def test_point_formats_round_trip(tmp_path, fmt):
    pts = _cube_points()
    path = tmp_path / f"s.{fmt}"
    if fmt == "ply":
        write_ply(path, pts)
    else:
        sep = "," if fmt == "csv" else " "
        path.write_text(("x,y,z\n" if fmt == "csv" else "") + "\n".join(sep.join(f"{v:.6f}" for v in p) for p in pts))
    s = load_scan(path)
    np.testing.assert_allclose(s.points, pts, atol=1e-5)
    # the sheet lies 3 units in front of the frame's origin: the sensor there, by convention
    assert s.viewpoint_from == "convention" and np.allclose(s.viewpoint, 0)


def test_bare_points_around_the_origin_get_an_estimated_viewpoint(tmp_path):
    pts = _cube_points() + [0, 0, 3.0]  # the origin now lies within the sheet: no view from there
    np.savetxt(tmp_path / "s.xyz", pts)
    s = load_scan(tmp_path / "s.xyz")
    assert s.viewpoint_estimated and s.viewpoint_from == "estimate" and s.kind == "single-view"


def test_ascii_ply_and_faces(tmp_path):
    path = tmp_path / "m.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n1 1 0.1\n0 1 0\n4 0 1 2 3\n")
    s = load_scan(path)
    assert s.faces.shape == (2, 3)


def test_pcd_viewpoint_and_binary(tmp_path):
    pts = _cube_points(200).astype(np.float32)
    head = ("# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 200\nHEIGHT 1\n"
            "VIEWPOINT 0 0 5 1 0 0 0\nPOINTS 200\n")
    (tmp_path / "a.pcd").write_text(head + "DATA ascii\n" + "\n".join(" ".join(map(str, p)) for p in pts))
    (tmp_path / "b.pcd").write_bytes((head + "DATA binary\n").encode() + pts.tobytes())
    for name in ("a.pcd", "b.pcd"):
        s = load_scan(tmp_path / name)
        np.testing.assert_allclose(s.points, pts, atol=1e-5)
        np.testing.assert_allclose(s.viewpoint, [0, 0, 5])
        assert not s.viewpoint_estimated


@pytest.mark.parametrize("fmt", ["obj", "stl", "off"])
def test_mesh_formats_keep_faces(tmp_path, fmt):
    import trimesh

    mesh = trimesh.creation.icosphere(subdivisions=2)
    path = tmp_path / f"m.{fmt}"
    mesh.export(path)
    s = load_scan(path)
    assert s.faces is not None and len(s.faces) == len(mesh.faces)


def test_an_obj_keeps_every_vertex_in_its_order_whether_faces_use_them_or_not(tmp_path):
    # trimesh's OBJ reader keeps only the vertices faces use: one face over 1600 vertices was read as 3 points,
    # and a file of vertices alone as "no vertices"
    pts = _cube_points(1600)
    rows = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in pts)
    (tmp_path / "v.obj").write_text(rows)
    (tmp_path / "f.obj").write_text(rows + "f 1 2 3\nf 1600 1599 1598\n")
    alone, partial = load_scan(tmp_path / "v.obj"), load_scan(tmp_path / "f.obj")
    np.testing.assert_allclose(alone.points, pts)
    np.testing.assert_allclose(partial.points, pts)
    assert alone.faces is None and partial.faces.tolist() == [[0, 1, 2], [1599, 1598, 1597]]
    # one part per material, each holding the whole vertex list: the vertices once, the faces of every part
    (tmp_path / "m.obj").write_text(rows + "usemtl a\nf 1 2 3\nusemtl b\nf 4 5 6\nusemtl c\nf 7 8 9\n")
    materials = load_scan(tmp_path / "m.obj")
    np.testing.assert_allclose(materials.points, pts)
    assert sorted(materials.faces.tolist()) == [[0, 1, 2], [3, 4, 5], [6, 7, 8]]


def test_an_ascii_float_past_float32s_range_is_dropped_as_non_finite_without_a_numpy_warning(tmp_path):
    import warnings

    pts = _cube_points(40)
    pts[3, 2] = 1e39  # a float property: past float32's range
    head = "ply\nformat ascii 1.0\nelement vertex 40\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
    (tmp_path / "o.ply").write_text(head + "".join(f"{x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in pts))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        s = load_scan(tmp_path / "o.ply")
    assert len(s.points) == 39 and np.isfinite(s.points).all()
    # an integer property past its type's range would wrap into another number: refused, named
    colour = head.replace("end_header", "property uchar red\nend_header")
    (tmp_path / "c.ply").write_text(colour + "".join(f"{x:.9g} {y:.9g} 1 {300 if k == 3 else 7}\n"
                                                     for k, (x, y, _) in enumerate(pts)))
    with pytest.raises(InputError, match="property 'red' of element 'vertex' holds 300, beyond its type's range"):
        load_scan(tmp_path / "c.ply")


def test_save_and_reload_keeps_grid_viewpoint_and_truth(tmp_path, scene):
    a, _ = scene("corner")
    save_scan(tmp_path / "c.ply", a)
    b = load_scan(tmp_path / "c.ply")
    np.testing.assert_allclose(b.points, a.points, atol=1e-2)
    np.testing.assert_array_equal(b.grid.index, a.grid.index)
    np.testing.assert_allclose(b.pose, a.pose)
    assert b.units == "mm" and not b.viewpoint_estimated


def test_viewpoint_override(tmp_path):
    pts = _cube_points()
    write_ply(tmp_path / "s.ply", pts)
    s = load_scan(tmp_path / "s.ply", viewpoint=np.array([0.0, 0.0, 10.0]))
    assert not s.viewpoint_estimated and s.viewpoint[2] == 10


@pytest.mark.parametrize("content, expect", [
    (None, "no such file"),
    (b"", "empty"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend", "not a PLY"),
    (b"ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
     "ends inside element 'vertex'.*header says 5 vertex rows.*holds only 1"),
])
def test_bad_ply_files(tmp_path, content, expect):
    path = tmp_path / "bad.ply"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError, match=expect) as err:
        load_scan(path)
    assert str(path) in str(err.value)


def test_unsupported_format(tmp_path):
    (tmp_path / "a.docx").write_text("hello")
    with pytest.raises(InputError, match="unsupported format"):
        load_scan(tmp_path / "a.docx")


def test_nan_points_dropped_and_counted(tmp_path):
    pts = _cube_points(100)
    pts[:7, 1] = np.nan
    pts[7, 0] = np.inf
    write_ply(tmp_path / "n.ply", pts)
    s = load_scan(tmp_path / "n.ply")
    assert len(s.points) == 92 and s.dropped == 8


def _refused(reader, path, text: str, match: str) -> None:
    """Write ``text`` to ``path`` and check ``reader`` refuses it with a message matching ``match``."""
    path.write_text(text)
    with pytest.raises(InputError, match=match):
        reader(path)


def test_too_few_and_collinear_points(tmp_path):
    _refused(load_scan, tmp_path / "two.xyz", "0 0 0\n1 1 1\nnan 0 0\n", "only 2 usable points.*1 NaN")
    _refused(load_scan, tmp_path / "line.xyz", "\n".join(f"{t} {2 * t} {3 * t}" for t in range(50)), "on a line")


def test_text_garbage(tmp_path):
    (tmp_path / "g.xyz").write_text("1 2 3\n4 5 banana\n")
    with pytest.raises(InputError, match="line 2"):
        load_scan(tmp_path / "g.xyz")


def test_flat_scan_is_refused_for_registration(tmp_path):
    from rangereg.core import prepare

    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 1, (300, 2)), np.zeros(300)]
    write_ply(tmp_path / "flat.ply", pts)
    s = load_scan(tmp_path / "flat.ply", viewpoint=np.array([0.5, 0.5, 3.0]))
    with pytest.raises(InputError, match="flat"):
        prepare(s, s)


def test_edge_on_viewpoint_cannot_triangulate(tmp_path):
    from rangereg.core.surface import triangulate

    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(0, 1, (300, 2)), np.zeros(300)]
    write_ply(tmp_path / "flat.ply", pts)
    s = load_scan(tmp_path / "flat.ply", viewpoint=np.array([5.0, 0.5, 0.0]))
    with pytest.raises(InputError, match="too thin|beside or behind"):
        triangulate(s)


_HEAD = "ply\nformat {fmt} 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\nend_header\n"


def _ascii_ply(path, declared: int, rows: int) -> None:
    pts = _cube_points(rows)
    path.write_text(_HEAD.format(fmt="ascii", n=declared) + "\n".join(" ".join(f"{v:.5f}" for v in p) for p in pts) + "\n")


def _binary_ply(path, declared, body: bytes) -> None:
    path.write_bytes(_HEAD.format(fmt="binary_little_endian", n=declared).encode() + body)


@pytest.mark.parametrize("declared, rows, match", [
    (50, 3600, "header says element vertex 50 but 10650 numbers follow the last row, i.e. 3600 vertex rows"),
    (3600, 50, "ends inside element 'vertex': the header says 3600 vertex rows .*holds only 50"),
    (-5, 3600, "negative count"),
    ("five", 10, "count 'five' is not a whole number"),
])
def test_ascii_ply_header_that_lies_is_refused(tmp_path, declared, rows, match):
    path = tmp_path / "lie.ply"
    _ascii_ply(path, declared, rows)
    with pytest.raises(InputError, match=match) as err:
        load_scan(path)
    assert str(path) in str(err.value)


def test_binary_ply_body_of_the_wrong_length_is_refused(tmp_path):
    pts = _cube_points(100).astype("<f4")
    path = tmp_path / "b.ply"
    _binary_ply(path, 100, pts.tobytes())
    assert len(load_scan(path).points) == 100  # the honest file reads
    _binary_ply(path, 100, pts.tobytes() + b"\n")  # a trailing newline is harmless
    assert len(load_scan(path).points) == 100
    _binary_ply(path, 40, pts.tobytes())
    with pytest.raises(InputError, match="header says element vertex 40 but 720 bytes follow.*100 vertex rows"):
        load_scan(path)
    _binary_ply(path, 100, pts.tobytes()[:-6])
    with pytest.raises(InputError, match=r"ends inside element 'vertex': the header says 100 vertex rows "
                       r"\(element vertex 100, 12 bytes each\) but the file holds only 99 \(1194 bytes\)"):
        load_scan(path)
    _binary_ply(path, -5, pts.tobytes())
    with pytest.raises(InputError, match="negative count"):
        load_scan(path)


def test_ply_list_with_a_negative_length_is_refused(tmp_path):
    path = tmp_path / "neg.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list char int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 1\n-3 0 1 2\n")
    with pytest.raises(InputError, match="a list of -3 items"):
        load_scan(path)


def test_binary_ply_list_with_a_negative_length_is_refused(tmp_path):
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
            "property float z\nelement face 2\nproperty list char int vertex_indices\nend_header\n")
    verts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1]], "<f4").tobytes()
    faces = np.array([3], "i1").tobytes() + np.array([0, 1, 2], "<i4").tobytes() + np.array([-2], "i1").tobytes()
    (tmp_path / "neg.ply").write_bytes(head.encode() + verts + faces)
    with pytest.raises(InputError, match="a list of -2 items"):
        load_scan(tmp_path / "neg.ply")


def test_the_bunny_plys_still_read_whole(bunny):
    # the honest Stanford range-grid files pass the checks (leftover data would be refused)
    for name in ("bun000", "bun045", "bun090", "bun315"):
        s = bunny(name)
        assert (s.grid.index >= 0).sum() == len(s.points)


def test_a_face_with_a_negative_vertex_index_is_refused(tmp_path):
    path = tmp_path / "f.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n1 1 0.1\n0 1 0\n3 0 -2 1\n")
    with pytest.raises(InputError, match="a face refers to vertex -2; the file has vertices 0 to 3"):
        load_scan(path)


def test_quads_are_split_into_fans(tmp_path):
    path = tmp_path / "q.ply"
    path.write_text("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                    "0 0 0\n1 0 0\n1 1 0.1\n0 1 0\n2 0 0\n2 1 0\n4 0 1 2 3\n4 1 4 5 2\n")
    assert load_scan(path).faces.tolist() == [[0, 1, 2], [0, 2, 3], [1, 4, 5], [1, 5, 2]]


def test_viewpoint_at_the_centre_of_the_points_is_a_panorama_and_refused_as_a_single_view(tmp_path):
    from rangereg.core.frustum import frustum_of
    from rangereg.core.scan import ScanKind
    from rangereg.core.surface import triangulate

    pts = np.r_[_cube_points(200), -_cube_points(200, seed=1)]  # two sheets around the origin
    write_ply(tmp_path / "s.ply", pts)
    assert load_scan(tmp_path / "s.ply", viewpoint=pts.mean(0)).kind is ScanKind.PANORAMA  # seen all around
    s = load_scan(tmp_path / "s.ply", viewpoint=pts.mean(0), kind=ScanKind.SINGLE_VIEW)  # as a user insists
    for build in (triangulate, frustum_of):
        with pytest.raises(InputError, match="centre of the points|beside or behind"):
            build(s)


@pytest.mark.parametrize("viewpoint, match", [
    ([0, 0], "should be three numbers"), ([0, np.nan, 1], "not finite"), ("up", "should be three numbers")])
def test_a_bad_viewpoint_argument_is_refused(tmp_path, viewpoint, match):
    write_ply(tmp_path / "s.ply", _cube_points())
    with pytest.raises(InputError, match=match):
        load_scan(tmp_path / "s.ply", viewpoint=viewpoint)


@pytest.mark.parametrize("change, said", [
    (("FIELDS x y z", "FIELDS x y z x"), "names the field 'x' more than once"),
    (("TYPE F F F", "TYPE f f f"), None),  # lower case: the same types
    (("TYPE F F F", "TYPE F F Q"), "TYPE Q and SIZE 4, no number type"),
    (("SIZE 4 4 4", "SIZE 2 2 2"), "TYPE F and SIZE 2, no number type"),
    (("SIZE 4 4 4", "SIZE 4 4 four"), "SIZE should hold whole numbers"),
    (("COUNT 1 1 1", "COUNT 1 1"), "3 FIELDS but gives 3 SIZE, 3 TYPE and 2 COUNT"),
    (("COUNT 1 1 1", "COUNT 1 1 0"), "COUNT values must be at least 1"),
    (("POINTS 50", "POINTS many"), "POINTS should hold whole numbers"),
    (("POINTS 50", "POINTS -5"), "a negative number of points"),
    (("POINTS 50", "POINTS 49"), "POINTS 49 but WIDTH x HEIGHT 50 x 1"),
    (("WIDTH 50\nHEIGHT 1\n", ""), None),  # POINTS alone is enough
    (("POINTS 50\n", ""), None),  # and WIDTH x HEIGHT alone
    (("WIDTH 50\nHEIGHT 1\nPOINTS 50\n", ""), "neither POINTS nor WIDTH"),
])
def test_a_pcd_header_whose_numbers_disagree_or_name_no_type_is_one_message(tmp_path, change, said):
    pts = _cube_points(50).astype(np.float32)
    head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 50\nHEIGHT 1\nPOINTS 50\n"
    head = head.replace(*change)
    extra = np.zeros((50, 1), np.float32) if "x y z x" in head else np.zeros((50, 0), np.float32)
    (tmp_path / "b.pcd").write_bytes((head + "DATA binary\n").encode() + np.c_[pts, extra].tobytes())
    if said is None:
        np.testing.assert_allclose(load_scan(tmp_path / "b.pcd").points, pts, atol=1e-6)
        return
    with pytest.raises(InputError, match=said):
        load_scan(tmp_path / "b.pcd")


def test_a_binary_pcd_with_more_bytes_than_its_points_is_refused(tmp_path):
    pts = _cube_points(50).astype(np.float32)
    head = "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 40\nHEIGHT 1\nPOINTS 40\nDATA binary\n"
    (tmp_path / "b.pcd").write_bytes(head.encode() + pts.tobytes())
    with pytest.raises(InputError, match="40 points of 12 bytes .* but 600 bytes follow"):
        load_scan(tmp_path / "b.pcd")


def test_a_pcd_viewpoint_that_is_not_finite_is_refused(tmp_path):
    pts = _cube_points(50)
    head = ("VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 50\nHEIGHT 1\n"
            "VIEWPOINT nan 0 5 1 0 0 0\nPOINTS 50\nDATA ascii\n")
    (tmp_path / "a.pcd").write_text(head + "\n".join(" ".join(map(str, p)) for p in pts))
    with pytest.raises(InputError, match="VIEWPOINT .* not finite"):
        load_scan(tmp_path / "a.pcd")


def _bin_frames(tmp_path, width: int = 4, suffix: str = ".bin"):
    """The simulated street's LiDAR pair written as KITTI (4 float32 a point) or nuScenes (5) frames, and the truth."""
    from rangereg.core import scenes_sensor as ss
    from rangereg.core.transforms import invert

    s, t = ss.lidar_pair("street", 0, ss.Spinning(rings=16, steps=512))
    paths = []
    for scan, name in ((s, "000001"), (t, "000000")):
        extra = np.c_[np.random.default_rng(0).random(len(scan.points)), np.arange(len(scan.points)) % 16][:, :width - 3]
        np.c_[scan.points, extra].astype("<f4").tofile(tmp_path / f"{name}{suffix}")
        paths.append(tmp_path / f"{name}{suffix}")
    return paths, invert(t.pose) @ s.pose, s


@pytest.mark.parametrize("width, suffix", [(4, ".bin"), (5, ".pcd.bin")])
def test_a_kitti_or_nuscenes_lidar_frame_is_a_panorama_in_metres_at_its_origin(tmp_path, width, suffix):
    (src, tgt), T_true, s = _bin_frames(tmp_path, width, suffix)
    scan = load_scan(src)
    assert scan.kind.value == "panorama" and np.array_equal(scan.viewpoint, np.zeros(3)) and scan.units == "m"
    written = np.fromfile(src, "<f4").reshape(-1, width)
    assert np.array_equal(scan.points, written[:, :3].astype(np.float64)) and np.array_equal(scan.intensity, written[:, 3])
    assert any(("KITTI" if width == 4 else "nuScenes") in note for note in scan.notes)
    from rangereg.core.guess import Guess
    from rangereg.core.register import Config, register
    from rangereg.core.transforms import pose_error

    r = register(scan, load_scan(tgt), Guess(np.eye(4)), Config(method="global"))  # odometry: from the identity
    rot, trans = pose_error(r.transform, T_true)
    assert r.trusted and rot < 1.0 and trans < 0.05, (rot, trans)


def _records(n: int, width: int, seed: int = 0) -> np.ndarray:
    """(n, width) float32 LiDAR-like records: points within 30 m, reflectance in [0, 1], a ring index last (5)."""
    rng = np.random.default_rng(seed)
    cols = [rng.normal(0, 10, (n, 3)), rng.random((n, 1))] + ([rng.integers(0, 32, (n, 1))] if width == 5 else [])
    return np.hstack(cols).astype("<f4")


@pytest.mark.parametrize("name, content, expect", [
    ("x.bin", bytes(100), "not a KITTI Velodyne file: 100 bytes is not a whole number of 16-byte records"),
    ("x.bin", np.full((50, 4), 5e4, "<f4").tobytes(), "50 of 50 points lie more than 1000 m from the sensor"),
    ("x.bin", _records(4000, 5).tobytes(), "looks like a nuScenes LiDAR sweep .* name it \\*.pcd.bin"),
    ("x.pcd.bin", _records(4000, 4).tobytes(), "not a nuScenes LiDAR sweep: its fifth float32"),
    ("x.pcd.bin", bytes(96), "not a nuScenes LiDAR file: 96 bytes is not a whole number of 20-byte records")])
def test_a_bin_file_that_is_no_lidar_frame_of_its_layout_is_one_message(tmp_path, name, content, expect):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(InputError, match=expect):
        load_scan(tmp_path / name)


def test_a_bin_frame_keeps_quiet_about_a_signalling_nan_and_drops_a_few_points_beyond_reach(tmp_path):
    records = _records(2000, 4)
    bits = records.view("<u4")
    bits[5, 3] = 0x7F800001  # a signalling NaN: casting it to float64 warns unless told not to
    records[:10, :3] = 2e4  # ten glitches 35 km out: dropped and said (1 % at most)
    (tmp_path / "x.bin").write_bytes(records.tobytes())
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scan = load_scan(tmp_path / "x.bin")
    assert len(scan.points) == 1990 and np.abs(scan.points).max() < 1000
    assert any("10 points more than 1000 m from the sensor dropped" in note for note in scan.notes)


def test_a_nuscenes_sweep_leaves_out_the_car_itself(tmp_path):
    records = _records(2000, 5)
    records[:30, :3] *= 0.5 / np.linalg.norm(records[:30, :3], axis=1, keepdims=True)  # returns 0.5 m out: the roof
    (tmp_path / "x.pcd.bin").write_bytes(records.tobytes())
    scan = load_scan(tmp_path / "x.pcd.bin")
    assert len(scan.points) == 1970 and np.linalg.norm(scan.points, axis=1).min() >= 1.0
    assert any("30 points within 1 m of the sensor (the car itself) dropped" in note for note in scan.notes)


def _pair_files(tmp_path):
    a, b = tmp_path / "a.ply", tmp_path / "b.xyz"
    write_ply(a, _cube_points(seed=1))
    b.write_text("\n".join(" ".join(f"{v:.6f}" for v in p) for p in _cube_points(seed=2)))
    return a, b


@pytest.mark.parametrize("side_by_side", [True, False])
def test_a_pair_reads_as_each_file_alone(tmp_path, monkeypatch, side_by_side):
    import rangereg.core.io as io

    a, b = _pair_files(tmp_path)
    if not side_by_side:  # files too large to read at once: one after the other
        monkeypatch.setattr(io, "PAIR_SIDE_BY_SIDE_BYTES", 0)
    vp = np.array([0.0, 0.0, 1.0])
    s, t = io.load_pair(a, b, target_viewpoint=vp)
    alone_s, alone_t = load_scan(a), load_scan(b, viewpoint=vp)
    for got, want in ((s, alone_s), (t, alone_t)):
        assert got.name == want.name and got.kind == want.kind and got.units == want.units
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.viewpoint, want.viewpoint)
    np.testing.assert_array_equal(t.viewpoint, vp)


def test_a_pair_with_two_bad_files_names_the_source_first(tmp_path):
    from rangereg.core.io import load_pair

    a, b = _pair_files(tmp_path)
    empty = tmp_path / "empty.ply"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="missing.ply"):
        load_pair(tmp_path / "missing.ply", empty)
    with pytest.raises(InputError, match="empty.ply: the file is empty"):
        load_pair(a, empty)
    with pytest.raises(InputError, match="empty.ply"):
        load_pair(empty, b)


def test_a_pair_whose_source_fails_says_so_without_waiting_for_the_targets_read(tmp_path, monkeypatch):
    import threading

    import rangereg.core.io as io

    a, b = _pair_files(tmp_path)
    release, done = threading.Event(), threading.Event()

    def slow(path, **kw):  # the target's read, as long as a large file's; the source cannot be read
        if str(path) == str(b):
            release.wait(10)
            done.set()
            return None
        raise InputError(f"{path}: cannot be read")

    monkeypatch.setattr(io, "load_scan", slow)
    try:
        with pytest.raises(InputError, match="a.ply: cannot be read"):
            io.load_pair(a, b)
        assert not done.is_set()  # the error came while the target was still being read
    finally:
        release.set()
