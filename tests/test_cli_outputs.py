"""rangereg.app.outputs: output paths checked before the work, atomic writes, a trace put in place only at the end."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
from rangereg.app.outputs import TraceFile, check_distinct, check_output, check_output_folder, write_output, write_outputs
from rangereg.core.errors import InputError


@pytest.mark.parametrize("name, suffixes, fragment", [
    ("missing/x.json", (".json",), "does not exist"),
    (".", (), "is a folder"),
    ("x.foo", (".png",), "unknown suffix '.foo'"),
    ("x", (".png",), "unknown suffix '(none)'"),
    ("scan.ply", (), "is an input file"),
    ("scan.json", (".json",), "sidecar of the input scan"),
    ("scan.ply/x.json", (".json",), "is not a folder"),
    ("", (), "got nothing"),
])
def test_a_bad_output_is_refused_before_the_work(tmp_path, monkeypatch, name, suffixes, fragment):
    monkeypatch.chdir(tmp_path)
    Path("scan.ply").write_text("ply")
    with pytest.raises(InputError, match=re.escape(fragment)):
        check_output(name, "--out", suffixes, scans=["scan.ply"])
    assert sorted(os.listdir(tmp_path)) == ["scan.ply"]


def test_an_unwritable_folder_is_refused(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        if os.access(ro, os.W_OK) and os.geteuid() == 0:
            pytest.skip("root writes into a read-only folder")
        with pytest.raises(InputError, match="cannot write in"):
            check_output(ro / "x.json", "--out")
    finally:
        ro.chmod(0o700)


def test_devices_pass_without_a_suffix():
    assert check_output("/dev/null", "--png", (".png",)) == Path("/dev/null")


def test_two_flags_writing_one_file_are_refused(tmp_path):
    with pytest.raises(InputError, match="--out writes the same file"):
        check_distinct({"--out": tmp_path / "a.json", "--trace": tmp_path / "a.json"})
    check_distinct({"--out": tmp_path / "a.json", "--trace": None, "--png": Path("/dev/null")})


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "T.json"
    target.write_text("old")

    def half_then_fail(p: Path):
        p.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(InputError, match="--out .*T.json: cannot write it \\(No space left on device\\)"):
        write_output(target, "--out", half_then_fail)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["T.json"]


def test_a_write_replaces_atomically_and_keeps_the_mode(tmp_path):
    target = tmp_path / "T.json"
    target.write_text("old")
    target.chmod(0o640)
    write_output(target, "--out", lambda p: p.write_text("new"))
    assert target.read_text() == "new" and (target.stat().st_mode & 0o777) == 0o640
    assert os.listdir(tmp_path) == ["T.json"]


def test_a_symlinked_output_stays_a_link(tmp_path):
    real = tmp_path / "real.json"
    real.write_text("old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    write_output(link, "--out", lambda p: p.write_text("new"))
    assert link.is_symlink() and real.read_text() == "new"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs named pipes")
def test_a_pipe_or_a_device_gets_a_plain_write_and_stays_what_it_is(tmp_path, monkeypatch):
    import stat
    import tempfile
    import threading

    spare = tmp_path / "tmp"  # where the temporary copy is made (no folder of its own beside a device)
    spare.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spare))
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()))
    reader.start()
    write_output(fifo, "--out", lambda p: p.write_text("the result"))
    reader.join(10)
    assert got == [b"the result"]  # written through the pipe ...
    assert stat.S_ISFIFO(fifo.stat().st_mode)  # ... not replaced by a regular file (an atomic rename would)
    write_output(Path("/dev/null"), "--out", lambda p: p.write_text("x"))
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert os.listdir(spare) == []  # the temporary copies are gone


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_every_output_is_tried_and_one_message_names_those_that_failed(tmp_path):
    ok = tmp_path / "ok.json"
    with pytest.raises(InputError) as e:
        write_outputs([(Path("/dev/full"), "--png", lambda p: p.write_text("x" * 10)),
                       (ok, "--out", lambda p: p.write_text("fine")), (None, "--npz", None)])
    assert ok.read_text() == "fine" and "\n" not in str(e.value) and str(e.value).startswith("--png /dev/full")


def test_a_trace_appears_only_when_committed(tmp_path):
    target = tmp_path / "run.jsonl"
    target.write_text("earlier\n")
    t = TraceFile(target)
    t.write('{"a": 1}')
    assert target.read_text() == "earlier\n"
    t.discard()
    assert target.read_text() == "earlier\n" and os.listdir(tmp_path) == ["run.jsonl"]
    t = TraceFile(target)
    t.write('{"a": 1}')
    t.commit()
    assert target.read_text() == '{"a": 1}\n' and os.listdir(tmp_path) == ["run.jsonl"]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_trace_onto_a_full_device_fails_at_commit():
    t = TraceFile(Path("/dev/full"))
    t.write("{}")
    with pytest.raises(InputError, match="--trace /dev/full: cannot write it"):
        t.commit()


def test_an_output_folder(tmp_path):
    assert check_output_folder(tmp_path / "new", "--out") == tmp_path / "new"
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        check_output_folder(tmp_path / "f", "--out")
    with pytest.raises(InputError, match="does not exist"):
        check_output_folder(tmp_path / "a" / "b", "--out")
