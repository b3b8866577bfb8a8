"""Writing scans with registered poses as one E57 file (pye57's binding of libE57Format).

Each scan read from an E57 (``Scan.e57`` names its file and index) is copied as it was:
every field of its header, its point records value for value (raw: scaled integers as their
integers, floats at their stored precision), with only its ``pose`` replaced; so the grid,
intensity, colours and timestamps are kept. A scan from another format is written as
double-precision cartesian points in a frame with its origin at the scan's viewpoint (E57 puts the
sensor at the scan's origin): ``points - viewpoint``, posed by ``T_world_scan @ Trans(viewpoint)``,
with its grid (rowIndex/columnIndex, when the grid holds every point once) and its intensity. The file's coordinateMetadata (its
coordinate reference system) is the first E57 source's. Images (``images2D``) are not carried over.
"""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .e57 import CARTESIAN, INT64, scan_nodes, text_of, translated
from .errors import InputError
from .scan import Scan

COPY_CHUNK = 1 << 20  # records per buffer when copying a scan's points into a new file


def world_poses(scans: Sequence[Scan], T_first_scan: Sequence[np.ndarray],
                T_world_first: np.ndarray | None = None) -> list[np.ndarray]:
    """Poses in the project's frame: T_world_scan = T_world_first @ T_first_scan, the first scan kept
    where ``T_world_first`` (its given initial pose) or else its stored pose places it (the frame of the
    E57 it came from); the first scan's own frame when it has neither."""
    if T_world_first is None:
        T_world_first = scans[0].guess if scans[0].guess is not None else np.eye(4)
    return [np.asarray(T_world_first, dtype=np.float64) @ np.asarray(T, dtype=np.float64) for T in T_first_scan]


def write_e57(path: str | Path, scans: Sequence[Scan], T_world_scan: Sequence[np.ndarray]) -> None:
    """Write ``scans`` with the poses ``T_world_scan`` ((4, 4) each) as one E57 file (see the module
    notes: scans from an E57 are copied record for record). Raises InputError."""
    from pye57 import libe57

    path = Path(path)
    if len(scans) != len(T_world_scan):
        raise InputError(f"{len(T_world_scan)} poses for {len(scans)} scans")
    sources: dict[str, object] = {}
    imf = None
    with translated(str(path), "write it as E57"):
        try:
            imf = libe57.ImageFile(str(path), "w")
            _write_header(imf, _coordinate_metadata(scans, sources))
            data3d = libe57.VectorNode(imf.root().get("data3D"))
            for scan, T in zip(scans, T_world_scan):
                origin = scan.e57
                if origin is not None:
                    _copy_scan(imf, data3d, _source(sources, origin.file), origin.index, T)
                else:
                    _new_scan(imf, data3d, scan, T)
            imf.close()
            imf = None
        finally:
            if imf is not None:
                imf.cancel()
            for src in sources.values():
                src.close()


def _source(sources: dict, file: str):
    from pye57 import libe57

    if file not in sources:
        with translated(file):
            sources[file] = libe57.ImageFile(file, "r")
    return sources[file]


def _coordinate_metadata(scans: Sequence[Scan], sources: dict) -> str:
    """The first E57 source's coordinateMetadata (its coordinate reference system), else ""."""
    for s in scans:
        if s.e57 is not None:
            return text_of(_source(sources, s.e57.file).root(), "coordinateMetadata")
    return ""


def _write_header(imf, coordinate_metadata: str) -> None:
    from pye57 import libe57

    root = imf.root()
    imf.extensionsAdd("", libe57.E57_V1_0_URI)
    root.set("formatName", libe57.StringNode(imf, "ASTM E57 3D Imaging Data File"))
    root.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
    root.set("versionMajor", libe57.IntegerNode(imf, libe57.E57_FORMAT_MAJOR))
    root.set("versionMinor", libe57.IntegerNode(imf, libe57.E57_FORMAT_MINOR))
    root.set("e57LibraryVersion", libe57.StringNode(imf, libe57.E57_LIBRARY_ID))
    root.set("coordinateMetadata", libe57.StringNode(imf, coordinate_metadata))
    created = libe57.StructureNode(imf)
    created.set("dateTimeValue", libe57.FloatNode(imf, 0.0))
    created.set("isAtomicClockReferenced", libe57.IntegerNode(imf, 0))
    root.set("creationDateTime", created)
    root.set("data3D", libe57.VectorNode(imf, True))
    root.set("images2D", libe57.VectorNode(imf, True))


def _pose_node(imf, T: np.ndarray):
    from pye57 import libe57

    T = np.asarray(T, dtype=np.float64)
    x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
    pose, rot, tr = (libe57.StructureNode(imf) for _ in range(3))
    for key, v in (("w", w), ("x", x), ("y", y), ("z", z)):
        rot.set(key, libe57.FloatNode(imf, float(v)))
    for key, v in zip("xyz", T[:3, 3]):
        tr.set(key, libe57.FloatNode(imf, float(v)))
    pose.set("rotation", rot)
    pose.set("translation", tr)
    return pose


def _leaves(node, prefix: str = "") -> list[tuple[str, object]]:
    """(path, node) of every leaf of a points prototype (nested structures flattened to 'a/b')."""
    from pye57 import libe57
    from pye57.utils import get_node

    out = []
    for i in range(node.childCount()):
        child = get_node(node, i)
        name = prefix + child.elementName()
        if isinstance(child, (libe57.StructureNode, libe57.VectorNode)):
            out += _leaves(child, name + "/")
        else:
            out.append((name, child))
    return out


def _raw_dtype(node) -> tuple[str, bool]:
    """(numpy dtype, scale?) that carries a field's stored values exactly."""
    from pye57 import libe57

    if isinstance(node, libe57.FloatNode):
        return ("f8" if node.precision() == libe57.FloatPrecision.E57_DOUBLE else "f4"), False
    return INT64, False  # integers, and scaled integers as their raw integers


def _copy_scan(imf, data3d, src_imf, index: int, T: np.ndarray) -> None:
    """Copy data3D[index] of ``src_imf`` into ``imf`` with the pose T: header fields as they were,
    point records value for value (raw, unscaled)."""
    from pye57 import libe57
    from pye57.utils import copy_node, get_node

    src = scan_nodes(src_imf)[index]
    node = libe57.StructureNode(imf)
    for i in range(src.childCount()):
        child = get_node(src, i)
        name = child.elementName()
        if name in ("pose", "points"):
            continue
        copied, vectors, blobs = copy_node(child, imf)
        if not vectors and not blobs:  # a blob or a second point set would need its data copied too
            node.set(name, copied)
    node.set("pose", _pose_node(imf, T))
    src_points = libe57.CompressedVectorNode(src.get("points"))
    prototype, _, _ = copy_node(libe57.StructureNode(src_points.prototype()), imf)
    codecs, _, _ = copy_node(src_points.codecs(), imf)
    points = libe57.CompressedVectorNode(imf, prototype, codecs)
    node.set("points", points)
    data3d.append(node)
    fields = [(name, _raw_dtype(leaf)[0]) for name, leaf in _leaves(libe57.StructureNode(src_points.prototype()))]
    n = src_points.childCount()
    arrays = {name: np.empty(min(n, COPY_CHUNK), dtype) for name, dtype in fields}

    def buffers(image, count):
        bufs = libe57.VectorSourceDestBuffer()
        for name, _ in fields:
            bufs.append(libe57.SourceDestBuffer(image, name, arrays[name], count, True, False))
        return bufs

    reader = src_points.reader(buffers(src_imf, len(arrays[fields[0][0]])))
    writer = points.writer(buffers(imf, len(arrays[fields[0][0]])))
    try:
        done = 0
        while done < n:
            got = reader.read()
            if got == 0:
                raise InputError(f"{src_imf.fileName()}#{index}: its point data ends after {done} of {n} records")
            writer.write(buffers(imf, got), got)
            done += got
    finally:
        reader.close()
        writer.close()


def _new_scan(imf, data3d, scan: Scan, T: np.ndarray) -> None:
    """A scan read from another format, as double-precision cartesian records in its sensor's frame."""
    from pye57 import libe57

    p = scan.points - scan.viewpoint
    T = np.asarray(T, dtype=np.float64).copy()
    T[:3, 3] += T[:3, :3] @ scan.viewpoint
    node = libe57.StructureNode(imf)
    node.set("guid", libe57.StringNode(imf, f"{{{uuid.uuid4()}}}"))
    node.set("name", libe57.StringNode(imf, scan.name))
    node.set("description", libe57.StringNode(imf, f"rangereg: {scan.source or scan.name}"))
    bounds = libe57.StructureNode(imf)
    for axis, k in zip("xyz", range(3)):
        bounds.set(f"{axis}Minimum", libe57.FloatNode(imf, float(p[:, k].min())))
        bounds.set(f"{axis}Maximum", libe57.FloatNode(imf, float(p[:, k].max())))
    node.set("cartesianBounds", bounds)
    node.set("pose", _pose_node(imf, T))
    data = {"cartesianX": np.ascontiguousarray(p[:, 0]), "cartesianY": np.ascontiguousarray(p[:, 1]),
            "cartesianZ": np.ascontiguousarray(p[:, 2])}
    proto = libe57.StructureNode(imf)
    for key in CARTESIAN:
        proto.set(key, libe57.FloatNode(imf, 0.0, libe57.FloatPrecision.E57_DOUBLE))
    rc = _grid_records(scan)
    if rc is not None:
        data["rowIndex"], data["columnIndex"] = rc
        index_bounds = libe57.StructureNode(imf)
        for key, v in (("rowMinimum", 0), ("rowMaximum", scan.grid.shape[0] - 1), ("columnMinimum", 0),
                       ("columnMaximum", scan.grid.shape[1] - 1), ("returnMinimum", 0), ("returnMaximum", 0)):
            index_bounds.set(key, libe57.IntegerNode(imf, int(v)))
        node.set("indexBounds", index_bounds)
        proto.set("rowIndex", libe57.IntegerNode(imf, 0, 0, max(scan.grid.shape[0] - 1, 1)))
        proto.set("columnIndex", libe57.IntegerNode(imf, 0, 0, max(scan.grid.shape[1] - 1, 1)))
    intensity = scan.intensity
    if intensity is not None and len(intensity) == len(p) and np.all(np.isfinite(intensity)):
        data["intensity"] = np.asarray(intensity, dtype=np.float64)
        lo, hi = float(data["intensity"].min()), float(data["intensity"].max())
        limits = libe57.StructureNode(imf)
        limits.set("intensityMinimum", libe57.FloatNode(imf, lo))
        limits.set("intensityMaximum", libe57.FloatNode(imf, hi))
        node.set("intensityLimits", limits)
        proto.set("intensity", libe57.FloatNode(imf, lo, libe57.FloatPrecision.E57_DOUBLE, lo, hi))
    points = libe57.CompressedVectorNode(imf, proto, libe57.VectorNode(imf, True))
    node.set("points", points)
    data3d.append(node)
    bufs = libe57.VectorSourceDestBuffer()
    for key, arr in data.items():
        bufs.append(libe57.SourceDestBuffer(imf, key, arr, len(p), True, False))
    writer = points.writer(bufs)
    try:
        writer.write(len(p))
    finally:
        writer.close()


def _grid_records(scan: Scan) -> tuple[np.ndarray, np.ndarray] | None:
    """(rowIndex, columnIndex) (N,) int64 of every point when the grid holds each point exactly once."""
    if scan.grid is None:
        return None
    g = scan.grid.index
    r, c = np.nonzero(g >= 0)
    idx = g[r, c]
    if len(idx) != len(scan.points) or len(np.unique(idx)) != len(idx):
        return None
    rows, cols = np.empty(len(idx), INT64), np.empty(len(idx), INT64)
    rows[idx], cols[idx] = r, c
    return rows, cols
