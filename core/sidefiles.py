"""The files beside a scan: its JSON sidecar (viewpoint, units, kind, ground truth, rough guess), Stanford
``.conf`` poses and transform files (16 numbers or JSON), each read with one clear error."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from .errors import InputError
from .files import CONF_LIMIT, SIDECAR_LIMIT, TRANSFORM_LIMIT, read_bytes
from .scan import Origin, Scan, ScanKind, check_coordinates, units_name
from .transforms import quaternion_matrix


def sidecar_path(path: Path) -> Path:
    return Path(path).with_suffix(".json")


def _read_text(path: Path, what: str, limit: int) -> str:
    """The text of a side file (sidecar, .conf, transform) of at most ``limit`` bytes, or one InputError
    saying why not (only a regular file is read: core.files)."""
    return read_bytes(path, str(path), limit, what).decode("utf-8", errors="replace")


def read_sidecar(path: Path) -> dict:
    """The scan's JSON sidecar, checked: {} when there is none."""
    side = sidecar_path(path)
    if not side.exists() and not side.is_symlink():
        return {}
    text = _read_text(side, "a JSON sidecar", SIDECAR_LIMIT)
    try:
        data = json.loads(text)
    except (ValueError, RecursionError) as exc:  # (also a number past int's digit limit, arrays nested past the stack)
        raise InputError(f"{side}: the sidecar is not valid JSON ({str(exc)[:120]})") from None
    if not isinstance(data, dict):
        raise InputError(f"{side}: the sidecar should hold a JSON object, found {type(data).__name__}")
    return check_sidecar(data, str(side))


def check_sidecar(data: dict, what: str) -> dict:
    """Check a sidecar's known keys; returns them as arrays: viewpoint (3,), pose and guess (4, 4) rigid,
    kind a core.scan.ScanKind ("single-view", "panorama" or "unstructured"), units a short name (core.scan.units_name)."""
    from .transforms import check_rigid

    out = dict(data)
    if data.get("viewpoint") is not None:
        out["viewpoint"] = vector3(data["viewpoint"], f"{what}: 'viewpoint'")
    for key in ("pose", "guess"):
        if data.get(key) is None:
            continue
        try:
            T = np.asarray(data[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{what}: {key!r} should be a 4 x 4 rigid transform (rows of numbers), "
                             f"found {_short(data[key])}") from None
        try:
            out[key] = check_rigid(T, f"{what}: {key!r}")
        except ValueError as exc:
            raise InputError(str(exc)) from None
        _near(out[key][:3, 3], f"{what}: {key!r}'s translation")
    if data.get("units") is not None:
        out["units"] = units_name(data["units"], f"{what}: 'units'")
    if data.get("kind") is not None:
        kinds = ", ".join(f'"{k.value}"' for k in ScanKind)
        try:
            out["kind"] = ScanKind(data["kind"]) if isinstance(data["kind"], str) else None
        except ValueError:
            out["kind"] = None
        if out["kind"] is None:
            raise InputError(f"{what}: 'kind' should be one of {kinds}, found {_short(data['kind'])}")
    return out


def vector3(value, what: str) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        v = None
    if v is None or v.shape != (3,):
        raise InputError(f"{what} should be three numbers x, y, z, found {_short(value)}")
    if not np.all(np.isfinite(v)):
        raise InputError(f"{what} {v.tolist()} is not finite")
    _near(v, what)
    return v


def _near(values, what: str) -> None:
    """Refuse coordinates (a point, a translation) beyond core.scan.MAX_COORDINATE."""
    problem = check_coordinates(values)
    if problem:
        raise InputError(f"{what}: {problem}")


def _short(value) -> str:
    text = json.dumps(value) if not isinstance(value, np.ndarray) else str(value.tolist())
    return text if len(text) <= 60 else text[:57] + "..."


def load_conf(path: str | Path) -> dict[str, np.ndarray]:
    """Stanford ``.conf`` -> {scan name (file stem): T_world_scan (4, 4)}.

    Each ``bmesh NAME tx ty tz qx qy qz qw`` line is read with the convention measured on the bunny
    data (see its README): ``x_world = R(q*) x_scan + t`` with the CONJUGATE quaternion.
    """
    path = Path(path)
    poses, lines = {}, {}
    for lineno, line in enumerate(_read_text(path, "a Stanford .conf file", CONF_LIMIT).splitlines(), 1):
        tok = line.split()
        if not tok or tok[0] != "bmesh":
            continue
        if len(tok) != 9:
            raise InputError(f"{path}: line {lineno} should be 'bmesh NAME tx ty tz qx qy qz qw'")
        try:
            tx, ty, tz, qx, qy, qz, qw = map(float, tok[2:])
        except ValueError:
            raise InputError(f"{path}: line {lineno} holds a value that is not a number") from None
        if not np.all(np.isfinite([tx, ty, tz])):
            raise InputError(f"{path}: line {lineno}'s translation {[tx, ty, tz]} is not finite")
        R = quaternion_matrix(np.array([-qx, -qy, -qz, qw]))
        if R is None:
            raise InputError(f"{path}: line {lineno} has a zero or invalid quaternion")
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = (tx, ty, tz)
        _near(T[:3, 3], f"{path}: line {lineno}'s translation")
        name = Path(tok[1]).stem
        if name in poses:
            raise InputError(f"{path}: line {lineno} gives a second pose for {name} (first on line {lines[name]}); "
                             "each scan may appear once")
        poses[name], lines[name] = T, lineno
    if not poses:
        raise InputError(f"{path}: no 'bmesh' lines: not a Stanford .conf file")
    return poses


def pose_from_conf_beside(path: Path):
    """The pose of ``path`` (by its stem) in a Stanford .conf in its folder, or None. A .conf that cannot
    be read (a folder, a FIFO, a device, too large, malformed) is passed over: the user did not name it."""
    for conf in sorted(path.parent.glob("*.conf")):
        try:
            poses = load_conf(conf)
        except InputError:
            continue
        if path.stem in poses:
            return poses[path.stem]
    return None


def write_sidecar(path: Path, scan: Scan, **extra) -> None:
    data = {"name": scan.name, "kind": str(scan.kind)}
    if scan.units != "unknown":
        data["units"] = scan.units
    if scan.viewpoint_from is not Origin.NONE:
        data["viewpoint"] = scan.viewpoint.tolist()
    if scan.pose is not None:
        data["pose"] = scan.pose.tolist()
    if scan.guess is not None:
        data["guess"] = scan.guess.tolist()
    data.update(extra)
    sidecar_path(path).write_text(json.dumps(data, indent=1) + "\n")


def parse_transform(text_or_path: str | Path) -> np.ndarray:
    """A rigid 4 x 4 transform from a file (16 numbers, row-major, whitespace or commas; or JSON
    with ``transform``) or, when ``text_or_path`` is a string naming no file, from the text itself
    (16 numbers, or that JSON)."""
    if isinstance(text_or_path, str) and not names_a_file(text_or_path) and _looks_like_numbers(text_or_path):
        text = text_or_path.strip()
        return transform_from_text(text, f"the transform {text if len(text) <= 40 else text[:37] + '...'!r}")
    path = Path(text_or_path)
    if not path.exists():
        raise InputError(f"{path}: no such file (and not 16 numbers)")
    return transform_from_text(_read_text(path, "a transform file", TRANSFORM_LIMIT).strip(), str(path))


def names_a_file(text: str | Path) -> bool:
    """Whether ``text`` is the path of something that exists (False for 16 numbers too long to be a
    file name: the system refuses such a path with an error rather than saying it is absent)."""
    try:
        return Path(text).exists()
    except (OSError, ValueError):
        return False


def read_transform(path: str | Path) -> np.ndarray:
    """A 4 x 4 transform from a file, or from the text of 16 numbers (see :func:`parse_transform`)."""
    return parse_transform(path)


def _looks_like_numbers(text: str) -> bool:
    t = text.strip()
    return t.startswith("{") or bool(re.fullmatch(r"[\s,;\[\]0-9eE+\-.naifNAIF]+", t)) and any(c.isdigit() for c in t)


def transform_from_text(text: str, what: str) -> np.ndarray:
    """A checked rigid (4, 4) transform from the text of 16 numbers or JSON with ``transform``; ``what``
    names it in messages."""
    from .transforms import check_rigid

    if text.startswith("{"):
        try:
            data = json.loads(text)
            values = np.asarray(data["transform"], dtype=np.float64)
        except (KeyError, TypeError, ValueError, RecursionError) as exc:
            raise InputError(f"{what}: expected JSON with a 'transform' 4 x 4 list ({str(exc)[:120]})") from None
    else:
        try:
            values = np.array([float(t) for t in re.split(r"[,;\s\[\]]+", text) if t], dtype=np.float64)
        except ValueError:
            raise InputError(f"{what}: expected 16 numbers (a row-major 4 x 4 matrix)") from None
    if values.size != 16:
        raise InputError(f"{what}: expected 16 numbers (a row-major 4 x 4 matrix), found {values.size}")
    try:
        T = check_rigid(values.reshape(4, 4), what)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    _near(T[:3, 3], f"{what}: its translation")
    return T


def write_transform(path: str | Path, T: np.ndarray, **extra) -> None:
    Path(path).write_text(json.dumps({"transform": np.asarray(T).tolist(), **extra}, indent=1) + "\n")
