"""A small PLY reader and writer (ASCII and binary) that keeps Stanford's ``range_grid`` element.

Generic readers (Open3D, trimesh) drop the range grid, which is the scanner's own neighbourhood
structure, so we read PLY ourselves. Elements come back as dicts of numpy arrays; a list property
comes back as ``(counts, flat_values)``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


class PlyError(ValueError):
    pass


_BOM = b"\xef\xbb\xbf"


def _parse_header(raw: bytes, whole: bool = True):
    """(format, elements [[name, count, props]], obj_info, comments, body start) of a PLY's first bytes.

    ``end_header`` ends the header only as a line of its own (not inside a comment); a UTF-8 byte-order
    mark before the magic (an editor's) is skipped. ``whole``: ``raw`` is the whole file (else its first
    :data:`core.files.HEADER_LIMIT` bytes)."""
    skip = len(_BOM) if raw.startswith(_BOM) else 0
    pos, lines = skip, []
    while True:
        nl = raw.find(b"\n", pos)
        line = raw[pos:nl if nl >= 0 else len(raw)].decode("ascii", errors="replace").strip()
        if not lines and line != "ply":
            raise PlyError("not a PLY file (no 'ply' magic on its first line)")
        if line == "end_header":
            body_start = nl + 1 if nl >= 0 else len(raw)
            break
        if nl < 0:
            raise PlyError("not a PLY file (no end_header line)" if whole else
                           f"not a PLY file (no end_header line in its first {len(raw) >> 20} MB)")
        lines.append(line)
        pos = nl + 1
    fmt, elements, obj_info, comments = None, [], {}, []
    for line in lines[1:]:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            if len(tok) < 2:
                raise PlyError(f"header line {line!r} names no format")
            fmt = tok[1]
        elif tok[0] == "element":
            if len(tok) != 3:
                raise PlyError(f"header line {line!r} should be 'element NAME COUNT'")
            try:
                count = int(tok[2])
            except ValueError:
                raise PlyError(f"header line {line!r}: the count {tok[2]!r} is not a whole number") from None
            if count < 0:
                raise PlyError(f"header line {line!r}: a negative count of {tok[1]} rows")
            if any(e[0] == tok[1] for e in elements):
                raise PlyError(f"element {tok[1]} is declared twice in the header")
            elements.append([tok[1], count, []])
        elif tok[0] == "property":
            if not elements:
                raise PlyError("property before any element")
            if len(tok) != (5 if len(tok) > 1 and tok[1] == "list" else 3):
                raise PlyError(f"header line {line!r} should be 'property TYPE NAME' or "
                               "'property list COUNT_TYPE TYPE NAME'")
            name, props = tok[-1], elements[-1][2]
            if any(q[0] == name for q in props):
                raise PlyError(f"element {elements[-1][0]} declares property {name} twice")
            if tok[1] == "list":
                if tok[2] not in _TYPES or tok[3] not in _TYPES:
                    raise PlyError(f"unknown list property types in {line!r}")
                props.append((name, "list", _TYPES[tok[2]], _TYPES[tok[3]]))
            else:
                if tok[1] not in _TYPES:
                    raise PlyError(f"unknown property type {tok[1]!r}")
                props.append((name, _TYPES[tok[1]]))
        elif tok[0] == "obj_info" and len(tok) >= 3:
            obj_info[tok[1]] = tok[2]
        elif tok[0] == "comment":
            comments.append(line[8:])
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"unsupported PLY format {fmt!r}")
    for name, count, props in elements:
        if count and not props:
            raise PlyError(f"element {name} has {count} rows but declares no property")
    return fmt, elements, obj_info, comments, body_start


def _check_counts(fmt: str, elements, body: int) -> None:
    """Refuse a header whose counts need more bytes than the file holds (each row at its smallest: a list
    of no items), before anything is allocated for them. Elements of scalars only are measured exactly
    by the readers (with the rows the file does hold); this bounds the ones with lists."""
    need = 0
    for name, count, props in elements:
        if fmt == "ascii":  # a number and a separator at least
            row = 2 * len(props)
        else:
            row = sum(np.dtype(p[1] if len(p) == 2 else p[2]).itemsize for p in props)
        if any(len(p) == 4 for p in props) and need + count * row > body + 1:
            raise PlyError(f"the file ends inside element {name!r}: the header says {count} {name} rows "
                           f"(element {name} {count}, at least {row} bytes each) but only {max(body - need, 0)} "
                           "bytes are left for them")
        need += count * row


def read_ply(path: Path, what: str | None = None) -> tuple[dict, dict]:
    """Read a PLY file -> ({element: {property: array or (counts, values)}}, obj_info).

    Only a regular file is read (core.files); the header is read first and its counts checked against
    the file's size before the body is read. ``what``: the file in messages (default the path)."""
    from .files import HEADER_LIMIT, TEXT_FACTOR, check_memory, open_regular

    what = what or str(path)
    with open_regular(path, what, "a scan file") as f:
        head = f.read(HEADER_LIMIT)
        size = os.fstat(f.fileno()).st_size
        fmt, elements, obj_info, _, start = _parse_header(head, whole=len(head) < HEADER_LIMIT)
        _check_counts(fmt, elements, size - start)
        if fmt == "ascii":
            check_memory(size, TEXT_FACTOR, what)
        raw = head + f.read()
    return _read_body(raw, fmt, elements, start), obj_info


def _read_body(raw: bytes, fmt: str, elements, start: int) -> dict:
    out: dict = {}
    if fmt == "ascii":
        tokens = raw[start:].split()
        values = _ascii_values(tokens, elements)
        pos = 0
        for name, count, props in elements:
            if all(len(p) == 2 for p in props):
                n = count * len(props)
                if pos + n > len(values):
                    held = (len(values) - pos) // max(len(props), 1)
                    raise PlyError(f"the file ends inside element {name!r}: the header says {count} {name} rows "
                                   f"(element {name} {count}) but the file holds only {held}")
                block = values[pos:pos + n].reshape(count, len(props))
                _check_int_range(block, props, name)
                with np.errstate(over="ignore"):  # a value past a float32 property's range reads as inf, dropped
                    out[name] = {p[0]: block[:, i].astype(p[1]) for i, p in enumerate(props)}  # as any non-finite
                pos += n
            else:
                out[name], pos = _ascii_rows(values, pos, count, props, name)
        if pos < len(values):
            raise PlyError(_leftover(elements, len(values) - pos, "numbers"))
        return out
    order = "<" if fmt == "binary_little_endian" else ">"
    buf = memoryview(raw)[start:]
    pos = 0
    for name, count, props in elements:
        if all(len(p) == 2 for p in props):
            dt = np.dtype([(p[0], order + p[1]) for p in props])
            if pos + dt.itemsize * count > len(buf):
                held = (len(buf) - pos) // dt.itemsize
                raise PlyError(f"the file ends inside element {name!r}: the header says {count} {name} rows "
                               f"(element {name} {count}, {dt.itemsize} bytes "
                               f"each) but the file holds only {held} ({len(buf) - pos} bytes)")
            arr = np.frombuffer(buf, dtype=dt, count=count, offset=pos)
            out[name] = {p[0]: arr[p[0]].astype(p[1]) for p in props}
            pos += dt.itemsize * count
        else:
            out[name], pos = _binary_rows(buf, pos, count, props, order, name)
    if len(buf) > pos and bytes(buf[pos:]).strip():  # a trailing newline is harmless; more rows are not
        raise PlyError(_leftover(elements, len(buf) - pos, "bytes"))
    return out


def _check_int_range(block: np.ndarray, props: list, element: str) -> None:
    """PlyError where a column of ``block`` (rows of ASCII values) holds a value its integer property's type cannot
    (a cast would wrap it into another number without a word)."""
    for i, (prop, kind) in enumerate(props):
        if np.dtype(kind).kind not in "iu" or not len(block):
            continue
        info, col = np.iinfo(kind), block[:, i]
        bad = ~((col >= info.min) & (col <= info.max))
        if bad.any():
            raise PlyError(f"property {prop!r} of element {element!r} holds {col[bad][0]:g}, beyond its type's range "
                           f"({info.min} to {info.max})")


def _ascii_values(tokens: list[bytes], elements) -> np.ndarray:
    """The tokens as float64. The rows of the leading scalar-only elements (vertices) are parsed as
    numbers; from the first element with a list property on (faces, a range grid: whole numbers), the
    tokens go through :func:`_whole_numbers`, ~3 x faster, and only fall back when one is not plain."""
    n_scalar = 0
    for _, count, props in elements:
        if not all(len(p) == 2 for p in props):
            break
        n_scalar += count * len(props)
    n_scalar = min(n_scalar, len(tokens))
    try:
        head = np.array(tokens[:n_scalar], dtype=np.float64)
        tail = _whole_numbers(tokens[n_scalar:])
        if tail is None:
            tail = np.array(tokens[n_scalar:], dtype=np.float64)
    except ValueError:
        raise PlyError("the data section holds something that is not a number") from None
    return np.concatenate([head, tail]) if len(tail) else head


def _whole_numbers(tokens: list[bytes]) -> np.ndarray | None:
    """(N,) float64 of tokens that are all plain non-negative whole numbers (digits only, at most 15),
    read digit column by digit column; None when any is not."""
    if not tokens:
        return np.zeros(0)
    S = np.array(tokens, dtype="S")
    width = S.dtype.itemsize
    if width > 15:
        return None
    u = S.view(np.uint8).reshape(len(tokens), width)
    length = np.count_nonzero(u, axis=1)
    it = np.int32 if width <= 9 else np.int64  # nine digits fit an int32
    v = np.zeros(len(tokens), dtype=it)
    for j in range(width):  # Horner's rule, one digit column at a time (the shorter tokens are zero-padded)
        live = j < length
        d = u[:, j].astype(it) - 48
        if np.any(live & ((d < 0) | (d > 9))):
            return None
        v = np.where(live, v * 10 + d, v)
    return v.astype(np.float64)


def _leftover(elements, extra: int, unit: str) -> str:
    """The message for data left after the last element the header declares."""
    name, count, props = elements[-1] if elements else ("vertex", 0, [])
    declared = ", ".join(f"element {n} {c}" for n, c, _ in elements) or "no elements"
    more = ""
    if props and all(len(p) == 2 for p in props):
        size = len(props) if unit == "numbers" else sum(np.dtype(p[1]).itemsize for p in props)
        if extra % size == 0:
            more = f", i.e. {count + extra // size} {name} rows where the header says {count}"
    return f"the header says {declared} but {extra} {unit} follow the last row{more}"


def _ascii_rows(values, pos, count, props, name):
    if len(props) == 1 and count > 0:
        return _ascii_list(values, pos, count, props[0], name)
    cols: dict = {p[0]: [] for p in props}
    try:
        for _ in range(count):
            for p in props:
                if len(p) == 2:
                    cols[p[0]].append(values[pos])
                    pos += 1
                else:
                    k = int(values[pos])
                    if k < 0:
                        raise PlyError(f"element {name!r}: a list of {k} items")
                    cols[p[0]].append(values[pos + 1:pos + 1 + k])
                    pos += 1 + k
    except IndexError:
        raise PlyError(f"the file ends inside element {name!r}: the header says {count} rows") from None
    if pos > len(values):
        raise PlyError(f"the file ends inside element {name!r}: the header says {count} rows")
    return _pack(cols, props), pos


def _ascii_list(values: np.ndarray, pos: int, count: int, prop, name: str):
    """An element of one list property (faces, Stanford's ``range_grid``) without a Python loop over rows.

    Row i starts at token p_i, p_(i+1) = p_i + 1 + values[p_i]. Reading that chain row by row costs
    ~0.35 s on a 512 x 400 range grid; instead every token gets its would-be successor and the chain is
    unrolled by doubling (log2(count) gathers), so only the true row starts are ever read as counts.
    """
    n = len(values)
    k = values[pos:]
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(k) | (k < 0) | (k != np.floor(k))  # a problem only where it is a row's count
    it = np.int32 if len(k) < 2**30 else np.int64  # half the memory traffic of the gathers below
    step = np.minimum(np.where(bad, 0, k), len(k)).astype(it) + 1
    # successor of every token (in tokens from ``pos``), n - pos as the sentinel past the end
    nxt = np.empty(len(k) + 1, dtype=it)
    np.minimum(np.arange(len(k), dtype=it) + step, len(k), out=nxt[:-1])
    nxt[-1] = len(k)
    jumps = [nxt]
    while (1 << len(jumps)) < count:
        jumps.append(jumps[-1][jumps[-1]])
    starts = np.zeros(1, dtype=it)
    for j in reversed(jumps):  # rows 0..2^m - 1 in order: each level interleaves a row with its 2^l-th successor
        starts = np.stack([starts, j[starts]], axis=1).reshape(-1)
    starts = starts[:count]
    if starts[-1] >= len(k):
        raise PlyError(f"the file ends inside element {name!r}: the header says {count} rows")
    starts = starts.astype(np.int64)
    if bad[starts].any():
        raise PlyError(f"element {name!r}: a list of {k[starts][bad[starts]][0]:g} items")
    counts = k[starts].astype(np.int64)
    end = int(starts[-1] + 1 + counts[-1])
    if pos + end > n:
        raise PlyError(f"the file ends inside element {name!r}: the header says {count} rows")
    total = int(counts.sum())
    first = np.repeat(starts + 1 - np.r_[0, np.cumsum(counts)[:-1]], counts)
    flat = k[first + np.arange(total)] if total else np.zeros(0)
    return {prop[0]: (counts, flat.astype(np.int64))}, pos + end


def _binary_rows(buf, pos, count, props, order, name):
    # Fast path: one list property of constant length (triangle faces).
    if len(props) == 1 and count > 0:
        _, _, ct, it = props[0]
        cdt, idt = np.dtype(order + ct), np.dtype(order + it)
        k = int(np.frombuffer(buf, dtype=cdt, count=1, offset=pos)[0])
        dt = np.dtype([("n", cdt), ("v", idt, (k,))]) if k > 0 else None
        if dt is not None and pos + dt.itemsize * count <= len(buf):
            arr = np.frombuffer(buf, dtype=dt, count=count, offset=pos)
            if np.all(arr["n"] == k):
                counts = np.full(count, k, dtype=np.int64)
                return {props[0][0]: (counts, arr["v"].reshape(-1).astype(np.int64))}, pos + dt.itemsize * count
    cols: dict = {p[0]: [] for p in props}
    try:
        for _ in range(count):
            for p in props:
                if len(p) == 2:
                    dt = np.dtype(order + p[1])
                    cols[p[0]].append(np.frombuffer(buf, dtype=dt, count=1, offset=pos)[0])
                    pos += dt.itemsize
                else:
                    cdt, idt = np.dtype(order + p[2]), np.dtype(order + p[3])
                    k = int(np.frombuffer(buf, dtype=cdt, count=1, offset=pos)[0])
                    if k < 0:
                        raise PlyError(f"element {name!r}: a list of {k} items")
                    pos += cdt.itemsize
                    cols[p[0]].append(np.frombuffer(buf, dtype=idt, count=k, offset=pos))
                    pos += idt.itemsize * k
    except PlyError:
        raise
    except ValueError:
        raise PlyError(f"the file ends inside element {name!r}: the header says {count} rows") from None
    return _pack(cols, props), pos


def _pack(cols, props):
    out = {}
    for p in props:
        if len(p) == 2:
            out[p[0]] = np.asarray(cols[p[0]], dtype=p[1])
        else:
            rows = cols[p[0]]
            counts = np.array([len(r) for r in rows], dtype=np.int64)
            flat = np.concatenate(rows).astype(np.int64) if len(rows) and counts.sum() else np.zeros(0, np.int64)
            out[p[0]] = (counts, flat)
    return out


def write_ply(path: Path, points: np.ndarray, faces: np.ndarray | None = None,
              colors: np.ndarray | None = None, comments: tuple[str, ...] = ()) -> None:
    """Write binary little-endian PLY: float32 vertices, optional uint8 colours and triangles."""
    pts = np.asarray(points, dtype=np.float32)
    header = ["ply", "format binary_little_endian 1.0"] + [f"comment {c}" for c in comments]
    header += [f"element vertex {len(pts)}", "property float x", "property float y", "property float z"]
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if colors is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vert = np.empty(len(pts), dtype=fields)
    vert["x"], vert["y"], vert["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
    if colors is not None:
        c = np.asarray(colors, dtype=np.uint8)
        vert["red"], vert["green"], vert["blue"] = c[:, 0], c[:, 1], c[:, 2]
    body = [vert.tobytes()]
    if faces is not None:
        f = np.asarray(faces, dtype=np.int64)
        header += [f"element face {len(f)}", "property list uchar int vertex_indices"]
        fa = np.empty(len(f), dtype=[("n", "u1"), ("v", "<i4", (3,))])
        fa["n"], fa["v"] = 3, f
        body.append(fa.tobytes())
    header.append("end_header")
    Path(path).write_bytes(("\n".join(header) + "\n").encode() + b"".join(body))


def write_range_grid_ply(path: Path, points: np.ndarray, grid_index: np.ndarray, comments: tuple[str, ...] = ()) -> None:
    """Write an ASCII Stanford range-grid PLY (vertices + ``range_grid``), readable by Stanford tools."""
    rows, cols = grid_index.shape
    lines = ["ply", "format ascii 1.0"] + [f"comment {c}" for c in comments]
    lines += [f"obj_info num_cols {cols}", f"obj_info num_rows {rows}", f"element vertex {len(points)}",
              "property float x", "property float y", "property float z",
              f"element range_grid {rows * cols}", "property list uchar int vertex_indices", "end_header"]
    body = [f"{x:.6g} {y:.6g} {z:.6g}" for x, y, z in np.asarray(points)]
    body += ["0" if i < 0 else f"1 {i}" for i in grid_index.reshape(-1)]
    Path(path).write_text("\n".join(lines + body) + "\n")


if __name__ == "__main__":  # pragma: no cover - debugging aid
    data, info = read_ply(Path(sys.argv[1]))
    print({k: {p: (v.shape if isinstance(v, np.ndarray) else v[0].shape) for p, v in e.items()} for k, e in data.items()}, info)
