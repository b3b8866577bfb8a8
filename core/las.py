"""LAS and LAZ files (ASPRS) through laspy (LAZ decompressed by its lazrs backend).

- **Points**: x, y, z with the header's scale and offset applied (float64, the file's frame and
  units; metres unless the JSON sidecar says ``units``).
- **Viewpoint**, first found of: the ``viewpoint`` argument (``--viewpoint``), the JSON sidecar's
  ``viewpoint``, scan-origin extra fields, else estimated from the points as for an XYZ file
  (core/viewpoint.py; ``Scan.viewpoint_estimated`` says so, and ``info``/``register`` print it).
  Scan-origin extra fields are three extra-bytes dimensions whose names, lower-cased with spaces and
  underscores removed, are ``{prefix}x``, ``{prefix}y``, ``{prefix}z`` for a prefix of
  :data:`ORIGIN_PREFIXES`: ``scan_origin_x``, ``OriginX``, ``sensor x``, ``viewpoint_x``. They
  hold the sensor's position per point (in the points' frame); the scan's one viewpoint is their
  median, and ``Scan.meta["origin_spread"]`` their spread (a mobile scanner's track is not one point).
- Ground truth and rough pose as for any scan: the sidecar's ``pose``/``guess``, a ``.conf`` beside.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .errors import InputError
from .scan import Scan, clean_points

SUFFIXES = (".las", ".laz")
ORIGIN_PREFIXES = ("scanorigin", "origin", "sensor", "viewpoint")


def _origin_fields(names: list[str]) -> tuple[str, str, str] | None:
    key = {re.sub(r"[^a-z0-9]", "", n.lower()): n for n in names}
    for prefix in ORIGIN_PREFIXES:
        found = [key.get(prefix + axis) for axis in "xyz"]
        if all(found):
            return tuple(found)
    return None


def _read(path: Path):
    import laspy

    kind = path.suffix[1:].upper()
    try:
        with laspy.open(str(path)) as reader:
            header = reader.header
            if not header.are_points_compressed:
                need = header.offset_to_point_data + header.point_count * header.point_format.size
                have = path.stat().st_size
                if have < need:
                    raise InputError(f"{path}: the file is cut short: its header promises {header.point_count} points "
                                     f"({need} bytes), the file holds {have} bytes")
            las = reader.read()
        points = np.asarray(las.xyz, dtype=np.float64)
        fields = _origin_fields(list(las.point_format.extra_dimension_names))
        origins = None if fields is None else np.c_[tuple(np.asarray(las[f], dtype=np.float64) for f in fields)]
    except InputError:
        raise
    except Exception as exc:  # laspy and lazrs raise many kinds (LaspyException, LazrsError, ValueError, OSError)
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        why = f"{type(exc).__name__}{': ' + text if text else ''}"
        if type(exc).__name__ == "LazrsError":
            why = f"its compressed points are corrupt or cut short; {why}"
        raise InputError(f"{path}: cannot read it as {kind} ({why})") from None
    return points, origins, fields


def read_las(path: str | Path, viewpoint: np.ndarray | None = None, name: str | None = None) -> Scan:
    """A scan from a LAS/LAZ file (see the module notes). ``viewpoint`` (3,) overrides any stored or
    estimated one. Raises InputError naming the file."""
    from .sidefiles import pose_from_conf_beside, read_sidecar, vector3
    from .viewpoint import check_viewpoint, estimate_viewpoint

    path = Path(path)
    what = str(path)
    raw, origins, fields = _read(path)
    if len(raw) == 0:
        raise InputError(f"{what}: the file holds 0 points")
    points, keep = clean_points(raw, what)
    meta: dict = {}
    stored = None
    if origins is not None:
        origins = origins[keep]
        ok = np.all(np.isfinite(origins), axis=1)
        if ok.any():
            stored = np.median(origins[ok], axis=0)
            meta["origin_fields"] = list(fields)
            meta["origin_spread"] = float(np.linalg.norm(origins[ok].max(0) - origins[ok].min(0)))
    side = read_sidecar(path)
    estimated = False
    if viewpoint is not None:
        vp = vector3(viewpoint, f"{what}: the viewpoint")
    elif side.get("viewpoint") is not None:
        vp = side["viewpoint"]
    elif stored is not None:
        vp = stored
    else:
        vp, estimated = estimate_viewpoint(points), True
    if not estimated:
        check_viewpoint(points, vp, None, None, what)
    pose = side.get("pose")
    if pose is None:
        pose = pose_from_conf_beside(path)
    return Scan(points=points, viewpoint=vp, name=name or path.stem, units=side.get("units") or "m",
                viewpoint_estimated=estimated, pose=None if pose is None else np.asarray(pose, dtype=np.float64),
                guess=side.get("guess"), dropped=int((~keep).sum()), source=what, meta=meta)
