"""Operators' files: how fast a structured E57 scan is read, and what registering and merging E57 and
LAS copies of the shared bunny scans gives.

    python benchmarks/e57_read.py [--runs 5] [--seeds 3] [--skip-register] [BUNNY_DIR]

1. Reading: a 1000 x 1000 structured scan (1M points, rowIndex/columnIndex, intensity) is written
   twice into a temporary folder, by pye57's own writer (single-precision cartesian, as pye57 writes)
   and as a scanner exports it (spherical range as scaled integers of 0.1 mm, angles in double); each
   is read by ``core.io.load_scan`` (points, grid, intensity: what ``register`` reads) ``--runs``
   times. Prints the median and range of the seconds, and the points and grid read.
2. Registering (needs the bunny): E57 files of bunny pairs built as tests/test_e57.py builds them
   (points in the sensor's frame, the first scan at its true pose, the second's stored pose turned 10
   degrees), registered both ways with ``rangereg register FILE#1 FILE#0 --json`` and the default
   settings, for ``--seeds`` seeded axes per pair (``--origin-seeds`` for the last family) and three
   ways to turn the pose: about the scan's
   centroid (the tests' family), both scans turned about their centroids (the relative guess 0-20
   degrees off), and about the frame's origin, the sensor (~1.2 m from a 0.15 m bunny: ~0.2 m off at
   the object). A run is right within 2 degrees and 2 mm of the truth. Then ``merge`` of the
   two-scan file and of a four-scan file, and the LAS copy of bun045 against its PLY.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from rangereg.app.cli import main as rangereg  # noqa: E402
from rangereg.core.io import load_scan  # noqa: E402
from rangereg.core.transforms import from_params, invert, pose_error  # noqa: E402

PAIRS = (("bun000", "bun045"), ("bun000", "bun315"), ("bun045", "bun090"))


def big_scan(folder: Path, n: int = 1000) -> dict[str, Path]:
    """The two 1M-point structured files: a wavy wall 10 m from the scanner, n x n directions (1000)."""
    import pye57

    from tests.test_e57 import write_raw

    rows, cols = np.mgrid[0:n, 0:n]
    az, el = np.radians(cols.ravel() * 0.07 - 35.0), np.radians(rows.ravel() * 0.05 - 25.0)
    r = 10.0 + 0.3 * np.sin(5 * az) * np.cos(4 * el)
    xyz = np.c_[r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)]
    intensity = np.random.default_rng(0).random(n * n)
    files = {"pye57 writer (cartesian float32)": folder / "cartesian.e57",
             "scanner-like (spherical, scaled range)": folder / "spherical.e57"}
    with pye57.E57(str(files["pye57 writer (cartesian float32)"]), mode="w") as e:
        e.write_scan_raw({"cartesianX": xyz[:, 0], "cartesianY": xyz[:, 1], "cartesianZ": xyz[:, 2],
                          "intensity": intensity.astype(np.float32), "rowIndex": rows.ravel().astype(np.uint16),
                          "columnIndex": cols.ravel().astype(np.uint16)}, name="wall")
    write_raw(files["scanner-like (spherical, scaled range)"], [{"name": "wall", "pose": ((1, 0, 0, 0), (0, 0, 0)), "fields": {
        "sphericalRange": ("0.0001", r), "sphericalAzimuth": ("double", az), "sphericalElevation": ("double", el),
        "intensity": ("double", intensity), "rowIndex": ("int", rows.ravel()), "columnIndex": ("int", cols.ravel())}}])
    return files


def time_reads(files: dict[str, Path], runs: int) -> None:
    print("reading a 1M-point structured E57 scan (core.io.load_scan: points, grid, intensity)")
    for label, path in files.items():
        seconds = []
        for _ in range(runs):
            t0 = time.perf_counter()
            scan = load_scan(path)
            seconds.append(time.perf_counter() - t0)
        print(f"  {label}: {path.stat().st_size / 1e6:.1f} MB, {len(scan.points)} points, grid "
              f"{'x'.join(map(str, scan.grid.shape))}: median {np.median(seconds):.2f} s "
              f"(min {min(seconds):.2f}, max {max(seconds):.2f}; {runs} runs)")


def cli(*args) -> dict:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = rangereg([str(a) for a in args])
    if code != 0:
        raise SystemExit(f"rangereg {' '.join(map(str, args))} failed: {err.getvalue().strip()}")
    return json.loads(out.getvalue())


def build(bunny: Path, path: Path, names, family: str, seed: int) -> list[np.ndarray]:
    """An E57 of ``names`` with stored poses turned 10 degrees by ``family``; returns the true poses."""
    from rangereg.core.e57_write import write_e57

    from tests.test_e57 import rotated_about_centroid, sensor_frame

    scans, truth, stored = [], [], []
    for k, n in enumerate(names):
        s, T = sensor_frame(load_scan(bunny / f"{n}.ply"))
        scans.append(s)
        truth.append(T)
        if k == 0 and family != "both about centroids":
            stored.append(T)
        elif family == "about the sensor origin":
            axis = np.random.default_rng(seed + k).normal(size=3)
            stored.append(T @ from_params(np.r_[0.0, 0.0, 0.0, np.radians(10.0) * axis / np.linalg.norm(axis)]))
        else:
            stored.append(rotated_about_centroid(T, s, 10.0, seed + k))
    write_e57(path, scans, stored)
    return truth


def registrations(bunny: Path, folder: Path, seeds: int, origin_seeds: int) -> None:
    from rangereg.core.e57 import read_e57

    print("registering two-scan bunny E57 files both ways from their stored poses (default settings)")
    for family in ("about the centroid", "both about centroids", "about the sensor origin"):
        rows = []
        for a, b in PAIRS:
            for seed in range(origin_seeds if family == "about the sensor origin" else seeds):
                path = folder / f"{a}-{b}-{seed}.e57"
                truth = build(bunny, path, (a, b), family, seed)
                for s, t in ((1, 0), (0, 1)):
                    src = read_e57(path, str(s))
                    right = invert(truth[t]) @ truth[s]
                    off = pose_error(invert(read_e57(path, str(t)).guess) @ src.guess, right, src.centroid)
                    res = cli("register", f"{path}#{s}", f"{path}#{t}", "--json")
                    rot, tr = pose_error(np.array(res["transform"]), right, src.centroid)
                    rows.append((off[0], off[1], rot, tr, res["seconds"], res["below_threshold"]))
                    print(f"    {family}: {(a, b)[s]} -> {(a, b)[t]} seed {seed}: guess {off[0]:.1f} deg "
                          f"{off[1] * 1000:.0f} mm off -> {rot:.3f} deg {tr * 1000:.3f} mm, {res['seconds']:.2f} s, "
                          f"trusted {res['below_threshold']}")
        r = np.array(rows, dtype=float)
        right = (r[:, 2] < 2.0) & (r[:, 3] < 0.002)
        print(f"  {family}: right {right.sum()}/{len(r)}; trusted and right {int((right & (r[:, 5] > 0)).sum())}, "
              f"trusted and wrong {int((~right & (r[:, 5] > 0)).sum())}; guess off {r[:, 0].min():.1f}-"
              f"{r[:, 0].max():.1f} deg, {1000 * r[:, 1].min():.0f}-{1000 * r[:, 1].max():.0f} mm at the centroid; "
              f"seconds median {np.median(r[:, 4]):.2f}, max {r[:, 4].max():.2f}")


def merges(bunny: Path, folder: Path) -> None:
    from rangereg.core.e57 import read_e57_all

    print("merge FILE.e57 --out registered.e57 (stored poses as initial poses, the scans written back)")
    for names in (("bun000", "bun045"), ("bun000", "bun045", "bun090", "bun315")):
        path, out = folder / f"merge{len(names)}.e57", folder / f"merge{len(names)}-registered.e57"
        truth = build(bunny, path, names, "about the centroid", 0)
        res = cli("merge", path, "--out", out, "--workers", "1", "--json")
        scans = read_e57_all(out)
        errs = [pose_error(s.guess, T, s.centroid) for s, T in zip(scans, truth)]
        print(f"  {len(names)} scans: {res['seconds']:.1f} s, {res['graph']['used']} of {res['graph']['pairs']} pairs "
              f"used; written poses vs truth: "
              + ", ".join(f"{n} {e[0]:.3f} deg {e[1] * 1000:.3f} mm" for n, e in zip(names, errs)))


def las_vs_ply(bunny: Path, folder: Path) -> None:
    from rangereg.core.sidefiles import load_conf

    from tests.test_las import write_las

    ply = load_scan(bunny / "bun045.ply")
    write_las(folder / "bun045.laz", ply.points, ("scan_origin_x", "scan_origin_y", "scan_origin_z"), ply.viewpoint)
    write_las(folder / "bun045.las", ply.points)
    conf = load_conf(bunny / "bun.conf")
    truth = invert(conf["bun000"]) @ conf["bun045"]
    axis = np.random.default_rng(0).normal(size=3)
    init = truth @ from_params(np.r_[0.0, 0.0, 0.0, np.radians(10.0) * axis / np.linalg.norm(axis)])
    print("bun045 onto bun000.ply from the same --init (10 deg off about the frame's origin)")
    for source, what in ((bunny / "bun045.ply", "PLY"), (folder / "bun045.laz", "LAZ with scan-origin fields"),
                         (folder / "bun045.las", "LAS, viewpoint estimated")):
        res = cli("register", source, bunny / "bun000.ply", "--init", " ".join(repr(float(v)) for v in init.ravel()), "--json")
        rot, tr = pose_error(np.array(res["transform"]), truth, ply.centroid)
        print(f"  {what}: {rot:.3f} deg {tr * 1000:.3f} mm from the truth, {res['seconds']:.2f} s, "
              f"trusted {res['below_threshold']}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bunny", nargs="?", default=str(ROOT.parent / "shared" / "data" / "bunny"))
    ap.add_argument("--runs", type=int, default=5, help="reads of each 1M-point file")
    ap.add_argument("--seeds", type=int, default=3, help="seeded axes per bunny pair and family")
    ap.add_argument("--origin-seeds", type=int, default=1, help="seeded axes per pair for the poses turned about "
                    "the sensor origin (runs of 30-180 s each)")
    ap.add_argument("--skip-register", action="store_true", help="time the reads only")
    ap.add_argument("--smallest", action="store_true", help="one read of a 60 x 60 scan, no registration")
    a = ap.parse_args()
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} (1, 5, 15 min)")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        time_reads(big_scan(folder, 60 if a.smallest else 1000), 1 if a.smallest else a.runs)
        bunny = Path(a.bunny)
        if a.skip_register or a.smallest:
            return 0
        if not (bunny / "bun.conf").is_file():
            raise SystemExit(f"no bunny scans in {bunny} (give the folder of bun*.ply and bun.conf)")
        registrations(bunny, folder, a.seeds, a.origin_seeds)
        merges(bunny, folder)
        las_vs_ply(bunny, folder)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
