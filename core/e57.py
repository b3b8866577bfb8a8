"""E57 files (ASTM E2807) read and written through pye57's binding of libE57Format.

One file holds many scans ("data3D" entries). Each becomes a :class:`core.scan.Scan`:

- **Frames.** An E57 scan stores its points in its own frame (the scanner's: spherical coordinates
  are measured about its origin) and its ``pose`` maps that frame into the file's:
  ``T_world_scan``. We keep the points as stored (pye57's ``read_scan`` would apply the pose; we
  read the raw fields instead), the pose as the scan's rough pose (``Scan.guess``), and the sensor
  at the scan frame's origin, (0, 0, 0), as its viewpoint (from the file). A scan without a pose
  gets no guess. The Scan is made by core.assemble (a scan all around its sensor is a panorama).
- **Points**: cartesianX/Y/Z, or sphericalRange/Azimuth/Elevation turned into x, y, z
  (``x = r cos(el) cos(az)``, ``y = r cos(el) sin(az)``, ``z = r sin(el)``, the standard's).
  Records flagged by ``cartesianInvalidState`` / ``sphericalInvalidState`` (not 0) are left out.
  Units are metres (the standard's).
- **Grid**: rowIndex/columnIndex, when both are present, become the :class:`RangeGrid` (rows and
  columns counted from their smallest value; where a cell holds several returns the first record
  wins), mirrored by the assembly if need be so that ``cross(d/dcol, d/drow)`` faces the sensor (the
  grid's convention, core/scan.py). The surface is then triangulated on the grid, as for a PLY range grid.
- **Intensity**, when present, is kept in ``Scan.intensity`` ((N,) float64, NaN where
  ``isIntensityInvalid``); nothing in the registration uses it. ``Scan.e57`` names the file and scan.

Choosing scans: ``site.e57#3`` is the scan at index 3, counted from 0 as the file stores them (the
order ``info`` lists); ``site.e57#NAME`` the scan of that name (a selector of digits only is always
an index). A file of one scan needs no selector.

Writing registered poses back: core/e57_write.py.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .assemble import RawScan
from .errors import InputError
from .scan import E57Record, Scan, ScanKind
from .transforms import quaternion_matrix

SUFFIX = ".e57"
CARTESIAN = ("cartesianX", "cartesianY", "cartesianZ")
SPHERICAL = ("sphericalRange", "sphericalAzimuth", "sphericalElevation")
# A grid of more cells than this (8 bytes each: 3.2 GB) is not built and the points are read without it:
# such indices are damage, or a scan far beyond what the registration handles (20k x 20k cells).
GRID_CELLS_MAX = 400_000_000
# 64-bit integer buffers as numpy's "q" (long long): pye57's binding takes the buffer format "l", numpy's
# int64 on Linux, for 32 bits (measured: every other value read back 0)
INT64 = "q"
_LISTED = 8  # scans named in an error that asks which one


@dataclass(frozen=True, eq=False)
class E57Entry:
    """One scan of a file, from its header alone. structured: it has rowIndex and columnIndex; grid:
    their (rows, cols) from the header's indexBounds, or None; pose: (4, 4) T_world_scan or None;
    coordinates: "cartesian", "spherical" or the fields it has instead."""

    index: int
    name: str
    points: int
    coordinates: str
    structured: bool
    grid: tuple[int, int] | None
    pose: np.ndarray | None
    intensity: bool

    def label(self) -> str:
        return f"#{self.index}" + (f" {self.name!r}" if self.name else "")

    def __repr__(self) -> str:
        grid = "x".join(map(str, self.grid)) if self.grid else ("yes" if self.structured else "no")
        return (f"E57Entry({self.label()}, {self.points} points, {self.coordinates}, grid={grid}, "
                f"pose={'yes' if self.pose is not None else 'no'})")


# ---- selection syntax ----

def split_selection(path: str | Path) -> tuple[Path, str | None]:
    """``"site.e57#3"`` -> (Path("site.e57"), "3"); anything else -> (Path(path), None).

    A path that exists as written is never split (a file may have '#' in its name)."""
    text = str(path)
    head, sep, selector = text.rpartition("#")
    if not sep or not head.lower().endswith(SUFFIX) or Path(text).exists():
        return Path(text), None
    return Path(head), selector


def choose(entries: Sequence[E57Entry], selector: str | None, path: Path) -> int:
    """The index of the scan ``selector`` names (see the module notes); raises InputError."""
    n = len(entries)
    if selector is None:
        if n == 1:
            return 0
        listed = ", ".join(e.label() for e in entries[:_LISTED]) + (", ..." if n > _LISTED else "")
        raise InputError(f"{path} holds {n} scans ({listed}); pick one with {path}#K (K from 0 to {n - 1}) "
                         f"or {path}#NAME ('rangereg info {path}' lists them)")
    sel = selector.strip()
    if not sel:
        raise InputError(f"{path}#: name a scan after '#': an index from 0 to {n - 1} or a scan's name")
    if sel.isascii() and sel.isdigit():
        k = int(sel)
        if k >= n:
            raise InputError(f"{path}#{selector}: no scan #{k}; the file holds {n} scan{'s' * (n != 1)}, "
                             f"#0 to #{n - 1} (counted from 0)")
        return k
    matches = [e.index for e in entries if e.name == sel] or [e.index for e in entries if e.name.lower() == sel.lower()]
    if len(matches) == 1:
        return matches[0]
    names = ", ".join(repr(e.name) for e in entries[:_LISTED] if e.name) or "none has a name"
    if matches:
        raise InputError(f"{path}#{selector}: {len(matches)} scans share that name; pick one by index "
                         f"({', '.join(f'#{k}' for k in matches)})")
    raise InputError(f"{path}#{selector}: no scan of that name (names: {names}); or pick by index, #0 to #{n - 1}")


def selector_for(entry: E57Entry, entries: Sequence[E57Entry]) -> str:
    """What to write after '#' to pick ``entry``: its name when that picks it alone, else its index."""
    name = entry.name
    clean = name and name == name.strip() and "#" not in name and not (name.isascii() and name.isdigit())
    return name if clean and sum(e.name.lower() == name.lower() for e in entries) == 1 else str(entry.index)


# ---- errors ----

_EXPLAIN = {
    "ErrorBadFileLength": "the file is cut short or padded: its header gives another length",
    "ErrorBadFileSignature": "not an E57 file (no E57 signature)",
    "ErrorBadChecksum": "the file is corrupt (a page checksum does not match)",
    "ErrorReadFailed": "the file ends early (truncated?)",
    "ErrorOpenFailed": "cannot open it",
    "ErrorBadCVPacket": "the point data is corrupt",
    "ErrorBadCVHeader": "the point data is corrupt",
    "ErrorXMLParser": "its XML header is corrupt",
    "ErrorBadXMLFormat": "its XML header is corrupt",
    "ErrorUnknownFileVersion": "an E57 version this library does not know",
}


def _explain(exc: BaseException) -> str:
    """One line from a libE57 exception (its text runs over many lines of debug context)."""
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    code = re.search(r"\((Error\w+)\)", text)
    if code and code.group(1) in _EXPLAIN:
        return f"{_EXPLAIN[code.group(1)]}; libE57: {code.group(1)}"
    return text


@contextmanager
def translated(what: str, doing: str = "read it as E57") -> Iterator[None]:
    """libE57's C++ exceptions (and pye57's) as one InputError naming ``what``."""
    from pye57 import libe57

    try:
        yield
    except InputError:
        raise
    except libe57.E57Exception as exc:
        raise InputError(f"{what}: cannot {doing} ({_explain(exc)})") from None
    except (ValueError, TypeError, KeyError, IndexError, RuntimeError, OSError) as exc:
        raise InputError(f"{what}: cannot {doing} ({type(exc).__name__}: {_explain(exc)})") from None


@contextmanager
def _open(path: Path) -> Iterator[object]:
    from pye57 import libe57

    imf = None
    with translated(str(path)):
        try:
            imf = libe57.ImageFile(str(path), "r")
            if not imf.root().isDefined("data3D"):
                raise InputError(f"{path}: the E57 file has no data3D section (no scans)")
            yield imf
        finally:
            if imf is not None:
                imf.close()


# ---- reading ----

def scan_nodes(imf) -> list:
    from pye57 import libe57

    data3d = libe57.VectorNode(imf.root().get("data3D"))
    return [libe57.StructureNode(data3d.get(k)) for k in range(data3d.childCount())]


def _child(node, name: str):
    from pye57.utils import get_node

    return get_node(node, name) if node.isDefined(name) else None


def _number(node, name: str, default: float) -> float:
    from pye57 import libe57

    n = _child(node, name)
    if n is None:
        return default
    return float(n.scaledValue() if isinstance(n, libe57.ScaledIntegerNode) else n.value())


def text_of(node, name: str) -> str:
    n = _child(node, name)
    return str(n.value()) if n is not None and hasattr(n, "value") else ""


def _pose(scan, what: str) -> np.ndarray | None:
    """T_world_scan from a data3D's pose (unit quaternion w, x, y, z and a translation), or None."""
    if not scan.isDefined("pose"):
        return None
    pose = _child(scan, "pose")
    q = np.array([1.0, 0.0, 0.0, 0.0])
    t = np.zeros(3)
    if pose.isDefined("rotation"):
        rot = _child(pose, "rotation")
        q = np.array([_number(rot, k, d) for k, d in (("w", 1.0), ("x", 0.0), ("y", 0.0), ("z", 0.0))])
    if pose.isDefined("translation"):
        tr = _child(pose, "translation")
        t = np.array([_number(tr, k, 0.0) for k in "xyz"])
    R = quaternion_matrix(np.r_[q[1:], q[0]])
    if R is None or not np.all(np.isfinite(t)):
        raise InputError(f"{what}: its pose is not a rigid transform (quaternion {q.tolist()}, "
                         f"translation {t.tolist()})")
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _fields(points_node) -> list[str]:
    from pye57 import libe57

    proto = libe57.StructureNode(points_node.prototype())
    return [proto.get(i).elementName() for i in range(proto.childCount())]


def _coordinates(fields: list[str]) -> str:
    if all(f in fields for f in CARTESIAN):
        return "cartesian"
    if all(f in fields for f in SPHERICAL):
        return "spherical"
    return "none of cartesianX/Y/Z or sphericalRange/Azimuth/Elevation (fields: " + ", ".join(fields) + ")"


def _entry(scan, k: int, what: str) -> E57Entry:
    from pye57 import libe57

    points = libe57.CompressedVectorNode(scan.get("points")) if scan.isDefined("points") else None
    fields = _fields(points) if points is not None else []
    grid, structured = None, "rowIndex" in fields and "columnIndex" in fields
    if structured and scan.isDefined("indexBounds"):
        b = _child(scan, "indexBounds")
        rows = _number(b, "rowMaximum", 0) - _number(b, "rowMinimum", 0) + 1
        cols = _number(b, "columnMaximum", 0) - _number(b, "columnMinimum", 0) + 1
        grid = (int(rows), int(cols)) if rows > 1 and cols > 1 else None
    return E57Entry(k, text_of(scan, "name"), points.childCount() if points is not None else 0,
                    _coordinates(fields) if fields else "no points", structured, grid, _pose(scan, what),
                    "intensity" in fields)


def list_scans(path: str | Path) -> list[E57Entry]:
    """Every scan of an E57 file from the headers (cheap: no point is read)."""
    path = Path(path)
    check_file(path)
    with _open(path) as imf, translated(str(path)):
        return [_entry(s, k, f"{path}#{k}") for k, s in enumerate(scan_nodes(imf))]


def count_scans(path: str | Path) -> int:
    """How many scans ``path`` names: all of an E57's without a selector, else 1."""
    file, selector = split_selection(path)
    if file.suffix.lower() != SUFFIX or selector is not None:
        return 1
    return len(list_scans(file))


def check_file(path: Path) -> None:
    """Refuse, before opening it, a path that is missing, not a regular file (a folder, a FIFO), or empty."""
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not path.is_file():
        raise InputError(f"{path}: is {'a folder' if path.is_dir() else 'not a regular file'}, not a scan file")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: the file is empty")


def _read_fields(imf, points_node, wanted: dict[str, str], n: int) -> dict[str, np.ndarray]:
    """Read the fields named in ``wanted`` (field -> numpy dtype) of all ``n`` records, scaled."""
    from pye57 import libe57

    data, bufs = {}, libe57.VectorSourceDestBuffer()
    for name, dtype in wanted.items():
        data[name] = np.empty(n, dtype)
        bufs.append(libe57.SourceDestBuffer(imf, name, data[name], n, True, True))
    reader = points_node.reader(bufs)
    try:
        got = reader.read()
    finally:
        reader.close()
    if got != n:
        raise InputError(f"the scan's point data ends after {got} of its {n} records")
    return data


def _scan_names(entries: Sequence[E57Entry], stem: str) -> list[str]:
    """A name per scan: its own when it has one no other scan of the file shares, else ``stem#k``
    (``stem`` alone for a file of one scan)."""
    counts: dict[str, int] = {}
    for e in entries:
        counts[e.name] = counts.get(e.name, 0) + 1
    return [e.name if e.name and counts[e.name] == 1 else (stem if len(entries) == 1 else f"{stem}#{e.index}")
            for e in entries]


def _grid(rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray | None, str]:
    """The range grid (R, C) int64 of kept records (rows, cols (N,) int64), facing left to the
    assembly, and a note when none is built."""
    if len(rows) == 0:
        return None, ""
    r0, c0 = int(rows.min()), int(cols.min())
    R, C = int(rows.max()) - r0 + 1, int(cols.max()) - c0 + 1
    if R < 2 or C < 2:
        return None, f"rowIndex/columnIndex span {R} x {C} cells: a line, not a grid"
    if R * C > GRID_CELLS_MAX:
        return None, f"rowIndex/columnIndex span {R} x {C} cells (over {GRID_CELLS_MAX:.0e}): read without its grid"
    flat = (rows - r0) * C + (cols - c0)
    g = np.full(R * C, -1, dtype=np.int64)
    g[flat[::-1]] = np.arange(len(flat) - 1, -1, -1)  # written last to first: the first record of a cell wins
    return g.reshape(R, C), ""


def _read_one(imf, scan, entry: E57Entry, path: Path, name: str) -> RawScan:
    from pye57 import libe57

    what = f"{path}#{entry.index}"
    if entry.points == 0:
        raise InputError(f"{what}: the scan holds no points")
    if entry.coordinates not in ("cartesian", "spherical"):
        raise InputError(f"{what}: unknown coordinates: {entry.coordinates}")
    points_node = libe57.CompressedVectorNode(scan.get("points"))
    fields = _fields(points_node)
    coords = CARTESIAN if entry.coordinates == "cartesian" else SPHERICAL
    state = "cartesianInvalidState" if entry.coordinates == "cartesian" else "sphericalInvalidState"
    wanted = {f: "f8" for f in coords}
    wanted.update({f: INT64 for f in (state, "rowIndex", "columnIndex", "isIntensityInvalid") if f in fields})
    if "intensity" in fields:
        wanted["intensity"] = "f8"
    try:
        d = _read_fields(imf, points_node, wanted, entry.points)
    except InputError as exc:
        raise InputError(f"{what}: {exc}") from None
    if entry.coordinates == "cartesian":
        xyz = np.c_[d["cartesianX"], d["cartesianY"], d["cartesianZ"]]
    else:
        r, az, el = d["sphericalRange"], d["sphericalAzimuth"], d["sphericalElevation"]
        xyz = np.c_[r * np.cos(el) * np.cos(az), r * np.cos(el) * np.sin(az), r * np.sin(el)]
    valid = d[state] == 0 if state in d else np.ones(len(xyz), dtype=bool)
    finite = np.all(np.isfinite(xyz), axis=1)
    if not valid.any():
        raise InputError(f"{what}: every one of its {len(xyz)} points is flagged invalid ({state})")
    keep = valid & finite
    grid, note = (None, "")
    if "rowIndex" in d and "columnIndex" in d:
        grid, note = _grid(d["rowIndex"][keep], d["columnIndex"][keep])
    intensity = None
    if "intensity" in d:
        intensity = d["intensity"][keep]
        if "isIntensityInvalid" in d:
            intensity = np.where(d["isIntensityInvalid"][keep] == 0, intensity, np.nan)
    record = E57Record(str(path), entry.index, entry.name, entry.coordinates, int((~valid).sum()))
    # the standard's scan frame has the sensor at its origin and measures in metres; the pose is the
    # scan's placement in the file's frame, kept as its rough pose
    return RawScan(xyz[keep], what, name, grid=grid, viewpoint=np.zeros(3), guess=entry.pose, units="m",
                   intensity=intensity, e57=record, dropped=int((valid & ~finite).sum()),
                   notes=(note,) if note else ())


def read_e57_raw(path: str | Path, selector: str | None = None) -> RawScan:
    """What the scan ``selector`` names in the E57 file ``path`` holds (core.assemble.RawScan)."""
    path = Path(path)
    check_file(path)
    with _open(path) as imf, translated(str(path)):
        scans, entries = _scans_of(imf, path)
        k = choose(entries, selector, path)
        return _read_one(imf, scans[k], entries[k], path, _scan_names(entries, path.stem)[k])


def read_e57(path: str | Path, selector: str | None = None, viewpoint: np.ndarray | None = None,
             name: str | None = None) -> Scan:
    """The scan ``selector`` names in the E57 file ``path`` (None: the file's only scan).

    ``viewpoint`` (3,) in the scan's frame overrides the scan's origin. Raises InputError."""
    from .assemble import Given, assemble

    return assemble(read_e57_raw(path, selector), Given(viewpoint=viewpoint, name=name))


def _scans_of(imf, path: Path) -> tuple[list, list]:
    """The file's scan nodes and their entries (index, name, size); raises InputError when it has none."""
    scans = scan_nodes(imf)
    entries = [_entry(s, k, f"{path}#{k}") for k, s in enumerate(scans)]
    if not entries:
        raise InputError(f"{path}: the E57 file holds no scans")
    return scans, entries


def read_e57_all(path: str | Path, kind: ScanKind | str | None = None) -> list[Scan]:
    """Every scan of the E57 file ``path``, in the file's order; ``kind`` overrides what each scan says."""
    path = Path(path)
    check_file(path)
    with _open(path) as imf, translated(str(path)):
        scans, entries = _scans_of(imf, path)
        names = _scan_names(entries, path.stem)
        raws = [_read_one(imf, s, e, path, n) for s, e, n in zip(scans, entries, names)]
    from .assemble import Given, assemble, scan_kind

    given = Given(kind=scan_kind(kind))
    return [assemble(raw, given) for raw in raws]
