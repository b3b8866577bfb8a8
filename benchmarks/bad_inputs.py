"""The bad-input table: every case runs ``python -m app.cli ...`` as a real subprocess and must meet
the CLI's contract: exit status 2, exactly one line on stderr holding the expected fragment, no
traceback, no file in its folder created, changed or removed, within a time bound.

    python benchmarks/bad_inputs.py [--jobs 2] [--timeout 60] [-k FRAGMENT] [--list]

Prints each case that fails and "N of M meet the contract". The fixtures (corrupt, empty, lying
files, bad sidecars, side files) are written into a temporary folder; each case runs in its own copy
of it, so the check "nothing touched" sees only that case. The bundled corner scene is the valid
pair. tests/test_cli_contract.py runs a fast subset (``FAST``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
CORNER = ROOT / "assets" / "corner"
WING = ROOT / "assets" / "wing"


@dataclass(frozen=True)
class Case:
    name: str
    args: tuple[str, ...]
    expect: str  # a fragment of the one stderr line (case-insensitive)
    stdout_ok: bool = False  # a late write failure prints the result first


def C(name: str, cmdline: str | list[str], expect: str, stdout_ok: bool = False) -> Case:
    args = cmdline.split() if isinstance(cmdline, str) else cmdline
    return Case(name, tuple(args), expect, stdout_ok)


EYE = " ".join(map(str, np.eye(4).ravel()))
FAR = "1 0 0 100000000 0 1 0 0 0 0 1 0 0 0 0 1"  # 100 km off in the corner's millimetres: no overlap
R = "register src.ply tgt.ply"
S = "slice src.ply tgt.ply"

CASES: list[Case] = [
    # --- the command line itself
    C("no command", "", "required"),
    C("unknown command", "frobnicate", "invalid choice"),
    C("unknown flag", f"{R} --frobnicate", "unrecognized arguments"),
    C("register one scan", "register src.ply", "required"),
    C("register no scans", "register", "required"),
    C("register three scans", f"{R} extra.ply", "unrecognized arguments"),
    C("flag without value", f"{R} --method", "expected one argument"),
    C("method unknown", f"{R} --method magic", "invalid choice"),
    C("frustum unknown", f"{R} --frustum round", "invalid choice"),
    C("seed negative", f"{R} --seed -1", "--seed"),
    C("seed 1e30", f"{R} --seed 1e30", "whole number"),
    C("seed fraction", f"{R} --seed 1.5", "whole number"),
    C("seed words", f"{R} --seed abc", "whole number"),
    C("seed too large", f"{R} --seed 99999999999", "<= 4294967295"),
    C("seed empty", [*R.split(), "--seed", ""], "whole number"),
    C("max-points 2", f"{R} --max-points 2", ">= 3"),
    C("max-points 0", f"{R} --max-points 0", ">= 3"),
    C("max-points 1e9", f"{R} --max-points 1000000000", "<= 100000"),
    C("max-points words", f"{R} --max-points many", "whole number"),
    C("rotation negative", f"{R} --rotation-uncertainty -5", ">= 0.01"),
    C("rotation zero", f"{R} --rotation-uncertainty 0", ">= 0.01"),
    C("rotation 200", f"{R} --rotation-uncertainty 200", "<= 180"),
    C("rotation nan", f"{R} --rotation-uncertainty nan", "finite"),
    C("rotation inf", f"{R} --rotation-uncertainty inf", "finite"),
    C("translation negative", f"{R} --translation-uncertainty -1", "> 0"),
    C("translation zero", f"{R} --translation-uncertainty 0", "> 0"),
    C("translation inf", f"{R} --translation-uncertainty inf", "finite"),
    C("threshold negative", f"{R} --threshold -3", ">= 0"),
    C("threshold words", f"{R} --threshold abc", "expected a number"),
    C("threshold nan", f"{R} --threshold nan", "finite"),
    C("threshold -inf", f"{R} --threshold=-inf", "finite"),
    C("hops negative", f"{R} --hops -1", ">= 0"),
    C("hops huge", f"{R} --hops 1000000000", "<= 100000"),
    C("recut rounds 0", f"{R} --recut-rounds 0", ">= 1"),
    C("recut rounds 100", f"{R} --recut-rounds 100", "<= 20"),
    C("viewpoint two numbers", f"{R} --viewpoint-source 1,2", "x,y,z"),
    C("viewpoint words", f"{R} --viewpoint-target a,b,c", "x,y,z"),
    C("viewpoint nan", f"{R} --viewpoint-source nan,0,0", "finite"),
    C("viewpoint on the points", f"{R} --viewpoint-source 0,0,-1000000", "viewpoint"),
    # --- --init: 16 numbers inline or a file
    C("init 15 numbers", [*R.split(), "--init", " ".join(["1"] * 15)], "16 numbers"),
    C("init not rigid inline", [*R.split(), "--init", EYE.replace("1.0", "2.0", 1)], "not rigid"),
    C("init nan inline", [*R.split(), "--init", "nan " + EYE.split(" ", 1)[1]], "NaN"),
    C("init last row", [*R.split(), "--init", EYE[:-3] + "2.0"], "last row"),
    C("init words", [*R.split(), "--init", "turn left a bit"], "not 16 numbers"),
    C("init missing file", f"{R} --init nope.txt", "no such file"),
    C("init a folder", f"{R} --init folder.ply", "folder"),
    C("init empty file", f"{R} --init empty.xyz", "16 numbers"),
    C("init binary file", f"{R} --init binary.bin", "not a text file"),
    C("init json without transform", f"{R} --init notransform.json", "transform"),
    C("init not rigid file", f"{R} --init shear.txt", "not rigid"),
    C("init 3x3 json", f"{R} --init t3x3.json", "16 numbers"),
    # --- output paths, checked before the work
    C("out wrong suffix", f"{R} --out result.txt", "suffix"),
    C("out onto a scan", f"{R} --out src.ply", "suffix"),
    C("out onto the init file", f"{R} --init eye.json --out eye.json", "input file"),
    C("out onto a sidecar", f"{R} --out src.json", "sidecar"),
    C("out a folder", f"{R} --out folder.ply", "folder"),
    C("out missing folder", f"{R} --out nowhere/t.json", "does not exist"),
    C("out under a file", f"{R} --out src.ply/t.json", "not a folder"),
    C("out unwritable folder", f"{R} --out /proc/t.json", "cannot write in"),  # refuses even root
    C("trace unwritable folder", f"{R} --trace /sys/run.jsonl", "cannot write in"),
    C("out empty", [*R.split(), "--out", ""], "file name"),
    C("trace wrong suffix", f"{R} --trace run.png", "suffix"),
    C("trace a folder", f"{R} --trace folder.ply", "folder"),
    C("trace missing folder", f"{R} --trace nowhere/run.jsonl", "does not exist"),
    C("trace same as out", f"{R} --trace same.json --out same.json", "same file"),
    C("trace kept on bad seed", f"{R} --trace keep.jsonl --seed -1", "--seed"),
    C("trace kept when the run fails", [*R.split(), "--init", FAR, "--trace", "keep.jsonl"], "do not overlap"),
    C("out /dev/full after the run", f"{R} --method icp --out /dev/full", "No space left", stdout_ok=True),
    C("trace /dev/full after the run", f"{R} --method icp --trace /dev/full --json", "No space left", stdout_ok=True),
    # --- scan files
    C("scan missing", "register nope.ply tgt.ply", "no such file"),
    C("scan a folder", "register folder.ply tgt.ply", "folder"),
    C("scan empty ply", "info empty.ply", "empty"),
    C("scan empty xyz", "info empty.xyz", "empty"),
    C("scan unsupported suffix", "info scan.foo", "unsupported format"),
    C("scan no suffix", "info noext", "unsupported format"),
    C("ply text garbage", "info garbage.ply", "garbage.ply"),
    C("ply random bytes", "info random.ply", "random.ply"),
    C("ply truncated binary", "info truncated.ply", "truncated.ply"),
    C("ply no end_header", "info noend.ply", "noend.ply"),
    C("ply unknown format", "info badformat.ply", "format"),
    C("ply unknown type", "info badtype.ply", "type"),
    C("ply no vertex element", "info novertex.ply", "vertex"),
    C("ply no xyz", "info noxyz.ply", "x, y, z"),
    C("ply lying count 50", "info lying50.ply", "lying50.ply"),
    C("ply negative count", "info negative.ply", "negative.ply"),
    C("ply count too large", "info toolarge.ply", "toolarge.ply"),
    C("ply words in data", "info words.ply", "words.ply"),
    C("ply face beyond vertices", "info badface.ply", "face"),
    C("xyz words", "info words.xyz", "line 3"),
    C("xyz two columns", "info twocol.xyz", "2 numbers"),
    C("xyz not utf-8", "info latin.xyz", "latin.xyz"),
    C("xyz all nan", "info nan.xyz", "usable points"),
    C("xyz two points", "info two.xyz", "usable points"),
    C("xyz collinear", "info line.xyz", "on a line"),
    C("xyz one spot", "info spot.xyz", "on a line"),
    C("pcd no data line", "info nodata.pcd", "DATA"),
    C("pcd no xyz fields", "info nofields.pcd", "x y z"),
    C("pcd unknown mode", "info badmode.pcd", "mode"),
    C("pcd short data", "info short.pcd", "short.pcd"),
    C("obj garbage", "info garbage.obj", "garbage.obj"),
    C("obj no vertices", "info novert.obj", "novert.obj"),
    C("stl garbage", "info garbage.stl", "garbage.stl"),
    C("off garbage", "info garbage.off", "garbage.off"),
    C("info two scans", "info src.ply tgt.ply", "unrecognized arguments"),
    C("info viewpoint short", "info src.ply --viewpoint 1,2", "x,y,z"),
    C("info viewpoint inf", "info src.ply --viewpoint inf,0,0", "finite"),
    # --- sidecars (scan.json beside scan.ply)
    C("sidecar not json", "info side_broken.ply", "sidecar"),
    C("sidecar viewpoint words", "info side_vp_abc.ply", "viewpoint"),
    C("sidecar viewpoint 2 numbers", "info side_vp_2.ply", "viewpoint"),
    C("sidecar viewpoint nan", "info side_vp_nan.ply", "viewpoint"),
    C("sidecar pose 2x2", "register side_pose.ply tgt.ply", "pose"),
    C("sidecar pose not rigid", "register side_shear.ply tgt.ply", "pose"),
    C("sidecar guess words", "register side_guess.ply tgt.ply", "guess"),
    C("sidecar units number", "info side_units.ply", "units"),
    C("sidecar a folder", "info side_dir.ply", "side_dir.json"),
    C("sidecar not an object", "info side_list.ply", "sidecar"),
    # --- geometry
    C("flat scans", "register flat.xyz flat2.xyz", "flat"),
    C("no overlap", [*R.split(), "--init", FAR], "do not overlap"),
    C("nan scan register", "register nan.xyz tgt.ply", "usable points"),
    C("collinear register", "register src.ply line.xyz", "on a line"),
    # --- slice
    C("slice no png", S, "--png"),
    C("slice steps 1", f"{S} --png s.png --steps 1", ">= 2"),
    C("slice steps 1000000", f"{S} --png s.png --steps 1000000", "<= 201"),
    C("slice steps words", f"{S} --png s.png --steps ten", "whole number"),
    C("slice params unknown", f"{S} --png s.png --params tx,qq", "--params"),
    C("slice params one", f"{S} --png s.png --params tx", "--params"),
    C("slice params same", f"{S} --png s.png --params tx,tx", "--params"),
    C("slice span one", f"{S} --png s.png --span 1", "--span"),
    C("slice span words", f"{S} --png s.png --span a,b", "--span"),
    C("slice span negative", f"{S} --png s.png --span=-1,2", "--span"),
    C("slice span nan", f"{S} --png s.png --span nan,1", "--span"),
    C("slice png suffix", f"{S} --png s.foo", "suffix"),
    C("slice png folder", f"{S} --png folder.ply", "folder"),
    C("slice png missing folder", f"{S} --png nowhere/s.png", "does not exist"),
    C("slice png kept on bad steps", f"{S} --png keep.png --steps 0", ">= 2"),
    C("slice png /dev/full after the work", f"{S} --png /dev/full --steps 5", "No space left", stdout_ok=True),
    C("slice npz suffix", f"{S} --png s.png --npz s.png", "suffix"),
    C("slice center choice", f"{S} --png s.png --center middle", "invalid choice"),
    C("slice center end without trace", f"{S} --png s.png --center end", "--trace"),
    C("slice trace missing", f"{S} --png s.png --trace nope.jsonl", "no such file"),
    C("slice trace folder", f"{S} --png s.png --trace folder.ply", "folder"),
    C("slice trace binary", f"{S} --png s.png --trace binary.bin", "not a text file"),
    C("slice trace not json", f"{S} --png s.png --trace words.xyz", "not a rangereg trace"),
    C("slice trace json not events", f"{S} --png s.png --trace notransform.json", "not a rangereg trace"),
    C("slice trace empty", f"{S} --png s.png --trace empty.xyz", "no events"),
    C("slice trace bad transform", f"{S} --png s.png --trace badevent.jsonl", "line 2"),
    C("slice trace of another pair", f"{S} --png s.png --trace trace_other.jsonl", "recorded on other scans"),
    C("slice trace of the pair swapped", f"{S} --png s.png --trace trace_swapped.jsonl", "other way round"),
    C("slice trace of an edited scan", f"{S} --png s.png --trace trace_edited.jsonl", "its target is tgt"),
    C("slice trace newer format", f"{S} --png s.png --trace trace_newer.jsonl", "newer rangereg"),
    C("slice trace not json lines", f"{S} --png s.png --trace trace_text.jsonl", "line 1 is not JSON"),
    C("slice trace two headers", f"{S} --png s.png --trace trace_twoheaders.jsonl", "first line only"),
    C("slice trace event after its result", f"{S} --png s.png --trace trace_after_result.jsonl", "nothing may follow"),
    # --- merge
    C("merge one scan", "merge src.ply", "at least two"),
    C("merge seed negative", "merge src.ply tgt.ply --seed -1", "--seed"),
    C("merge scan missing", "merge src.ply nope.ply", "no such file"),
    C("merge init missing", "merge src.ply tgt.ply --init nope.conf", "no such file"),
    C("merge init folder", "merge src.ply tgt.ply --init folder.ply", "folder"),
    C("merge init binary", "merge src.ply tgt.ply --init binary.bin", "not a text file"),
    C("merge init not a conf", "merge src.ply tgt.ply --init words.xyz", "bmesh"),
    C("merge init bad line", "merge src.ply tgt.ply --init badline.conf", "line 1"),
    C("merge init lacks a scan", "merge src.ply tgt.ply --init other.conf", "no pose"),
    C("merge truth folder", "merge src.ply tgt.ply --truth folder.ply", "folder"),
    C("merge out suffix", "merge src.ply tgt.ply --out model.obj", "suffix"),
    C("merge out onto a scan", "merge src.ply tgt.ply --out src.ply", "input file"),
    C("merge out folder", "merge src.ply tgt.ply --out folder.ply", "folder"),
    C("merge out missing folder", "merge src.ply tgt.ply --out nowhere/m.ply", "does not exist"),
    C("merge same names", "merge a/s.ply b/s.ply", "share a name"),
    C("merge no overlap", "merge src.ply far.xyz", "overlap"),
    # --- serve (each fails before the server starts)
    C("serve port 99999", "serve --port 99999", "<= 65535"),
    C("serve port 0", "serve --port 0", ">= 1"),
    C("serve port words", "serve --port http", "whole number"),
    C("serve scene unknown", "serve --scene moon", "invalid choice"),
    C("serve upload cap 0", "serve --upload-cap-mb 0", "> 0"),
    C("serve upload cap nan", "serve --upload-cap-mb nan", "finite"),
    C("serve one scan", "serve src.ply", "two scans"),
    C("serve scans missing", "serve nope.ply tgt.ply", "no such file"),
    C("serve data dir missing", "serve --data-dir nowhere", "no such folder"),
    C("serve host empty", ["serve", "--host", ""], "--host"),
    C("serve trace of another pair", "serve src.ply tgt.ply --trace trace_other.jsonl", "recorded on other scans"),
    C("serve trace not json lines", "serve src.ply tgt.ply --trace trace_text.jsonl", "not a rangereg trace"),
    # --- bench and scenes
    C("bench runs 0", "bench --runs 0", ">= 1"),
    C("bench runs words", "bench --runs some", "whole number"),
    C("bench runs huge", "bench --runs 1000000", "<= 1000"),
    C("bench json suffix", "bench --quick --json rows.txt", "suffix"),
    C("bench json folder", "bench --quick --json folder.ply", "folder"),
    C("bench json missing folder", "bench --quick --json nowhere/r.json", "does not exist"),
    C("scenes seed negative", "scenes --seed -1", "--seed"),
    C("scenes out a file", "scenes --out src.ply", "is a file"),
    C("scenes out missing parent", "scenes --out nowhere/deeper", "does not exist"),
]

# A quick, varied subset for the test suite (each case a subprocess of about 2 s).
FAST = ("seed 1e30", "init not rigid inline", "out onto a sidecar", "trace kept on bad seed", "scan empty ply",
        "slice trace folder", "merge out onto a scan", "serve port 99999")


def write_fixtures(folder: Path) -> None:
    """Every bad file the table reads, beside a copy of the corner pair (src.ply, tgt.ply + sidecars)."""
    f = Path(folder)
    for name, src in (("src", "scan2"), ("tgt", "scan1")):
        shutil.copy(CORNER / f"{src}.ply", f / f"{name}.ply")
        shutil.copy(CORNER / f"{src}.json", f / f"{name}.json")
    for sub in ("a", "b"):
        (f / sub).mkdir()
        shutil.copy(CORNER / "scan1.ply", f / sub / "s.ply")
    (f / "folder.ply").mkdir()
    (f / "empty.ply").write_bytes(b"")
    (f / "empty.xyz").write_bytes(b"")
    (f / "scan.foo").write_text("1 2 3\n")
    (f / "noext").write_text("1 2 3\n")
    (f / "binary.bin").write_bytes(bytes(range(256)) * 4)
    (f / "garbage.ply").write_text("hello, this is not a scan\n")
    (f / "random.ply").write_bytes(np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    rng = np.random.default_rng(1)
    u, v = np.meshgrid(np.linspace(-1, 1, 60), np.linspace(-1, 1, 60))
    bowl = np.c_[u.ravel(), v.ravel(), (u**2 + v**2).ravel() - 5.0]
    rows = "\n".join(f"{x:.5f} {y:.5f} {z:.5f}" for x, y, z in bowl) + "\n"

    def ply(count, props="property float x\nproperty float y\nproperty float z\n", body=rows, fmt="ascii 1.0", extra=""):
        return f"ply\nformat {fmt}\nelement vertex {count}\n{props}{extra}end_header\n{body}"

    (f / "lying50.ply").write_text(ply(50))
    (f / "negative.ply").write_text(ply(-5))
    (f / "toolarge.ply").write_text(ply(10_000))
    (f / "words.ply").write_text(ply(3600, body=rows.replace("0.", "zero ", 3)))
    (f / "noend.ply").write_text(ply(3600).replace("end_header\n", ""))
    (f / "badformat.ply").write_text(ply(3600, fmt="binary_middle_endian 1.0"))
    (f / "badtype.ply").write_text(ply(3600, props="property float128 x\nproperty float y\nproperty float z\n"))
    (f / "noxyz.ply").write_text(ply(3600, props="property float a\nproperty float b\nproperty float c\n"))
    (f / "novertex.ply").write_text("ply\nformat ascii 1.0\nelement point 3\nproperty float x\nend_header\n1\n2\n3\n")
    (f / "badface.ply").write_text(ply(3600, extra="element face 1\nproperty list uchar int vertex_indices\n",
                                       body=rows + "3 0 1 99999\n"))
    header = "ply\nformat binary_little_endian 1.0\nelement vertex 1000\nproperty float x\nproperty float y\n" \
             "property float z\nend_header\n"
    (f / "truncated.ply").write_bytes(header.encode() + np.zeros(30, np.float32).tobytes())
    (f / "words.xyz").write_text("1 2 3\n4 5 6\nseven eight nine\n")
    (f / "twocol.xyz").write_text("1 2\n3 4\n5 6\n")
    (f / "latin.xyz").write_bytes("1 2 3\n# caf\xe9\n4 5 6\n".encode("latin-1"))
    (f / "nan.xyz").write_text("nan nan nan\n" * 10)
    (f / "two.xyz").write_text("0 0 0\n1 1 1\n")
    (f / "line.xyz").write_text("".join(f"{t} {2 * t} {3 * t}\n" for t in range(50)))
    (f / "spot.xyz").write_text("1 1 1\n" * 20)
    plane = np.c_[u.ravel(), v.ravel(), np.full(u.size, -5.0)]
    (f / "flat.xyz").write_text("\n".join(f"{x} {y} {z}" for x, y, z in plane) + "\n")
    (f / "flat2.xyz").write_text("\n".join(f"{x} {y} {z}" for x, y, z in plane + rng.normal(0, 1e-3, plane.shape)) + "\n")
    (f / "far.xyz").write_text("\n".join(f"{x + 1e7} {y} {z - 1e7}" for x, y, z in bowl * 500) + "\n")
    pcd = "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 5\nHEIGHT 1\nPOINTS 5\n"
    (f / "nodata.pcd").write_text(pcd + "0 0 0\n")
    (f / "nofields.pcd").write_text(pcd.replace("FIELDS x y z", "FIELDS a b c") + "DATA ascii\n0 0 0\n")
    (f / "badmode.pcd").write_text(pcd + "DATA zipped\n0 0 0\n")
    (f / "short.pcd").write_text(pcd + "DATA ascii\n0 0 0\n1 1 1\n")
    for ext in ("obj", "stl", "off"):
        (f / f"garbage.{ext}").write_bytes(b"\x00\x01garbage\xff" * 20)
    (f / "novert.obj").write_text("# nothing here\n")
    (f / "eye.json").write_text(json.dumps({"transform": np.eye(4).tolist()}))
    (f / "notransform.json").write_text(json.dumps({"pose": [1, 2, 3]}) + "\n")
    (f / "t3x3.json").write_text(json.dumps({"transform": np.eye(3).tolist()}))
    shear = np.eye(4)
    shear[0, 1] = 0.5
    (f / "shear.txt").write_text(" ".join(map(str, shear.ravel())))
    event = {"phase": "icp", "iteration": 1, "phase_iteration": 1, "leg": 1, "transform": np.eye(4).tolist(), "error": 1.0}
    (f / "badevent.jsonl").write_text(json.dumps(event) + "\n" + json.dumps({**event, "transform": shear.tolist()}) + "\n")
    write_trace_fixtures(f, json.dumps(event) + "\n")
    (f / "badline.conf").write_text("bmesh src.ply 1 2 3\n")
    (f / "other.conf").write_text("bmesh elsewhere.ply 0 0 0 0 0 0 1\nbmesh another.ply 0 0 0 0 0 0 1\n")
    (f / "keep.jsonl").write_text('{"kept": true}\n')
    (f / "keep.png").write_bytes(b"an existing picture that a failed run must keep")
    sidecars = {"side_broken": "{not json", "side_vp_abc": {"viewpoint": "abc"}, "side_vp_2": {"viewpoint": [0, 0]},
                "side_vp_nan": '{"viewpoint": [NaN, 0, 0]}', "side_pose": {"pose": [[1, 2], [3, 4]]},
                "side_shear": {"pose": shear.tolist()}, "side_guess": {"guess": "near"}, "side_units": {"units": 5},
                "side_list": [1, 2, 3]}
    for name, content in sidecars.items():
        shutil.copy(CORNER / "scan2.ply", f / f"{name}.ply")
        (f / f"{name}.json").write_text(content if isinstance(content, str) else json.dumps(content))
    shutil.copy(CORNER / "scan2.ply", f / "side_dir.ply")
    (f / "side_dir.json").mkdir()


def write_trace_fixtures(f: Path, event: str) -> None:
    """Traces (a header line, then ``event``) that do not match the pair src.ply -> tgt.ply, or are not traces."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from core.config import Config
    from core.events import TraceHeader
    from core.io import load_scan

    src, tgt = load_scan(f / "src.ply"), load_scan(f / "tgt.ply")
    wing = [load_scan(WING / f"{n}.ply") for n in ("scan2", "scan1")]
    header = TraceHeader.of(src, tgt, np.eye(4), Config()).to_json()

    def trace(head: dict) -> str:
        return json.dumps(head) + "\n" + event

    (f / "trace_other.jsonl").write_text(trace(TraceHeader.of(*wing, np.eye(4), Config()).to_json()))
    (f / "trace_swapped.jsonl").write_text(trace(TraceHeader.of(tgt, src, np.eye(4), Config()).to_json()))
    edited = json.loads(json.dumps(header))
    edited["header"]["target"]["sha256"] = "0" * 64  # same point count, other points
    (f / "trace_edited.jsonl").write_text(trace(edited))
    newer = json.loads(json.dumps(header))
    newer["header"]["format_version"] = 99
    (f / "trace_newer.jsonl").write_text(trace(newer))
    (f / "trace_text.jsonl").write_text("this is a note, not JSON lines\n")
    (f / "trace_twoheaders.jsonl").write_text(trace(header) + json.dumps(header) + "\n")
    result = json.dumps({"result": {"transform": np.eye(4).tolist(), "error": 1.0}}) + "\n"
    (f / "trace_after_result.jsonl").write_text(trace(header) + result + event)


def snapshot(folder: Path) -> dict[str, tuple[int, int]]:
    """Every file and folder under ``folder`` -> (size, mtime in ns)."""
    out = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = Path(root) / name
            st = p.lstat()
            out[str(p.relative_to(folder))] = (st.st_size if p.is_file() else 0, st.st_mtime_ns)
    return out


def run_case(case: Case, fixtures: Path, timeout: float = 60.0) -> tuple[str | None, float]:
    """(None if the case meets the contract else why not, seconds)."""
    with tempfile.TemporaryDirectory(prefix="badin-") as tmp:
        work = Path(tmp) / "w"
        shutil.copytree(fixtures, work, symlinks=True)
        before = snapshot(work)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        t0 = time.perf_counter()
        try:
            r = subprocess.run([sys.executable, "-m", "app.cli", *case.args], cwd=work, env=env, capture_output=True,
                               text=True, timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            return f"took longer than {timeout:g} s", time.perf_counter() - t0
        seconds = time.perf_counter() - t0
        lines = r.stderr.strip().splitlines()
        problems = []
        if r.returncode != 2:
            problems.append(f"exit {r.returncode}")
        if "Traceback" in r.stderr:
            problems.append("a traceback")
        if len(lines) != 1:
            problems.append(f"{len(lines)} stderr lines")
        elif case.expect.lower() not in lines[0].lower():
            problems.append(f"no {case.expect!r} in the message")
        if r.stdout.strip() and not case.stdout_ok:
            problems.append("output on stdout")
        after = snapshot(work)
        touched = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
        if touched:
            problems.append(f"files touched: {', '.join(touched)}")
        if problems:
            shown = " | ".join(lines[-3:]) if lines else "(no stderr)"
            return f"{'; '.join(problems)} -- stderr: {shown[:300]}", seconds
        return None, seconds


def run_table(cases: list[Case], jobs: int = 2, timeout: float = 60.0, say=print) -> int:
    """Run ``cases``; print each failing one and the tally. Returns the number that failed."""
    names = [c.name for c in cases]
    assert len(set(names)) == len(names), "case names must be distinct"
    with tempfile.TemporaryDirectory(prefix="badin-fixtures-") as tmp:
        fixtures = Path(tmp)
        write_fixtures(fixtures)
        t0 = time.perf_counter()
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            results = list(pool.map(lambda c: run_case(c, fixtures, timeout), cases))
    failed = 0
    for case, (problem, seconds) in zip(cases, results):
        if problem is not None:
            failed += 1
            say(f"FAIL  {case.name}  [rangereg {' '.join(case.args)}]  ({seconds:.1f} s): {problem}")
    slowest = max(zip((s for _, s in results), names))
    say(f"{len(cases) - failed} of {len(cases)} meet the contract (exit 2, one stderr line with the expected "
        f"message, no traceback, no file touched, under {timeout:g} s); {time.perf_counter() - t0:.0f} s with "
        f"{jobs} jobs, slowest case {slowest[0]:.1f} s ({slowest[1]})")
    return failed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2)")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per case (default 60)")
    ap.add_argument("-k", dest="only", help="only cases whose name holds this")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    a = ap.parse_args(argv)
    cases = [c for c in CASES if not a.only or a.only in c.name]
    if a.list:
        for c in cases:
            print(f"{c.name:36s} rangereg {' '.join(c.args)}  ->  {c.expect}")
        return 0
    return 1 if run_table(cases, a.jobs, a.timeout) else 0


if __name__ == "__main__":
    raise SystemExit(main())
