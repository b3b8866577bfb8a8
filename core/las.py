"""LAS and LAZ files (ASPRS) through laspy (LAZ decompressed by its lazrs backend).

- **Points**: x, y, z with the header's scale and offset applied (float64, the file's frame and
  units; metres by the format's convention unless the JSON sidecar says ``units``); intensity kept.
- **Viewpoint**: scan-origin extra fields are the file's; the flag and the sidecar come first, the
  frame's origin or an estimate after (core.assemble's one rule).
  Scan-origin extra fields are three extra-bytes dimensions whose names, lower-cased with spaces and
  underscores removed, are ``{prefix}x``, ``{prefix}y``, ``{prefix}z`` for a prefix of
  :data:`ORIGIN_PREFIXES`: ``scan_origin_x``, ``OriginX``, ``sensor x``, ``viewpoint_x``. They
  hold the sensor's position per point (in the points' frame); the scan's one viewpoint is their
  median, and ``Scan.viewpoint_spread`` their spread (a mobile scanner's track is not one point).
- Ground truth and rough pose as for any scan: the sidecar's ``pose``/``guess``, a ``.conf`` beside.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .assemble import RawScan
from .errors import InputError
from .scan import Scan

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
        names = set(las.point_format.dimension_names)
        intensity = np.asarray(las["intensity"], dtype=np.float64) if "intensity" in names else None
    except InputError:
        raise
    except Exception as exc:  # laspy and lazrs raise many kinds (LaspyException, LazrsError, ValueError, OSError)
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
        why = f"{type(exc).__name__}{': ' + text if text else ''}"
        if type(exc).__name__ == "LazrsError":
            why = f"its compressed points are corrupt or cut short; {why}"
        raise InputError(f"{path}: cannot read it as {kind} ({why})") from None
    return points, origins, fields, intensity


def read_las_raw(path: str | Path) -> RawScan:
    """What a LAS/LAZ file holds (core.assemble.RawScan; see the module notes). Raises InputError."""
    path = Path(path)
    what = str(path)
    raw, origins, fields, intensity = _read(path)
    if len(raw) == 0:
        raise InputError(f"{what}: the file holds 0 points")
    stored, spread, notes = None, None, ()
    if origins is not None:
        ok = np.all(np.isfinite(origins), axis=1) & np.all(np.isfinite(raw), axis=1)
        if ok.any():
            stored = np.median(origins[ok], axis=0)
            spread = float(np.linalg.norm(origins[ok].max(0) - origins[ok].min(0)))
            notes = (f"viewpoint: the median of the scan-origin fields {', '.join(fields)} "
                     f"(they spread over {spread:.4g})",)
    return RawScan(raw, what, path.stem, viewpoint=stored, viewpoint_label="the scan-origin fields",
                   viewpoint_spread=spread, units_convention="m",
                   intensity=intensity, sidecar=path, notes=notes)


def read_las(path: str | Path, viewpoint: np.ndarray | None = None, name: str | None = None) -> Scan:
    """A scan from a LAS/LAZ file (see the module notes). ``viewpoint`` (3,) overrides any stored or
    estimated one. Raises InputError naming the file."""
    from .assemble import Given, assemble

    return assemble(read_las_raw(path), Given(viewpoint=viewpoint, name=name))
