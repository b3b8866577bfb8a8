"""The files beside a scan (core.sidefiles): the JSON sidecar, a Stanford .conf, a transform file or text;
each one that is a folder, unreadable, or holds nonsense is one clear InputError."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.core.errors import InputError
from rangereg.core.io import load_conf, load_scan, parse_transform, read_transform
from rangereg.core.ply import write_ply
from rangereg.core.transforms import apply, invert

from tests.test_io import _cube_points, _refused


def test_conf_poses_bring_bun045_onto_bun000(bunny):
    a, b = bunny("bun000"), bunny("bun045")
    gaps, _ = a.tree.query(apply(invert(a.pose) @ b.pose, b.points))
    assert np.median(gaps) < 0.0005
    # The plain (non-conjugate) quaternion would not align them: the convention matters.
    poses = load_conf(a.source.replace("bun000.ply", "bun.conf"))
    assert set(poses) == {"bun000", "bun045", "bun090", "bun315"}


def test_read_transform_forms(tmp_path):
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    (tmp_path / "t.txt").write_text(" ".join(map(str, T.ravel())))
    (tmp_path / "t.json").write_text(json.dumps({"transform": T.tolist()}))
    (tmp_path / "c.txt").write_text(",".join(map(str, T.ravel())))
    for name in ("t.txt", "t.json", "c.txt"):
        np.testing.assert_allclose(read_transform(tmp_path / name), T)
    bad = T.copy()
    bad[0, 0] = 2
    (tmp_path / "bad.txt").write_text(" ".join(map(str, bad.ravel())))
    with pytest.raises(InputError, match="not rigid"):
        read_transform(tmp_path / "bad.txt")
    (tmp_path / "sing.txt").write_text(" ".join(["0"] * 15 + ["1"]))
    with pytest.raises(InputError, match="singular"):
        read_transform(tmp_path / "sing.txt")
    (tmp_path / "short.txt").write_text("1 2 3")
    with pytest.raises(InputError, match="16 numbers"):
        read_transform(tmp_path / "short.txt")


def test_malformed_conf(tmp_path):
    _refused(load_conf, tmp_path / "x.conf", "bmesh a.ply 0 0 0 0 0\n", "line 1")
    _refused(load_conf, tmp_path / "y.conf", "camera 0 0 0 0 0 0 1\n", "no 'bmesh'")
    _refused(load_conf, tmp_path / "n.conf", "bmesh a.ply nan 0 0 0 0 0 1\n", "line 1's translation .* not finite")
    _refused(load_conf, tmp_path / "z.conf", "bmesh a.ply 0 0 0 0 0 0 0\n", "line 1 has a zero or invalid quaternion")


def test_a_quaternion_too_large_to_square_is_a_direction_like_any_other(tmp_path, recwarn):
    from rangereg.core.transforms import quaternion_matrix
    from scipy.spatial.transform import Rotation

    # b: qz = qw = 1e300, a quarter turn about z, read with the conjugate (the bunny's convention): -90 degrees
    (tmp_path / "q.conf").write_text("bmesh a.ply 0 0 0 0 0 0 1e300\nbmesh b.ply 0 0 0 0 0 1e300 1e300\n")
    poses = load_conf(tmp_path / "q.conf")
    assert np.allclose(poses["a"], np.eye(4))
    assert np.allclose(poses["b"][:3, :3], Rotation.from_euler("z", -90, degrees=True).as_matrix())
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]  # no overflow on the way
    for q in ([0, 0, 0, 0], [0, 0, 0, 1e-12], [np.inf, 0, 0, 1], [np.nan, 0, 0, 1]):
        assert quaternion_matrix(np.array(q, dtype=float)) is None


@pytest.fixture
def unreadable(monkeypatch):
    """Make a file that cannot be read (as root, chmod 0 does not stop reading: refuse it where core.files opens)."""
    import rangereg.core.files

    refused = set()
    real = rangereg.core.files._open_fd

    def open_fd(path):
        if path in refused:
            raise PermissionError(13, "Permission denied", str(path))
        return real(path)

    monkeypatch.setattr(rangereg.core.files, "_open_fd", open_fd)

    def make(path):
        path.write_text("{}")
        path.chmod(0)
        refused.add(path)
        return path

    return make


@pytest.mark.parametrize("sidecar, match", [
    ({"viewpoint": "abc"}, "'viewpoint' should be three numbers x, y, z, found \"abc\""),
    ({"viewpoint": [0, 0]}, r"'viewpoint' should be three numbers x, y, z, found \[0, 0\]"),
    ({"viewpoint": [0, "nan", 0]}, "'viewpoint' .*not finite"),
    ({"viewpoint": [[0, 0, 1]]}, "'viewpoint' should be three numbers"),
    ({"pose": [[1, 2], [3, 4]]}, "'pose' must be a 4 x 4 matrix, got shape \\(2, 2\\)"),
    ({"pose": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}, "'pose' is not rigid"),
    ({"guess": "identity"}, "'guess' should be a 4 x 4 rigid transform"),
    ({"pose": [[1, 0, 0], [0, 1]]}, "'pose' should be a 4 x 4 rigid transform"),
    ({"units": 5}, "'units' should name a length unit .*found int"),
    ({"units": "furlongs"}, "'units' should name a length unit \\(\"um\", \"mm\", .*found 'furlongs'"),
    ({"units": ""}, "'units' should name a length unit"),
    ([1, 2, 3], "should hold a JSON object, found list"),
])
def test_sidecar_contents_are_checked(tmp_path, sidecar, match):
    write_ply(tmp_path / "s.ply", _cube_points())
    (tmp_path / "s.json").write_text(json.dumps(sidecar))
    with pytest.raises(InputError, match=match) as err:
        load_scan(tmp_path / "s.ply")
    assert "s.json" in str(err.value)


def test_nan_viewpoint_in_sidecar_text_is_refused(tmp_path):
    write_ply(tmp_path / "s.ply", _cube_points())
    (tmp_path / "s.json").write_text('{"viewpoint": [NaN, 0, 5]}')  # Python's json reads NaN
    with pytest.raises(InputError, match="not finite"):
        load_scan(tmp_path / "s.ply")


@pytest.mark.parametrize("spelled, name", [("Millimeters", "mm"), (" metres ", "m"), ("inches", "in"), ("µm", "um")])
def test_units_spelled_out_are_read_as_their_short_name(tmp_path, spelled, name):
    write_ply(tmp_path / "s.ply", _cube_points())
    (tmp_path / "s.json").write_text(json.dumps({"units": spelled}))
    assert load_scan(tmp_path / "s.ply").units == name
    assert load_scan(tmp_path / "s.ply", units=spelled.upper()).units == name  # the caller's word, too
    with pytest.raises(InputError, match="^units should name a length unit"):
        load_scan(tmp_path / "s.ply", units="parsecs")


def test_megametres_are_not_folded_to_millimetres(tmp_path):
    write_ply(tmp_path / "s.ply", _cube_points())
    (tmp_path / "s.json").write_text(json.dumps({"units": "Mm"}))
    with pytest.raises(InputError, match='"Mm" is megametres'):
        load_scan(tmp_path / "s.ply")
    (tmp_path / "s.json").write_text(json.dumps({"units": "MM"}))
    assert load_scan(tmp_path / "s.ply").units == "mm"  # upper case, as CAD files write it


def test_a_good_sidecar_still_sets_viewpoint_pose_and_units(tmp_path):
    write_ply(tmp_path / "s.ply", _cube_points())
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    (tmp_path / "s.json").write_text(json.dumps({"viewpoint": [0, 0, 5], "pose": T.tolist(), "units": "mm"}))
    s = load_scan(tmp_path / "s.ply")
    np.testing.assert_allclose(s.viewpoint, [0, 0, 5])
    np.testing.assert_allclose(s.pose, T)
    assert s.units == "mm" and not s.viewpoint_estimated and s.guess is None


def test_sidecar_that_is_a_folder_orunreadable(tmp_path, unreadable):
    write_ply(tmp_path / "s.ply", _cube_points())
    (tmp_path / "s.json").mkdir()
    with pytest.raises(InputError, match="s.json: is a folder, not a JSON sidecar"):
        load_scan(tmp_path / "s.ply")
    (tmp_path / "s.json").rmdir()
    unreadable(tmp_path / "s.json")
    with pytest.raises(InputError, match="s.json: cannot read a JSON sidecar"):
        load_scan(tmp_path / "s.ply")


def test_conf_that_is_a_folder_orunreadable(tmp_path, unreadable):
    (tmp_path / "d.conf").mkdir()
    with pytest.raises(InputError, match="is a folder, not a Stanford .conf file"):
        load_conf(tmp_path / "d.conf")
    # a folder named *.conf beside a scan is passed over when looking for its pose
    write_ply(tmp_path / "s.ply", _cube_points())
    assert load_scan(tmp_path / "s.ply").pose is None
    with pytest.raises(InputError, match="cannot read a Stanford .conf file"):
        load_conf(unreadable(tmp_path / "u.conf"))


def test_transform_file_that_is_a_folder_orunreadable(tmp_path, unreadable):
    (tmp_path / "t").mkdir()
    with pytest.raises(InputError, match="is a folder, not a transform file"):
        read_transform(tmp_path / "t")
    with pytest.raises(InputError, match="cannot read a transform file"):
        read_transform(unreadable(tmp_path / "u.txt"))
    with pytest.raises(InputError, match="no such file"):
        read_transform(tmp_path / "missing.txt")


def test_transform_from_the_text_of_16_numbers():
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    for text in (" ".join(map(str, T.ravel())), ",".join(map(str, T.ravel())), json.dumps(T.tolist()),
                 json.dumps({"transform": T.tolist()})):
        np.testing.assert_allclose(parse_transform(text), T)
        np.testing.assert_allclose(read_transform(text), T)  # callers of read_transform get it too
    with pytest.raises(InputError, match="expected 16 numbers .* found 3"):
        parse_transform("1 2 3")
    with pytest.raises(InputError, match="not rigid"):
        parse_transform(" ".join(["2"] + ["0"] * 4 + ["1"] + ["0"] * 4 + ["1"] + ["0"] * 4 + ["1"]))
    with pytest.raises(InputError, match="NaN or infinite"):
        parse_transform(" ".join(["nan"] + ["0"] * 14 + ["1"]))
