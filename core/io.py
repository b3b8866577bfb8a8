"""Loading and saving scans: PLY (with Stanford range grids), PCD (its VIEWPOINT, an organised cloud's
grid), XYZ/TXT/CSV, OBJ/STL/OFF meshes, E57 (core.e57), LAS/LAZ (core.las), KITTI Velodyne and nuScenes LiDAR
``.bin`` frames (float32 records, metres), Stanford ``.conf`` poses
and our JSON sidecar (viewpoint, units, kind, ground truth). The readers return what the file holds
(core.assemble.RawScan); core.assemble makes the Scan by one precedence rule."""

from __future__ import annotations

import re
import threading
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from .assemble import Given, RawScan, assemble, scan_kind
from .e57 import SUFFIX as E57_SUFFIX
from .e57 import read_e57_all, read_e57_raw, split_selection
from .errors import InputError
from .files import BINARY_FACTOR, HEADER_LIMIT, TEXT_FACTOR, check_memory, memory_available, open_regular, stat_regular
from .las import SUFFIXES as LAS_SUFFIXES
from .las import read_las_raw
from .ply import PlyError, read_ply, write_ply, write_range_grid_ply
from .rows import norms
from .scan import Scan, ScanKind, units_name
from .sidefiles import (  # noqa: F401  (callers read side files through core.io too)
    check_sidecar,
    load_conf,
    parse_transform,
    pose_from_conf_beside,
    read_sidecar,
    read_transform,
    sidecar_path,
    vector3,
    write_sidecar,
    write_transform,
)
from .transforms import quaternion_matrix

POINT_FORMATS = (".ply", ".pcd", ".xyz", ".txt", ".csv", ".pts")
MESH_FORMATS = (".obj", ".stl", ".off")
BIN_SUFFIX = ".bin"  # KITTI's Velodyne frames (velodyne/*.bin) and nuScenes' LiDAR sweeps (*.pcd.bin)
SCANNER_FORMATS = (E57_SUFFIX, *LAS_SUFFIXES, BIN_SUFFIX)  # files that carry their own units, poses or origins
FORMATS = POINT_FORMATS + MESH_FORMATS + SCANNER_FORMATS


def load_scan(path: str | Path, viewpoint: np.ndarray | None = None, name: str | None = None,
              kind: ScanKind | str | None = None, units: str | None = None) -> Scan:
    """Read a scan file. ``viewpoint`` (3,), ``kind`` and ``units`` override whatever the sidecar, the
    file or the points say (core.assemble's precedence rule).

    ``path`` may pick one scan of an E57 file: ``site.e57#3`` or ``site.e57#NAME`` (core.e57).
    Raises InputError with a message naming the file for anything unreadable or degenerate.
    """
    path, selector = split_selection(path)
    check_scan_file(path)
    units = None if units is None else units_name(units, "units")
    given = Given(viewpoint=viewpoint, units=units, kind=scan_kind(kind), name=name)
    return assemble(read_raw(path, selector), given)


# Two scans are read side by side (the target on a thread while this thread reads the source; the readers,
# the points' checks and the k-d tree let go of the GIL for most of it) when their files together are at most
# this many bytes and the memory free holds PAIR_PEAK_FACTOR x their sizes: the shared Kinect pair with its
# spacings in 0.27 s instead of 0.36 s, the shared LiDAR pair in 0.060 s instead of 0.076 s (medians of five,
# load 1.3-1.8). Larger
# files are read one after the other, so that each one's memory check (core.files) sees the memory the other
# one has taken. PAIR_PEAK_FACTOR: the peak measured reading a 1M-point float32 file (11.6 x its size).
PAIR_SIDE_BY_SIDE_BYTES = 256 * 2**20
PAIR_PEAK_FACTOR = 12


def load_pair(source: str | Path, target: str | Path, source_viewpoint: np.ndarray | None = None,
              target_viewpoint: np.ndarray | None = None, kind: ScanKind | str | None = None) -> tuple[Scan, Scan]:
    """(source, target): :func:`load_scan` of both paths (each with its ``viewpoint`` override, both with
    ``kind``), read side by side where they are small enough (module notes above). A file that cannot be read
    raises as read in turn would: the source's error first."""
    def one(path, viewpoint):
        scan = load_scan(path, viewpoint=viewpoint, kind=kind)
        # its point spacing (and the k-d tree it is measured on) here, on this file's thread: every pair asks for
        # both scans' spacings next (core.scan.scale_mismatch); a scan whose sidecar states its kind and units
        # has not measured it yet (a 270k-point RGB-D fragment: 0.15 s). (A panorama's spherical image made here as
        # well was no faster: the shared LiDAR pair 0.687 s median of 11 against 0.653 without, 0.624 against 0.642 of
        # 5 on an earlier hour: the two threads then hold the GIL in turn.)
        _ = scan.spacing
        return scan

    sizes = []
    for path in (source, target):
        try:
            sizes.append(Path(split_selection(path)[0]).stat().st_size)
        except OSError:
            sizes.append(None)  # load_scan says why
    free = memory_available()
    small = (None not in sizes and sum(sizes) <= PAIR_SIDE_BY_SIDE_BYTES
             and (free is None or PAIR_PEAK_FACTOR * sum(sizes) <= free))
    if not small:
        return one(source, source_viewpoint), one(target, target_viewpoint)
    # a daemon thread, not an executor (which waits for its thread on the way out): when the source cannot be
    # read, or a signal stops the command, the error comes at once, not after the target's whole read (a bad
    # source beside a 110 MB text target: 19 s; SIGINT while the target was read: 13 s); the abandoned read
    # ends with the process
    read: list = []  # (scan, None) or (None, what reading the target raised)

    def read_target() -> None:
        try:
            read.append((one(target, target_viewpoint), None))
        except BaseException as exc:  # noqa: BLE001 - raised below, in the caller's thread
            read.append((None, exc))

    reader = threading.Thread(target=read_target, name="load-target", daemon=True)
    reader.start()
    first = one(source, source_viewpoint)
    reader.join()
    second, error = read[0]
    if error is not None:
        raise error
    return first, second


def read_raw(path: str | Path, selector: str | None = None) -> RawScan:
    """What the scan file ``path`` holds (core.assemble.RawScan), any format; ``selector`` picks an
    E57 file's scan. Raises InputError naming the file."""
    path = Path(path)
    what = str(path)
    suffix = path.suffix.lower()
    if suffix == E57_SUFFIX:
        return read_e57_raw(path, selector)
    if suffix in LAS_SUFFIXES:
        return read_las_raw(path)
    try:
        if suffix == ".ply":
            return _load_ply(path)
        if suffix == ".pcd":
            return _load_pcd(path)
        if suffix in MESH_FORMATS:
            return _load_mesh(path)
        if suffix == BIN_SUFFIX:
            return _load_bin(path)
        return RawScan(_load_text(path), what, path.stem, sidecar=path)
    except InputError:
        raise
    except (PlyError, ValueError, KeyError, IndexError, OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{what}: cannot read it as {suffix[1:].upper()} ({exc})") from None


def check_scan_file(path: str | Path) -> None:
    """What can be known of a scan file without reading it: a regular file (not a FIFO, a device, a folder,
    a link loop), of a known format, not empty, and small enough for the memory free now (core.files).
    ``path`` may pick one scan of an E57 file (``site.e57#3``): the file is checked. Raises InputError
    naming the file."""
    path, _ = split_selection(path)
    what = str(path)
    st = stat_regular(path, what, "a scan file")
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise InputError(f"{what}: unsupported format {suffix or '(no extension)'!r}; "
                         f"use one of {', '.join(FORMATS)}")
    if st.st_size == 0:
        raise InputError(f"{what}: the file is empty")
    # E57 and LAS hold binary records; a LAZ decompresses about as much as text parses
    binary = (".ply", ".pcd", ".stl", ".e57", ".las", BIN_SUFFIX)
    check_memory(st.st_size, BINARY_FACTOR if suffix in binary else TEXT_FACTOR, what, st)


def _load_ply(path: Path) -> RawScan:
    data, info = read_ply(path)
    if "vertex" not in data:
        raise InputError(f"{path}: the PLY file has no vertex element")
    v = data["vertex"]
    if not all(k in v and not isinstance(v[k], tuple) for k in "xyz"):
        raise InputError(f"{path}: the PLY vertices have no x, y, z properties")
    pts = np.c_[v["x"], v["y"], v["z"]].astype(np.float64)
    if len(pts) == 0:
        rest = ", ".join(f"{_rows(e)} {n} rows" for n, e in data.items() if n != "vertex" and e)
        raise InputError(f"{path}: the PLY file holds no vertices (element vertex 0){'; only ' + rest if rest else ''}")
    grid_idx = None
    if "range_grid" in data:
        counts, flat = _list_property(data["range_grid"], "range_grid", path)
        rows, cols = (_whole(info.get(k, "0"), k, path) for k in ("num_rows", "num_cols"))
        if rows * cols != len(counts):
            raise InputError(f"{path}: range_grid has {len(counts)} cells but the header says {rows} x {cols}")
        g = np.full(len(counts), -1, dtype=np.int64)
        first = np.cumsum(counts) - counts
        has = counts > 0
        g[has] = flat[first[has]]
        if g.max(initial=-1) >= len(pts):
            raise InputError(f"{path}: range_grid refers to vertex {g.max()} of {len(pts)}")
        grid_idx = g.reshape(rows, cols)
    faces = None
    if "face" in data and data["face"]:
        counts, flat = _list_property(data["face"], "face", path)
        faces = _triangulate_polygons(counts, flat)
        if faces.size and (faces.max() >= len(pts) or faces.min() < 0):
            bad = faces.max() if faces.max() >= len(pts) else faces.min()
            raise InputError(f"{path}: a face refers to vertex {bad}; the file has vertices 0 to {len(pts) - 1}")
    intensity = _intensity(v, len(pts))
    return RawScan(pts, str(path), path.stem, grid=grid_idx, grid_faces_sensor=True, faces=faces,
                   intensity=intensity, sidecar=path)


def _intensity(fields: dict, n: int) -> np.ndarray | None:
    """(n,) float64 of a per-point ``intensity`` (or ``scalar_intensity``) property, else None."""
    for key in ("intensity", "scalar_intensity", "Intensity"):
        value = fields.get(key)
        if value is not None and not isinstance(value, tuple) and len(value) == n:
            return np.asarray(value, dtype=np.float64).reshape(n)
    return None


def _whole(text: str, name: str, path: Path) -> int:
    if not text.isdigit():
        raise InputError(f"{path}: obj_info {name} {text!r} is not a whole number")
    return int(text)


def _rows(element: dict) -> int:
    """The rows of a read PLY element (a list property is (counts, flat))."""
    first = next(iter(element.values()))
    return len(first[0]) if isinstance(first, tuple) else len(first)


def _list_property(element: dict, name: str, path: Path):
    """(counts, flat) of the vertex-index list of a face or range_grid element; refused when it has none."""
    lists = {k: v for k, v in element.items() if isinstance(v, tuple)}
    if not lists:
        raise InputError(f"{path}: element {name} has no list property (such as "
                         f"'property list uchar int vertex_indices'), found {', '.join(element) or 'no property'}")
    return lists.get("vertex_indices", lists.get("vertex_index", next(iter(lists.values()))))


def _triangulate_polygons(counts, flat) -> np.ndarray:
    if len(counts) and np.all(counts == 3):
        return flat.reshape(-1, 3)
    if len(counts) and counts[0] > 3 and np.all(counts == counts[0]):  # all quads (say): fans, vectorised
        poly = flat.reshape(len(counts), int(counts[0]))
        k = poly.shape[1]
        return np.stack([np.broadcast_to(poly[:, :1], (len(poly), k - 2)), poly[:, 1:-1], poly[:, 2:]],
                        axis=2).reshape(-1, 3)
    tris, pos = [], 0
    for k in counts:
        poly = flat[pos:pos + k]
        tris += [(poly[0], poly[i], poly[i + 1]) for i in range(1, k - 1)]
        pos += k
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4",
              ("I", 8): "i8", ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def _load_pcd(path: Path) -> RawScan:
    with open_regular(path, str(path), "a scan file") as f:
        raw = f.read()
    header, pos = {}, 0
    while True:
        nl = raw.find(b"\n", pos)
        if nl < 0 or pos > HEADER_LIMIT:
            raise InputError(f"{path}: not a PCD file (no DATA line)")
        line = raw[pos:nl].decode("ascii", errors="replace").strip()
        pos = nl + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
    mode = header["DATA"][0].lower() if header["DATA"] else ""
    fields, sizes, types, counts, n = _pcd_layout(header, path, mode)
    row = sum(s * c for s, c in zip(sizes, counts))
    if mode == "binary" and pos + n * row != len(raw):
        raise InputError(f"{path}: the header says {n} points of {row} bytes ({n * row} bytes) but "
                         f"{len(raw) - pos} bytes follow it")
    if mode == "ascii":
        text = raw[pos:].decode("ascii").split()
        if len(text) != n * sum(counts):
            raise InputError(f"{path}: the header says {n} points of {sum(counts)} numbers but {len(text)} numbers "
                             "follow it")
        arr = np.array(text, dtype=np.float64).reshape(n, sum(counts))
        offs = np.cumsum([0] + counts)
        pts = np.c_[[arr[:, offs[fields.index(a)]] for a in "xyz"]].T
    elif mode == "binary":
        dt = np.dtype([(f, "<" + _PCD_TYPES[(t, s)], (c,)) if c > 1 else (f, "<" + _PCD_TYPES[(t, s)])
                       for f, s, t, c in zip(fields, sizes, types, counts)])
        arr = np.frombuffer(raw, dtype=dt, count=n, offset=pos)
        pts = np.c_[arr["x"], arr["y"], arr["z"]].astype(np.float64)
    elif mode == "binary_compressed":
        pts = _load_compressed_pcd(path, raw, pos, n, row)
        n = len(pts)
    else:
        raise InputError(f"{path}: unsupported PCD DATA mode {mode!r}")
    intensity = None
    if mode == "binary" and "intensity" in fields:
        intensity = _intensity({"intensity": np.asarray(arr["intensity"]).reshape(len(arr), -1)[:, 0]}, len(pts))
    elif mode == "ascii" and "intensity" in fields:
        intensity = arr[:, offs[fields.index("intensity")]]
    vp, rotation = _pcd_viewpoint(header.get("VIEWPOINT"), path)
    default = vp is not None and [float(x) for x in header["VIEWPOINT"]] == [0, 0, 0, 1, 0, 0, 0]  # PCL's and Open3D's
    grid_idx = None
    w, h = int(header.get("WIDTH", [n])[0]), int(header.get("HEIGHT", ["1"])[0])
    if h > 1 and w * h == len(pts):
        grid_idx = np.arange(len(pts)).reshape(h, w)  # row-major; NaN cells are emptied by the assembly
    return RawScan(pts, str(path), path.stem, grid=grid_idx, viewpoint=vp, viewpoint_label="VIEWPOINT",
                   viewpoint_default=default, viewpoint_pose=vp is not None, sensor_rotation=rotation,
                   intensity=intensity, sidecar=path)


def _pcd_layout(header: dict, path: Path, mode: str) -> tuple[list[str], list[int], list[str], list[int], int]:
    """A PCD header's fields, sizes, types and counts (one each a field) and its number of points, checked:
    InputError naming what is wrong, where the file's own numbers disagree or name no type PCD has."""
    fields = header.get("FIELDS")
    if not fields or not all(f in fields for f in "xyz"):
        raise InputError(f"{path}: the PCD file has no x y z fields")
    twice = sorted({f for f in fields if fields.count(f) > 1})
    if twice:
        raise InputError(f"{path}: the PCD header names the field {twice[0]!r} more than once")
    k = len(fields)

    def whole(key: str, default: list[str]) -> list[int]:
        values = header.get(key, default)
        try:
            return [int(v) for v in values]
        except ValueError:
            raise InputError(f"{path}: the PCD header's {key} should hold whole numbers, found "
                             f"{' '.join(values)[:40]!r}") from None

    sizes, counts = whole("SIZE", ["4"] * k), whole("COUNT", ["1"] * k)
    types = [t.upper() for t in header.get("TYPE", ["F"] * k)]
    if not len(sizes) == len(types) == len(counts) == k:
        raise InputError(f"{path}: the PCD header names {k} FIELDS but gives {len(sizes)} SIZE, {len(types)} TYPE "
                         f"and {len(counts)} COUNT values")
    for f, t, size in zip(fields, types, sizes):
        if (t, size) not in _PCD_TYPES:
            raise InputError(f"{path}: the PCD field {f!r} has TYPE {t} and SIZE {size}, no number type of PCD's "
                             "(F of 4 or 8 bytes, I or U of 1, 2, 4 or 8)")
    if any(c < 1 for c in counts):
        raise InputError(f"{path}: the PCD header's COUNT values must be at least 1, found {counts}")
    if mode == "binary_compressed" and any((types[fields.index(a)], sizes[fields.index(a)]) != ("F", 4) for a in "xyz"):
        raise InputError(f"{path}: a compressed PCD is read (by Open3D) with x, y and z as 4-byte floats (TYPE F, "
                         "SIZE 4) only; save it uncompressed (DATA binary) or as float32")
    points = whole("POINTS", []) if "POINTS" in header else []
    width, height = whole("WIDTH", []) if "WIDTH" in header else [], whole("HEIGHT", ["1"])
    if not points and not width:
        raise InputError(f"{path}: the PCD header gives neither POINTS nor WIDTH: no number of points")
    n = points[0] if points else width[0] * height[0]
    if n < 0 or (width and (width[0] < 0 or height[0] < 0)):
        raise InputError(f"{path}: the PCD header gives a negative number of points")
    if points and width and points[0] != width[0] * height[0]:
        raise InputError(f"{path}: the PCD header says POINTS {points[0]} but WIDTH x HEIGHT {width[0]} x {height[0]}")
    return fields, sizes, types, counts, n


def _pcd_viewpoint(values: list[str] | None, path: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A PCD's ``VIEWPOINT tx ty tz qw qx qy qz``: the sensor's position (3,) in the cloud's frame and its
    orientation (3, 3) (the points are stored as they are, not turned by it); (None, None) without one."""
    if values is None:
        return None, None
    try:
        tx, ty, tz, qw, qx, qy, qz = (float(x) for x in values)
    except ValueError:
        raise InputError(f"{path}: VIEWPOINT should be 7 numbers 'tx ty tz qw qx qy qz', found "
                         f"{' '.join(values)[:60]!r}") from None
    R = quaternion_matrix(np.array([qx, qy, qz, qw]))
    if R is None:
        raise InputError(f"{path}: VIEWPOINT's quaternion (qw qx qy qz) {[qw, qx, qy, qz]} is not a rotation")
    return np.array([tx, ty, tz]), R


def _load_compressed_pcd(path: Path, raw: bytes, pos: int, n: int, row: int) -> np.ndarray:
    """(n, 3) points of a PCD's LZF-compressed body at ``raw[pos:]`` (two uint32 sizes, then the data),
    decompressed by Open3D once its sizes agree with the header; Open3D's warnings stay off the console."""
    import open3d as o3d

    if len(raw) < pos + 8:
        raise InputError(f"{path}: the file ends before its compressed data starts")
    packed, unpacked = (int(v) for v in np.frombuffer(raw, "<u4", 2, pos))
    if unpacked != n * row:
        raise InputError(f"{path}: the compressed data says it unpacks to {unpacked} bytes, but the header's "
                         f"{n} points of {row} bytes take {n * row}")
    if pos + 8 + packed > len(raw):
        raise InputError(f"{path}: the file ends inside the compressed data ({packed} bytes announced, "
                         f"{len(raw) - pos - 8} present)")
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pts = np.asarray(o3d.io.read_point_cloud(str(path), format="pcd").points, dtype=np.float64)
    if n and not len(pts):
        raise InputError(f"{path}: the compressed data is corrupt (it does not decompress as LZF)")
    return pts


# A KITTI Velodyne frame is nothing but records of four little-endian float32 (x, y, z in metres, reflectance); a
# nuScenes LiDAR sweep (``*.pcd.bin``) of five (x, y, z, intensity, ring). The file says nothing else, so what would
# tell another ``.bin`` apart is checked: whole records, a nuScenes ring a whole number, and points no farther than a
# spinning LiDAR reaches (a few beyond are dropped and said, as glitches; more, and it is no LiDAR frame).
BIN_LAYOUTS = {"KITTI Velodyne": ("x, y, z, reflectance", 4), "nuScenes LiDAR": ("x, y, z, intensity, ring", 5)}
BIN_REACH = 1000.0  # metres: a point farther than this is no spinning LiDAR's return (KITTI's HDL-64 reaches 120 m)
BIN_RINGS = 128  # a nuScenes ring index is a whole number below this (its LiDAR has 32)
# A nuScenes sweep holds the car's own roof and body within this of the sensor (the devkit's remove_close(1.0) drops
# them): they sit still in the sensor's frame in every sweep and would pull odometry towards the identity
NUSCENES_EGO = 1.0  # metres


def _rings_in(records: np.ndarray) -> bool:
    """Whether the last column of (N, 5) float32 records holds ring indices: whole numbers in [0, BIN_RINGS)."""
    ring = records[:, -1]
    return bool(len(ring)) and bool(np.all((ring >= 0) & (ring < BIN_RINGS) & (ring == np.round(ring))))


def _load_bin(path: Path) -> RawScan:
    layout = "nuScenes LiDAR" if path.name.lower().endswith(".pcd.bin") else "KITTI Velodyne"
    fields, width = BIN_LAYOUTS[layout]
    with open_regular(path, str(path), "a scan file") as f:
        raw = f.read()
    if len(raw) % (4 * width):
        raise InputError(f"{path}: not a {layout} file: {len(raw)} bytes is not a whole number of {4 * width}-byte "
                         f"records (float32 {fields})")
    with np.errstate(invalid="ignore"):  # a signalling NaN among the floats is just a NaN here
        records = np.frombuffer(raw, dtype="<f4").reshape(-1, width)
        if width == 5 and not _rings_in(records):
            raise InputError(f"{path}: not a nuScenes LiDAR sweep: its fifth float32 a point (the ring) is not a whole "
                             f"number below {BIN_RINGS}; a KITTI Velodyne frame (four float32) is read from a .bin "
                             f"not named *.pcd.bin")
        if width == 4 and len(raw) % 20 == 0 and _rings_in(np.frombuffer(raw, dtype="<f4").reshape(-1, 5)):
            raise InputError(f"{path}: this looks like a nuScenes LiDAR sweep (five float32 a point, the fifth a ring "
                             f"index), not a KITTI Velodyne frame (four): name it *.pcd.bin")
        rec = records.astype(np.float64)
    xyz = rec[:, :3].copy()
    finite = np.isfinite(xyz).all(axis=1)
    with np.errstate(invalid="ignore", over="ignore"):
        reach = norms(np.where(finite[:, None], xyz, 0.0))  # from the sensor (0 where not finite)
    far = finite & ~(reach <= BIN_REACH)
    notes = [f"read as a {layout} file: {len(rec)} records of float32 {fields}"]
    if width == 5:
        ego = finite & (reach < NUSCENES_EGO)
        if ego.any():
            xyz[ego] = np.nan
            notes.append(f"{ego.sum()} points within {NUSCENES_EGO:g} m of the sensor (the car itself) dropped")
    if far.any():
        if far.sum() > 0.01 * finite.sum():
            raise InputError(f"{path}: not a {layout} file (float32 {fields}, metres): {far.sum()} of "
                             f"{finite.sum()} points lie more than {BIN_REACH:g} m from the sensor")
        xyz[far] = np.nan  # dropped and counted with the non-finite (core.assemble)
        notes.append(f"{far.sum()} points more than {BIN_REACH:g} m from the sensor dropped")
    return RawScan(xyz, str(path), path.stem, units_convention="m", intensity=rec[:, 3], sidecar=path,
                   notes=tuple(notes))


def _load_text(path: Path) -> np.ndarray:
    """(N, 3) from lines of x y z (more columns ignored). In a Leica ``.pts`` a line holding one whole
    number is the count of the rows that follow it (a file may hold several such blocks)."""
    rows, announced = [], []
    pts = path.suffix.lower() == ".pts"
    with open_regular(path, str(path), "a scan file") as f:
        text = f.read().decode("utf-8")
    for lineno, line in enumerate(text.splitlines(), 1):
        s = line.strip()
        if not s or s[0] in "#/%":
            continue
        tok = re.split(r"[,;\s]+", s)
        if pts and len(tok) == 1 and tok[0].isdigit():
            announced.append((lineno, int(tok[0]), len(rows)))
            continue
        try:
            vals = [float(t) for t in tok[:3]]
        except ValueError:
            if not rows:  # a header line such as "x,y,z"
                continue
            raise InputError(f"{path}: line {lineno} is not 'x y z' numbers: {s[:60]!r}") from None
        if len(vals) < 3:
            raise InputError(f"{path}: line {lineno} has {len(vals)} numbers, expected x y z")
        rows.append(vals)
    for k, (lineno, count, first) in enumerate(announced):
        held = (announced[k + 1][2] if k + 1 < len(announced) else len(rows)) - first
        if held != count:
            raise InputError(f"{path}: line {lineno} announces {count} points but {held} rows follow it")
    if not rows:
        raise InputError(f"{path}: holds no x y z lines")
    return np.asarray(rows, dtype=np.float64)


def _load_mesh(path: Path) -> RawScan:
    import trimesh

    # an OBJ's vertices all, in the file's order, faces or none: trimesh's OBJ reader otherwise keeps only the
    # vertices faces use (one face of 1600 vertices read as 3 points; a file of vertices alone as none)
    keep = {"maintain_order": True} if path.suffix.lower() == ".obj" else {}
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):  # trimesh's texture code warns on odd UVs
            warnings.simplefilter("ignore")
            mesh = trimesh.load(str(path), process=False, **keep)  # a regular file: load_scan checked it
            verts, faces = _mesh_arrays(mesh)
            if verts is None:  # materials that do not share one vertex list: trimesh's one mesh of them
                verts, faces = _mesh_arrays(trimesh.load(str(path), force="mesh", process=False))
    except Exception as exc:  # trimesh raises many kinds on corrupt files
        raise InputError(f"{path}: cannot read it as a mesh ({type(exc).__name__}: {exc})") from None
    if len(verts) == 0:
        raise InputError(f"{path}: the mesh has no vertices")
    return RawScan(verts, str(path), path.stem, faces=faces if len(faces) else None, sidecar=path)


def _mesh_arrays(mesh) -> tuple[np.ndarray | None, np.ndarray]:
    """(V, 3) vertices and (F, 3) faces of what trimesh loaded; (None, _) for a Scene (one part per material) whose
    parts do not all hold the same vertices (kept in order, each part holds the whole list: faces are joined)."""
    import trimesh

    if isinstance(mesh, trimesh.Scene):
        parts = list(mesh.geometry.values())
        first = np.asarray(getattr(parts[0], "vertices", np.zeros((0, 3))), dtype=np.float64) if parts else None
        if first is None or any(np.asarray(getattr(g, "vertices", ())).shape != first.shape
                                or not np.array_equal(np.asarray(g.vertices), first) for g in parts[1:]):
            return None, np.zeros((0, 3), dtype=np.int64)
        faces = [np.asarray(getattr(g, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3) for g in parts]
        return first, np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    verts = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), dtype=np.float64)
    return verts, np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)


def save_scan(path: str | Path, scan: Scan) -> None:
    """Write a scan as PLY (a Stanford range-grid PLY when it has a grid) plus its JSON sidecar."""
    path = Path(path)
    if scan.grid is not None:
        write_range_grid_ply(path, scan.points, scan.grid.index, comments=(f"rangereg scan {scan.name}",))
    else:
        write_ply(path, scan.points, scan.faces)
    write_sidecar(path, scan)


def load_scans(paths: Sequence[str | Path], kind: ScanKind | str | None = None) -> list[Scan]:
    """The scans ``paths`` name, in order: every scan of an E57 given without ``#``, one scan for any
    other path (:func:`load_scan`); ``kind`` overrides each file's. Names shared by scans of different
    files are made distinct by the file's stem (``site:Scan 0``)."""
    scans: list[Scan] = []
    for p in paths:
        file, selector = split_selection(p)
        if file.suffix.lower() == E57_SUFFIX and selector is None:
            scans += read_e57_all(file, kind=kind)
        else:
            scans.append(load_scan(p, kind=kind))
    names = [s.name for s in scans]
    clash = {n for n in names if names.count(n) > 1}
    if clash:
        scans = [replace(s, name=f"{Path(s.source.split('#')[0]).stem}:{s.name}") if s.name in clash and s.e57
                 else s for s in scans]
    return scans
