"""The bad-input table: every case runs ``python -m rangereg.app.cli ...`` as a real subprocess and must meet
the CLI's contract: exit status 2 (or 128 + the signal for a signal sent to it, or 0 for an input that
must be accepted: a pipe given as --init, a .conf beside a scan that is not a regular file), exactly
one line on stderr holding the expected fragment (none for an accepted input unless it warns), no
traceback, no file in its folder created, changed or removed, and within a time bound (10 s; for a
signal, from the signal to the exit).

    python benchmarks/bad_inputs.py [--jobs 2] [--timeout 60] [--bound 10] [-k FRAGMENT] [--only N]
                                    [--smallest] [--list]

Prints each case that fails and "N of M meet the contract". ``--only N`` runs N cases spread evenly over
the table, ``--smallest`` two of the fast subset tests/test_cli_contract.py runs (``FAST``). The fixtures
(corrupt, empty, lying files, bad sidecars, side files) are written into a temporary folder; each case
runs in its own copy of it, where the special files (FIFOs, links to devices, link loops, sockets,
50 GB sparse files) are then made, so the check "nothing touched" sees only that case. The bundled
corner scene is the valid pair.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
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
    expect: str  # a fragment of the one stderr line (case-insensitive); "" with status 0: stderr stays empty
    stdout_ok: bool = False  # a late write failure prints the result first; an accepted input prints its result
    status: int = 2  # the exit status the contract asks for
    signal: int | None = None  # sent once ``when`` holds (Ctrl-C: to the process group, as a terminal does)
    when: tuple = ("delay", 0.0)  # ("delay", s) | ("file", glob in its folder) | ("children", n[, s after])
    pipe: bytes | None = None  # fed through an anonymous pipe named by "{pipe}" in args (as <(...) does)
    stdout_closed: bool = False  # run as `rangereg ... >&-`
    bound: float | None = None  # seconds it may take, when not the table's: an accepted input, or a write that
    # fails only after the work (/dev/full), runs the whole registration or slice first
    writes: tuple[str, ...] = ()  # files it may create: a merge that places some scans writes their model


def C(name: str, cmdline: str | list[str], expect: str, stdout_ok: bool = False, **kw) -> Case:
    args = cmdline.split() if isinstance(cmdline, str) else cmdline
    return Case(name, tuple(args), expect, stdout_ok, **kw)


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


_FREE_PORTS = (_free_port(), _free_port())
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
    C("out /dev/full after the run", f"{R} --method icp --out /dev/full", "No space left", stdout_ok=True, bound=30.0),
    C("trace /dev/full after the run", f"{R} --method icp --trace /dev/full --json", "No space left", stdout_ok=True, bound=30.0),
    # --- scan files
    C("scan missing", "register nope.ply tgt.ply", "no such file"),
    C("scan a folder", "register folder.ply tgt.ply", "folder"),
    C("scan empty ply", "info empty.ply", "empty"),
    C("scan empty xyz", "info empty.xyz", "empty"),
    C("scan unsupported suffix", "info scan.foo", "unsupported format"),
    C("scan no suffix", "info noext", "unsupported format"),
    C("bin not whole records", "info cut.bin", "not a whole number of 16-byte records"),
    C("bin bytes of another kind", "info binary.bin", "not a KITTI Velodyne file"),
    C("bin nuscenes not whole records", "register cut.pcd.bin tgt.ply", "not a whole number of 20-byte records"),
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
    # info describes several files in turn (e4b3f0e); one it cannot read gets its one line, the rest are described
    C("info two scans", "info src.ply tgt.ply", "", status=0, stdout_ok=True),
    C("info a missing scan among two", "info src.ply nope.ply", "no such file", stdout_ok=True),
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
    C("sidecar units unknown word", "info side_furlongs.ply", "should name a length unit"),
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
    C("slice png /dev/full after the work", f"{S} --png /dev/full --steps 5", "No space left", stdout_ok=True, bound=30.0),
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
    C("merge one file twice", "merge src.ply src.ply", "the same file"),
    # no poses: no guess, so no overlap can be refused up front; the far scan is registered over every pose,
    # nothing is trusted, and it is reported not placed (status 3; the model holds the placed scan)
    C("merge no overlap", "merge src.ply far.xyz --json", "not placed", stdout_ok=True, status=3,
      writes=("model.ply",), bound=30.0),
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

# ---- second round: special files, sparse and huge inputs, header faults, numbers, tiny scans, signals -----
SIGINT, SIGTERM, SIGHUP = signal.SIGINT, signal.SIGTERM, signal.SIGHUP
SPECIAL = {  # a special file made in each case's folder -> what the message must name
    "fifo": "pipe (FIFO)", "zero": "character device", "urandom": "character device", "null": "character device",
    "loop": "too many levels of symbolic links", "dangling": "which does not exist", "sock": "socket",
}
T16 = " ".join(map(str, np.eye(4).ravel()))

CASES += [
    # special files as scans, for each command that reads one
    *[C(f"scan {k} info", f"info {k}.ply", m) for k, m in SPECIAL.items()],
    *[C(f"scan {k} register source", f"register {k}.ply tgt.ply", m) for k, m in SPECIAL.items()],
    *[C(f"scan {k} register target", f"register src.ply {k}.ply", m) for k, m in SPECIAL.items()],
    *[C(f"scan {k} merge", f"merge src.ply {k}.ply", m) for k, m in SPECIAL.items()],
    *[C(f"scan {k} serve", f"serve {k}.ply tgt.ply", m) for k, m in SPECIAL.items()],
    *[C(f"scan {k} slice", f"slice {k}.ply tgt.ply --png s.png", m) for k, m in SPECIAL.items() if k != "null"],
    C("scan fifo xyz", "info fifo.xyz", "pipe (FIFO)"),
    C("scan zero pcd", "info zero.pcd", "character device"),
    C("scan loop obj", "info loop.obj", "too many levels"),
    C("scan under a file", "info src.ply/inner.ply", "not a folder"),
    # special files as --init (a named pipe is read if a program writes to it: this one is given up)
    *[C(f"init {k}", f"{R} --init {k}.txt", m) for k, m in SPECIAL.items() if k not in ("fifo", "null")],
    C("init fifo without a writer", f"{R} --init fifo.txt", "sent nothing for 5 s"),
    C("init null device", f"{R} --init null.txt", "character device"),
    C("init sparse", f"{R} --init sparse.txt", "sparse file"),
    C("slice init zero", f"{S} --png s.png --init zero.txt", "character device"),
    C("slice init fifo", f"{S} --png s.png --init fifo.txt", "sent nothing"),
    # --init through a pipe (<(...)): read once
    C("init pipe accepted", [*R.split(), "--method", "icp", "--init", "{pipe}"], "", status=0, stdout_ok=True,
      pipe=(" ".join(map(str, np.eye(4).ravel())) + "\n").encode(), bound=30.0),
    C("init pipe json accepted", [*R.split(), "--method", "icp", "--init", "{pipe}"], "", status=0, stdout_ok=True,
      pipe=json.dumps({"transform": np.eye(4).tolist()}).encode(), bound=30.0),
    C("init pipe 15 numbers", [*R.split(), "--init", "{pipe}"], "found 15", pipe=" ".join(["1"] * 15).encode()),
    C("init pipe binary", [*R.split(), "--init", "{pipe}"], "not a text file", pipe=bytes(range(256)) * 8),
    C("init pipe too long", [*R.split(), "--init", "{pipe}"], "more than 1.05 MB", pipe=b"1 " * 600_000),
    C("init pipe scaled", [*R.split(), "--init", "{pipe}"], "scaled by 1.001",
      pipe=b"1.001 0 0 0 0 1.001 0 0 0 0 1.001 0 0 0 0 1"),
    # special files as sidecars (scan.json beside scan.ply)
    *[C(f"sidecar {k}", f"info side_{k}.ply", m) for k, m in SPECIAL.items()],
    C("sidecar sparse", "info side_sparse.ply", "sparse file"),
    C("sidecar too large", "info side_large.ply", "more than a JSON sidecar may be"),
    # a .conf beside a scan that is not a regular file is passed over (the user did not name it)
    *[C(f"conf beside {k}", f"info beside_{k}/s.ply", "", status=0, stdout_ok=True)
      for k in ("fifo", "zero", "loop", "sock", "sparse")],
    # traces and merge's side files
    *[C(f"slice trace {k}", f"{S} --png s.png --trace {k}.jsonl", m) for k, m in SPECIAL.items() if k != "null"],
    C("slice trace sparse", f"{S} --png s.png --trace sparse.jsonl", "sparse file"),
    *[C(f"serve trace {k}", f"serve src.ply tgt.ply --trace {k}.jsonl", m) for k, m in SPECIAL.items()
      if k in ("fifo", "zero", "loop")],
    *[C(f"merge init {k}", f"merge src.ply tgt.ply --init {k}.conf", m) for k, m in SPECIAL.items() if k != "null"],
    C("merge init sparse", "merge src.ply tgt.ply --init sparse.conf", "sparse file"),
    C("merge truth fifo", "merge src.ply tgt.ply --truth fifo.conf", "pipe (FIFO)"),
    C("merge truth zero", "merge src.ply tgt.ply --truth zero.conf", "character device"),
    C("merge truth sparse", "merge src.ply tgt.ply --truth sparse.conf", "sparse file"),
    C("merge init names a scan twice", "merge src.ply tgt.ply --init twice.conf", "second pose for src"),
    C("merge init translation 1e300", "merge src.ply tgt.ply --init far.conf", "beyond"),
    C("merge truth translation nan", "merge src.ply tgt.ply --truth nan.conf", "not finite"),
    C("merge init quaternion 1e300", "merge src.ply tgt.ply --init hugeq.conf --json", "", status=0, stdout_ok=True,
      writes=("model.ply",), bound=60.0),
    # the page's data folder
    C("serve data dir a fifo", "serve --data-dir fifo.ply", "pipe (FIFO), not a folder"),
    C("serve data dir a file", "serve --data-dir src.ply", "is a file, not a folder"),
    C("serve data dir a loop", "serve --data-dir loop.ply", "too many levels"),
    C("serve data dir a device", "serve --data-dir null.ply", "character device"),
    # sparse and huge files: refused from their size, never read whole
    C("sparse ply", "info sparse.ply", "sparse file"),
    C("sparse ply with a header", "info sparse_head.ply", "sparse file"),
    C("sparse xyz", "info sparse.xyz", "sparse file"),
    C("sparse pcd", "info sparse.pcd", "sparse file"),
    C("sparse obj", "info sparse.obj", "sparse file"),
    C("sparse register", "register sparse.ply tgt.ply", "sparse file"),
    C("ply vertex 2e9 binary", "info v2e9_binary.ply", "holds only"),
    C("ply vertex 2e9 ascii", "info v2e9_ascii.ply", "holds only"),
    C("ply face 2e9 one row binary", "info f2e9_binary.ply", "face 2000000000"),
    C("ply face 2e9 one row ascii", "info f2e9_ascii.ply", "face 2000000000"),
    C("ply grid 2e9 cells", "info g2e9.ply", "range_grid 2000000000"),
    C("pcd points 2e9", "info p2e9.pcd", "header says 2000000000 points"),
    C("pcd points 2e9 ascii", "info p2e9_ascii.pcd", "header says 2000000000 points"),
    # PLY header faults, each named
    C("ply range_grid 0 no property", "info grid_noprop.ply", "no list property"),
    C("ply range_grid rows no property", "info grid_rows_noprop.ply", "declares no property"),
    C("ply range_grid scalar", "info grid_scalar.ply", "no list property"),
    C("ply face scalar", "info face_scalar.ply", "no list property"),
    C("ply end_header in a comment", "info comment_end.ply", "", status=0, stdout_ok=True),
    C("ply faces only", "info faces_only.ply", "no vertices (element vertex 0); only 2 face rows"),
    C("ply x twice", "info x_twice.ply", "declares property x twice"),
    C("ply two vertex elements", "info two_vertex.ply", "element vertex is declared twice"),
    C("ply element without a name", "info element_short.ply", "element NAME COUNT"),
    C("ply property without a name", "info property_short.ply", "property TYPE NAME"),
    C("ply no format", "info no_format.ply", "format None"),
    C("ply list x", "info list_x.ply", "no x, y, z"),
    C("ply bom binary body lies", "info bom_short.ply", "holds only"),
    C("ply num_rows words", "info rows_words.ply", "num_rows 'many' is not a whole number"),
    C("ply grid size disagrees", "info grid_cells.ply", "range_grid has"),
    C("ply header 2 MB of comments", "info long_header.ply", "first 1 MB"),
    C("ply magic not first", "info magic_late.ply", "'ply' magic"),
    # numbers beyond what float64 geometry survives
    C("one point at 1e300 among 1600", "info far1.xyz", "1 of 1600 points lie beyond"),
    C("one point at 1e300 register", "register far1.xyz tgt.ply", "1 of 1600 points lie beyond"),
    C("every point at 1e300", "info farall.xyz", "1600 of 1600 points"),
    C("a scan 1e13 away", "info far13.xyz", "lie beyond"),
    C("a scan 1e-300 across", "info micro.xyz", "span only"),
    C("a scan 1e-150 across register", "register micro150.xyz micro150.xyz", "span only"),
    C("ply double at 1e300", "info far_double.ply", "lie beyond"),
    C("viewpoint source 1e300", f"{R} --viewpoint-source 1e300,0,0", "beyond what the geometry can use"),
    C("viewpoint target 1e13", f"{R} --viewpoint-target 0,1e13,0", "beyond what the geometry can use"),
    C("info viewpoint 1e300", "info src.ply --viewpoint 1e300,0,0", "beyond what the geometry can use"),
    C("slice viewpoint 1e300", f"{S} --png s.png --viewpoint-source 0,0,-1e300", "beyond"),
    C("slice span 1e300", f"{S} --png s.png --span 1e300,1", "half-width of tx"),
    C("slice span rotation 1e300", f"{S} --png s.png --span 1,1e300", "half-width of ry"),
    C("slice span rotation 181", f"{S} --png s.png --span 1,181", "more than 180"),
    C("sidecar viewpoint 1e300", "info side_vp_far.ply", "beyond"),
    C("sidecar pose translation 1e300", "info side_pose_far.ply", "translation"),
    C("pcd viewpoint 1e300", "info vp_far.pcd", "VIEWPOINT"),
    C("init translation 1e300", [*R.split(), "--init", FAR.replace("100000000", "1e300")], "translation"),
    C("init translation 1e13 file", f"{R} --init far13.txt", "translation"),
    C("rotation uncertainty 1e-300", f"{R} --rotation-uncertainty 1e-300", ">= 0.01"),
    # tiny and degenerate scans
    C("4 points onto themselves", "register tiny4.xyz tiny4.xyz", "only 4 points"),
    C("20 points onto themselves", "register tiny20.xyz tiny20.xyz", "only 20 points"),
    C("23 points against the corner", "register tiny23.xyz tgt.ply", "at least 24"),
    C("4 points slice", "slice tiny4.xyz tiny4.xyz --png s.png", "only 4 points"),
    C("max-points 3 accepted", f"{R} --method icp --max-points 3", "", status=0, stdout_ok=True, bound=30.0),
    # causes named
    C("init scaled 1.001", [*R.split(), "--init", "1.001 0 0 0 0 1.001 0 0 0 0 1.001 0 0 0 0 1"], "scaled by 1.001"),
    # an entry whose square overflows: the one line, no numpy warning before it
    C("init entry 1e300", [*R.split(), "--init", "1e300 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"], "stretches by 1e+300"),
    C("init mirrored", [*R.split(), "--init", "-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1"], "reflection"),
    C("init stretched", [*R.split(), "--init", "1 0.5 0 0 0 1 0 0 0 0 1 0 0 0 0 1"], "stretches"),
    C("leica pts with its count", "info leica.pts", "", status=0, stdout_ok=True),
    C("leica pts count lies", "info leica_short.pts", "announces 5 points but 3 rows"),
    C("pcd compressed corrupt", "info corrupt.pcd", "corrupt"),
    C("pcd compressed truncated", "info truncated_c.pcd", "ends inside the compressed data"),
    C("pcd compressed size lies", "info sizelie.pcd", "unpacks to"),
    C("ply with a utf-8 bom", "info bom.ply", "", status=0, stdout_ok=True),
    C("latin-1 name accepted", ["info", os.fsdecode(b"caf\xe9.ply")], "", status=0, stdout_ok=True),
    C("latin-1 name missing", ["info", os.fsdecode(b"th\xe9.ply")], "no such file"),
    C("latin-1 name register", ["register", os.fsdecode(b"caf\xe9.ply"), os.fsdecode(b"th\xe9.ply")], "no such file"),
    C("stdout closed info", "info src.ply", "standard output is closed", stdout_closed=True),
    C("stdout closed register", R, "standard output is closed", stdout_closed=True),
    # suspicious inputs: a warning or a refusal
    C("units 1000x apart", "register src_m.ply tgt.ply", "x smaller than tgt"),
    C("units 1000x apart icp", "register src_m.ply tgt.ply --method icp", "other units"),
    C("units 1000x apart slice", "slice src_m.ply tgt.ply --png s.png", "(millimetres and metres?)"),
    C("units stated alike warned", "register src_mm.ply tgt.ply --method icp", "though both sidecars say mm",
      status=0, stdout_ok=True, bound=30.0),
    # Dask: a scheduler is reached before any work; the flags belong to --sweep
    C("bench sweep scheduler unreachable", "bench --sweep --scheduler tcp://127.0.0.1:1", "cannot reach"),
    C("bench scheduler without sweep", "bench --quick --scheduler tcp://127.0.0.1:1", "only with --sweep"),
    C("bench workers without sweep", "bench --quick --workers 2", "only with --sweep"),
    C("merge scheduler unreachable", "merge src.ply tgt.ply --scheduler tcp://127.0.0.1:1", "cannot reach"),
    C("merge workers and scheduler", "merge src.ply tgt.ply --workers 2 --scheduler tcp://127.0.0.1:1", "give one"),
    C("merge scheduler without a port", "merge src.ply tgt.ply --scheduler tcp://127.0.0.1", "tcp://HOST:PORT"),
    # signals: one line, 128 + the signal, temporaries removed (the old trace kept), workers stopped quietly
    C("register trace SIGTERM", "register src.ply tgt.ply --method sa --threshold 0 --trace keep.jsonl",
      "interrupted (SIGTERM)", status=143, signal=SIGTERM, when=("file", ".keep-*.jsonl")),
    C("register trace SIGHUP", "register src.ply tgt.ply --method sa --threshold 0 --trace keep.jsonl",
      "interrupted (SIGHUP)", status=129, signal=SIGHUP, when=("file", ".keep-*.jsonl")),
    C("register trace ctrl-c", "register src.ply tgt.ply --method sa --threshold 0 --trace keep.jsonl",
      "interrupted (SIGINT)", status=130, signal=SIGINT, when=("file", ".keep-*.jsonl")),
    C("ctrl-c right after start", "register src.ply tgt.ply", "interrupted (SIGINT)", status=130, signal=SIGINT,
      when=("delay", 0.3)),
    C("SIGTERM during imports", "info src.ply", "interrupted (SIGTERM)", status=143, signal=SIGTERM,
      when=("delay", 0.2)),  # (at 0.5 s a quiet machine had read src.ply and answered)
    C("slice SIGTERM", f"{S} --png keep.png --steps 201", "interrupted (SIGTERM)", status=143, signal=SIGTERM,
      when=("delay", 4.0)),
    # --json: the merge's progress lines (on stderr otherwise) would come before the one line of the interruption
    C("merge 2 workers ctrl-c", "merge src.ply tgt.ply c3.ply --workers 2 --json --out m0.ply", "interrupted (SIGINT)",
      status=130, signal=SIGINT, when=("children", 2)),
    # 3 s after the workers appear the merge is registering (a quiet machine finished it 8 s after them)
    C("merge 2 workers ctrl-c at work", "merge src.ply tgt.ply c3.ply --workers 2 --json --out m.ply",
      "interrupted (SIGINT)", status=130, signal=SIGINT, when=("children", 2, 3.0)),
    C("merge 2 workers SIGTERM at work", "merge src.ply tgt.ply c3.ply --workers 2 --json --out m2.ply",
      "interrupted (SIGTERM)", status=143, signal=SIGTERM, when=("children", 2, 3.0)),
    C("serve SIGTERM", f"serve --port {_FREE_PORTS[0]}", "interrupted (SIGTERM)", status=143, stdout_ok=True,
      signal=SIGTERM, when=("delay", 6.0)),
    C("serve SIGHUP", f"serve --port {_FREE_PORTS[1]}", "interrupted (SIGHUP)", status=129, stdout_ok=True,
      signal=SIGHUP, when=("delay", 6.0)),
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
    (f / "cut.bin").write_bytes(bytes(100))
    (f / "cut.pcd.bin").write_bytes(bytes(96))
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
                "side_furlongs": {"units": "furlongs"}, "side_list": [1, 2, 3]}
    for name, content in sidecars.items():
        shutil.copy(CORNER / "scan2.ply", f / f"{name}.ply")
        (f / f"{name}.json").write_text(content if isinstance(content, str) else json.dumps(content))
    shutil.copy(CORNER / "scan2.ply", f / "side_dir.ply")
    (f / "side_dir.json").mkdir()
    write_round_two(f)


def write_round_two(f: Path) -> None:
    """The regular fixtures of the second round (header faults, far and tiny scans, units, side files)."""
    rng = np.random.default_rng(2)
    head = "ply\nformat {fmt} 1.0\n"
    xyz = "property float x\nproperty float y\nproperty float z\n"

    def ply(name: str, text: str | bytes) -> None:
        (f / name).write_bytes(text if isinstance(text, bytes) else text.encode())

    tri = "0 0 0\n1 0 0\n0 1 1\n"
    ply("v2e9_binary.ply", (head.format(fmt="binary_little_endian") + "element vertex 2000000000\n" + xyz +
                            "end_header\n").encode() + np.zeros(9, "<f4").tobytes())
    ply("v2e9_ascii.ply", head.format(fmt="ascii") + "element vertex 2000000000\n" + xyz + "end_header\n" + tri)
    face = "element face 2000000000\nproperty list uchar int vertex_indices\n"
    ply("f2e9_binary.ply", (head.format(fmt="binary_little_endian") + "element vertex 3\n" + xyz + face +
                            "end_header\n").encode() + np.array([[0, 0, 0], [1, 0, 0], [0, 1, 1]], "<f4").tobytes()
        + b"\x03" + np.array([0, 1, 2], "<i4").tobytes())
    ply("f2e9_ascii.ply", head.format(fmt="ascii") + "element vertex 3\n" + xyz + face + "end_header\n" + tri + "3 0 1 2\n")
    ply("g2e9.ply", head.format(fmt="ascii") + "element vertex 3\n" + xyz + "element range_grid 2000000000\n"
        "property list uchar int vertex_indices\nend_header\n" + tri + "1 0\n")
    pcd = "VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 2000000000\nHEIGHT 1\nPOINTS 2000000000\n"
    (f / "p2e9.pcd").write_bytes((pcd + "DATA binary\n").encode() + np.zeros(9, "<f4").tobytes())
    (f / "p2e9_ascii.pcd").write_text(pcd + "DATA ascii\n" + tri)
    grid = "obj_info num_cols 2\nobj_info num_rows 2\n"
    ply("grid_noprop.ply", head.format(fmt="ascii") + grid + "element vertex 3\n" + xyz + "element range_grid 0\n"
        "end_header\n" + tri)
    ply("grid_rows_noprop.ply", head.format(fmt="ascii") + grid + "element vertex 3\n" + xyz +
        "element range_grid 4\nend_header\n" + tri)
    ply("grid_scalar.ply", head.format(fmt="ascii") + grid + "element vertex 3\n" + xyz + "element range_grid 4\n"
        "property int vertex_indices\nend_header\n" + tri + "0\n1\n2\n-1\n")
    ply("face_scalar.ply", head.format(fmt="ascii") + "element vertex 3\n" + xyz + "element face 1\n"
        "property int vertex_indices\nend_header\n" + tri + "2\n")
    ply("faces_only.ply", head.format(fmt="ascii") + "element vertex 0\n" + xyz + "element face 2\n"
        "property list uchar int vertex_indices\nend_header\n3 0 1 2\n3 1 2 3\n")
    bowl = (CORNER / "scan1.ply").read_text()
    ply("comment_end.ply", bowl.replace("comment rangereg scan corner-scan1",
                                        "comment written before end_header by a tool that says end_header here"))
    ply("bom.ply", b"\xef\xbb\xbf" + bowl.encode())
    ply("bom_short.ply", b"\xef\xbb\xbf" + (head.format(fmt="binary_little_endian") + "element vertex 1000\n" + xyz +
                                             "end_header\n").encode() + np.zeros(30, "<f4").tobytes())
    ply("x_twice.ply", head.format(fmt="ascii") + "element vertex 3\nproperty float x\n" + xyz + "end_header\n"
        "0 0 0 0\n1 1 0 0\n2 0 1 1\n")
    ply("two_vertex.ply", head.format(fmt="ascii") + "element vertex 3\n" + xyz + "element vertex 3\n" + xyz +
        "end_header\n" + tri + tri)
    ply("element_short.ply", head.format(fmt="ascii") + "element vertex\n" + xyz + "end_header\n" + tri)
    ply("property_short.ply", head.format(fmt="ascii") + "element vertex 3\nproperty float\nproperty float y\n"
        "property float z\nend_header\n" + tri)
    ply("no_format.ply", "ply\nelement vertex 3\n" + xyz + "end_header\n" + tri)
    ply("list_x.ply", head.format(fmt="ascii") + "element vertex 1\nproperty list uchar float x\nproperty float y\n"
        "property float z\nend_header\n2 0 1 5 6\n")
    ply("rows_words.ply", bowl.replace("obj_info num_rows 85", "obj_info num_rows many"))
    ply("grid_cells.ply", bowl.replace("obj_info num_rows 85", "obj_info num_rows 80"))
    ply("long_header.ply", "ply\nformat ascii 1.0\n" + "comment padding padding padding padding\n" * 60_000 +
        "element vertex 3\n" + xyz + "end_header\n" + tri)
    ply("magic_late.ply", "comment first\nply\nformat ascii 1.0\nelement vertex 3\n" + xyz + "end_header\n" + tri)
    # numbers beyond what the geometry survives
    u = rng.uniform(-1, 1, (1600, 2))
    cap = np.c_[u, (u ** 2).sum(1) - 5]
    np.savetxt(f / "far1.xyz", np.r_[cap[:7], [[1e300, 0, 0]], cap[8:]])
    np.savetxt(f / "farall.xyz", cap * 1e300)
    np.savetxt(f / "far13.xyz", cap + 1e13)
    np.savetxt(f / "micro.xyz", cap * 1e-300)
    np.savetxt(f / "micro150.xyz", cap * 1e-150)
    ply("far_double.ply", head.format(fmt="ascii") + "element vertex 4\nproperty double x\nproperty double y\n"
        "property double z\nend_header\n0 0 0\n1 0 0\n0 1 1\n1e300 1 1\n")
    side = {"side_vp_far": {"viewpoint": [1e300, 0, 0]},
            "side_pose_far": {"pose": [[1, 0, 0, 1e300], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]},
            "side_large": {"comment": "x" * (17 << 20)}}
    for name, content in side.items():
        shutil.copy(CORNER / "scan2.ply", f / f"{name}.ply")
        (f / f"{name}.json").write_text(json.dumps(content))
    (f / "vp_far.pcd").write_text("VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 3\nHEIGHT 1\n"
                                  "VIEWPOINT 1e300 0 0 1 0 0 0\nPOINTS 3\nDATA ascii\n" + tri)
    far13 = np.eye(4)
    far13[0, 3] = 1e13
    (f / "far13.txt").write_text(" ".join(map(str, far13.ravel())))
    (f / "twice.conf").write_text("bmesh src.ply 0 0 0 0 0 0 1\nbmesh src.ply 0 0 0 0 0 0 1\nbmesh tgt.ply 0 0 0 0 0 0 1\n")
    (f / "far.conf").write_text("bmesh src.ply 1e300 0 0 0 0 0 1\nbmesh tgt.ply 0 0 0 0 0 0 1\n")
    (f / "nan.conf").write_text("bmesh src.ply nan 0 0 0 0 0 1\nbmesh tgt.ply 0 0 0 0 0 0 1\n")
    # a quaternion whose square overflows: a direction like any other (the identity here), not a traceback
    (f / "hugeq.conf").write_text("bmesh src.ply 0 0 0 0 0 0 1e300\nbmesh tgt.ply 0 0 0 0 0 0 1\n")
    # tiny scans
    for n in (4, 20, 23):
        v = rng.uniform(-1, 1, (n, 2))
        np.savetxt(f / f"tiny{n}.xyz", np.c_[v, (v ** 2).sum(1) - 5] * 500)
    # Leica .pts, compressed PCDs, a latin-1 name, scans in metres
    pts = np.loadtxt(f / "far1.xyz")[10:200] * 300
    (f / "leica.pts").write_text(f"{len(pts)}\n" + "".join(f"{x:.4f} {y:.4f} {z:.4f} -1200 120 130 140\n"
                                                           for x, y, z in pts))
    (f / "leica_short.pts").write_text("5\n" + "".join(f"{x} {y} {z}\n" for x, y, z in pts[:3]))
    _compressed_pcds(f)
    shutil.copy(CORNER / "scan2.ply", f / os.fsdecode(b"caf\xe9.ply"))
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from rangereg.core.io import load_scan
    from rangereg.core.ply import write_range_grid_ply

    src = load_scan(f / "src.ply")
    write_range_grid_ply(f / "src_m.ply", src.points / 1000, src.grid.index)
    write_range_grid_ply(f / "src_mm.ply", src.points / 1000, src.grid.index)
    (f / "src_mm.json").write_text(json.dumps({"units": "mm"}))
    shutil.copy(CORNER / "scan1.ply", f / "c3.ply")
    shutil.copy(CORNER / "scan1.json", f / "c3.json")
    for k in ("fifo", "zero", "urandom", "null", "loop", "dangling", "sock", "sparse"):
        shutil.copy(CORNER / "scan2.ply", f / f"side_{k}.ply")
    for k in ("fifo", "zero", "loop", "sock", "sparse"):
        (f / f"beside_{k}").mkdir()
        shutil.copy(CORNER / "scan1.ply", f / f"beside_{k}" / "s.ply")


def _compressed_pcds(f: Path) -> None:
    """A good binary_compressed PCD's header and LZF body, then: bytes flipped, cut short, its size lying."""
    import open3d as o3d

    pts = np.loadtxt(f / "far1.xyz")[20:600] * 300
    good = f / "good_c.pcd"
    o3d.io.write_point_cloud(str(good), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)), compressed=True)
    raw = good.read_bytes()
    good.unlink()
    at = raw.index(b"DATA binary_compressed\n") + len(b"DATA binary_compressed\n")
    bad = bytearray(raw)
    for k in range(at + 18, len(raw), 7):
        bad[k] ^= 0x5A
    (f / "corrupt.pcd").write_bytes(bytes(bad))
    (f / "truncated_c.pcd").write_bytes(raw[:at + 100])
    lie = bytearray(raw)
    lie[at + 4:at + 8] = np.array([12345], "<u4").tobytes()
    (f / "sizelie.pcd").write_bytes(bytes(lie))


GB50 = 50 << 30


def _sparse(path: Path) -> None:
    """A 50 GB file of which nothing is stored (it reads as zeros)."""
    with open(path, "wb") as fh:
        fh.truncate(GB50)


def write_special(f: Path) -> None:
    """The special files every case's folder gets (made there, since copying them would read or hang):
    FIFOs, links to devices, link loops, dangling links, sockets and 50 GB sparse files."""
    import socket

    for ext in ("ply", "xyz", "txt", "jsonl", "conf"):
        os.mkfifo(f / f"fifo.{ext}")
        (f / f"zero.{ext}").symlink_to("/dev/zero")
        (f / f"urandom.{ext}").symlink_to("/dev/urandom")
        (f / f"null.{ext}").symlink_to("/dev/null")
        (f / f"loop.{ext}").symlink_to(f"loop2.{ext}")
        (f / f"loop2.{ext}").symlink_to(f"loop.{ext}")
        (f / f"dangling.{ext}").symlink_to(f"nowhere.{ext}")
        with socket.socket(socket.AF_UNIX) as s:
            s.bind(str(f / f"sock.{ext}"))
    os.mkfifo(f / "fifo.pcd")
    (f / "zero.pcd").symlink_to("/dev/zero")
    (f / "loop.obj").symlink_to("loop2.obj")
    (f / "loop2.obj").symlink_to("loop.obj")
    for name in ("sparse.ply", "sparse.xyz", "sparse.pcd", "sparse.obj", "sparse.txt", "sparse.conf", "sparse.jsonl"):
        _sparse(f / name)
    (f / "sparse_head.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                       "property float z\nend_header\n0 0 0\n1 0 0\n0 1 1\n")
    os.truncate(f / "sparse_head.ply", GB50)
    for k, target in (("fifo", None), ("zero", "/dev/zero"), ("urandom", "/dev/urandom"), ("null", "/dev/null"),
                      ("loop", "side_loop2.json"), ("dangling", "nowhere.json"), ("sock", None), ("sparse", None)):
        side = f / f"side_{k}.json"
        if k == "fifo":
            os.mkfifo(side)
        elif k == "sock":
            with socket.socket(socket.AF_UNIX) as s:
                s.bind(str(side))
        elif k == "sparse":
            _sparse(side)
        else:
            side.symlink_to(target)
    (f / "side_loop2.json").symlink_to("side_loop.json")
    beside = {"fifo": None, "zero": "/dev/zero", "loop": "y.conf", "sock": None, "sparse": None}
    for k, target in beside.items():
        conf = f / f"beside_{k}" / "x.conf"
        if k == "fifo":
            os.mkfifo(conf)
        elif k == "sock":
            with socket.socket(socket.AF_UNIX) as s:
                s.bind(str(conf))
        elif k == "sparse":
            _sparse(conf)
        else:
            conf.symlink_to(target)
            if k == "loop":
                (f / f"beside_{k}" / "y.conf").symlink_to("x.conf")


def write_trace_fixtures(f: Path, event: str) -> None:
    """Traces (a header line, then ``event``) that do not match the pair src.ply -> tgt.ply, or are not traces."""
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from rangereg.core.config import Config
    from rangereg.core.io import load_scan
    from rangereg.core.trace import TraceHeader

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


def _children(pid: int) -> int:
    """Worker processes (multiprocessing's) started by process ``pid``."""
    n = 0
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as fh:
                ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            with open(f"/proc/{entry}/cmdline", "rb") as fh:
                forked = b"multiprocessing-fork" in fh.read()
        except (OSError, ValueError, IndexError):
            continue
        n += ppid == pid and forked
    return n


def _group(pgid: int) -> list[int]:
    """Live processes (not zombies: an orphan's exit status waits for a reaper) of process group ``pgid``."""
    live = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":
                live.append(int(entry))
    return live


def _await(case: Case, proc: subprocess.Popen, work: Path, timeout: float) -> None:
    """Wait until the case's moment to signal: a delay, a file (glob) in its folder, or worker processes."""
    kind, arg, *after = case.when
    t0 = time.perf_counter()
    while proc.poll() is None and time.perf_counter() - t0 < timeout:
        if kind == "delay" and time.perf_counter() - t0 >= arg:
            return
        if kind == "file" and any(work.glob(arg)):
            time.sleep(0.5)  # into the work the file announces
            return
        if kind == "children" and _children(proc.pid) >= arg:
            time.sleep(after[0] if after else 1.5)  # the cluster starting, or (later) at work
            return
        time.sleep(0.05)


def _run(case: Case, work: Path, env: dict, timeout: float) -> tuple[int | None, str, str, float]:
    """(status or None when it timed out, stdout, stderr, seconds to judge: the run, or signal to exit)."""
    args = [sys.executable, "-m", "rangereg.app.cli", *case.args]
    fds: tuple = ()
    writer = None
    if case.pipe is not None:  # as <(...) does: the read end of a pipe, named /dev/fd/N
        r, w = os.pipe()
        args = [a.replace("{pipe}", f"/dev/fd/{r}") for a in args]
        fds = (r,)

        def feed():
            with os.fdopen(w, "wb") as fh:
                try:
                    fh.write(case.pipe)
                except BrokenPipeError:
                    pass

        writer = threading.Thread(target=feed, daemon=True)
    if case.stdout_closed:
        args = ["sh", "-c", 'exec "$@" >&-', "sh", *args]
    t0 = time.perf_counter()
    proc = subprocess.Popen(args, cwd=work, env=env, stdin=subprocess.DEVNULL, pass_fds=fds,
                            stdout=None if case.stdout_closed else subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=case.signal is not None)
    if fds:
        os.close(fds[0])
        writer.start()
    if case.signal is not None:
        _await(case, proc, work, timeout)
        if proc.poll() is None:
            t0 = time.perf_counter()
            if case.signal == signal.SIGINT:  # Ctrl-C: the terminal signals the whole process group
                os.killpg(proc.pid, case.signal)
            else:
                proc.send_signal(case.signal)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL) if case.signal is not None else proc.kill()
        out, err = proc.communicate()
        return None, out or b"", err, time.perf_counter() - t0
    seconds = time.perf_counter() - t0
    if case.signal is not None:  # the group's other processes (workers) must be gone too, within a second
        deadline = time.perf_counter() + 1.0
        while _group(proc.pid) and time.perf_counter() < deadline:
            time.sleep(0.05)
        if _group(proc.pid):
            err += b"\n(processes of its group still running after it ended)"
            os.killpg(proc.pid, signal.SIGKILL)
    return proc.returncode, (out or b"").decode(errors="replace"), err.decode(errors="replace"), seconds


def run_case(case: Case, fixtures: Path, timeout: float = 60.0, bound: float = 10.0) -> tuple[str | None, float]:
    """(None if the case meets the contract else why not, seconds)."""
    with tempfile.TemporaryDirectory(prefix="badin-") as tmp:
        work = Path(tmp) / "w"
        shutil.copytree(fixtures, work, symlinks=True)
        write_special(work)
        before = snapshot(work)
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)}
        status, out, err, seconds = _run(case, work, env, timeout)
        if status is None:
            return f"took longer than {timeout:g} s", seconds
        lines = err.strip().splitlines()
        problems = []
        if status != case.status:
            problems.append(f"exit {status}")
        if "Traceback" in err:
            problems.append("a traceback")
        want = 1 if case.expect or case.status != 0 else 0
        if len(lines) != want:
            problems.append(f"{len(lines)} stderr lines")
        elif want and case.expect.lower() not in lines[0].lower():
            problems.append(f"no {case.expect!r} in the message")
        if out.strip() and not case.stdout_ok:
            problems.append("output on stdout")
        bound = case.bound or bound
        if seconds > bound:
            problems.append(f"{seconds:.1f} s{' from the signal' if case.signal else ''} (bound {bound:g} s)")
        after = snapshot(work)
        touched = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k) and k not in case.writes)
        if touched:
            problems.append(f"files touched: {', '.join(touched)}")
        if problems:
            shown = " | ".join(lines[-3:]) if lines else "(no stderr)"
            return f"{'; '.join(problems)} -- stderr: {shown[:300]}", seconds
        return None, seconds


def run_table(cases: list[Case], jobs: int = 2, timeout: float = 60.0, say=print, bound: float = 10.0) -> int:
    """Run ``cases``; print each failing one and the tally. Returns the number that failed."""
    names = [c.name for c in cases]
    assert len(set(names)) == len(names), "case names must be distinct"
    with tempfile.TemporaryDirectory(prefix="badin-fixtures-") as tmp:
        fixtures = Path(tmp)
        write_fixtures(fixtures)
        t0 = time.perf_counter()
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            results = list(pool.map(lambda c: run_case(c, fixtures, timeout, bound), cases))
    failed = 0
    for case, (problem, seconds) in zip(cases, results):
        if problem is not None:
            failed += 1
            say(f"FAIL  {case.name}  [rangereg {' '.join(case.args)}]  ({seconds:.1f} s): {problem}")
    slowest = max(zip((s for _, s in results), names))
    say(f"{len(cases) - failed} of {len(cases)} meet the contract (exit 2 or 128 + the signal, or 0 where the input "
        f"must be accepted; one stderr line with the expected message, none when accepted unless it warns; no "
        f"traceback, no file touched, under {bound:g} s); {time.perf_counter() - t0:.0f} s with {jobs} jobs, slowest "
        f"case {slowest[0]:.1f} s ({slowest[1]})")
    return failed


def select(cases: list[Case], only: int | None = None, smallest: bool = False, fragment: str | None = None) -> list[Case]:
    """The cases to run: those whose name holds ``fragment``; the fast subset (``smallest``); or ``only`` of
    them spread evenly over the table."""
    cases = [c for c in cases if not fragment or fragment in c.name]
    if smallest:
        cases = [c for c in cases if c.name in FAST]
    if only is not None and only < len(cases):
        cases = [cases[round(i * (len(cases) - 1) / max(only - 1, 1))] for i in range(only)] if only > 0 else []
    return cases


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="cases run at once (default 2)")
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds before a case is killed (default 60)")
    ap.add_argument("--bound", type=float, default=10.0, help="seconds a case may take (default 10; a signal's "
                    "case from the signal to the exit)")
    ap.add_argument("-k", dest="fragment", help="only cases whose name holds this")
    ap.add_argument("--only", type=int, metavar="N", help="N cases spread evenly over the table")
    ap.add_argument("--smallest", action="store_true", help="two cases of the fast subset (with --only N: N of it)")
    ap.add_argument("--list", action="store_true", help="list the cases and exit")
    a = ap.parse_args(argv)
    cases = select(CASES, 2 if a.smallest and a.only is None else a.only, a.smallest, a.fragment)
    if a.list:
        for c in cases:
            print(f"{c.name:36s} rangereg {' '.join(c.args)}  ->  {c.expect or f'exit {c.status}'}")
        return 0
    return 1 if run_table(cases, a.jobs, a.timeout, bound=a.bound) else 0


if __name__ == "__main__":
    raise SystemExit(main())
