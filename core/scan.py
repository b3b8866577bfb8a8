"""A range scan: its points, the sensor viewpoint, an optional range grid and ground truth.

Points are stored in the scan's own frame (the sensor's, for a real scanner). ``pose`` is the
ground-truth ``T_world_scan`` when known; ``guess`` a rough ``T_world_scan`` such as dead reckoning.
Where the viewpoint, the units and the kind came from is said by :class:`Origin` fields (a loaded scan is
assembled by core.assemble, one precedence rule for all formats).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from enum import StrEnum

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .threads import cached_property

# The largest coordinate (in the scan's units) a scan, a viewpoint or a span may have. At 1e12, float64
# still resolves 2e-4 units (eps 2.2e-16 x 1e12), finer than any scanner's noise in the units we meet
# (mm, m); differences of such points, their squares and products of three stay below 1e37, under
# float32's 3.4e38 (Open3D's ray casting and the PLY files we write hold float32), so no step overflows.
# A point at 1e300 squares to inf: numpy then warns and every distance is meaningless.
MAX_COORDINATE = 1e12
# The smallest extent (the longest side of the bounding box, in the scan's units) a scan may have. The geometry takes
# squares and fourth powers of distances a thousandth of the extent and less (spacings, noise floors): from
# 1e-9 they stay above 1e-60, far from float64's smallest normal number (2.2e-308); a scan spanning 1e-150
# squares its spacing to 0 and every error and threshold to 0. No range scan is smaller than 1e-9 of its unit.
MIN_EXTENT = 1e-9


def kd_tree(points: np.ndarray) -> cKDTree:
    """A k-d tree of (N, 3) ``points`` for exact nearest-neighbour queries, split at the medians (scipy's
    default). Not at the cells' midpoints (``balanced_tree=False``, built in 0.57 x the time): among neighbours
    at equal distances, common in quantized scans, the two trees return different ones, and so other normals,
    noise floors and misfits (k = 12 on the shared Kinect frame: 15.9k of its 250k points got another set of
    neighbours; the Kinect pair's angle floor 14.02 deg instead of 13.68)."""
    return cKDTree(points)


def check_coordinates(values) -> str | None:
    """Why ``values`` (any shape) hold a number beyond :data:`MAX_COORDINATE`, or None."""
    a = np.abs(np.asarray(values, dtype=np.float64))
    finite = a[np.isfinite(a)]
    if finite.size and finite.max() > MAX_COORDINATE:
        return f"{finite.max():.3g} is beyond what the geometry can use (|coordinate| <= {MAX_COORDINATE:.0e})"
    return None


@dataclass(frozen=True, eq=False)
class RangeGrid:
    """The scanner's range image: ``index[r, c]`` is the vertex held by cell (r, c), or -1.

    Convention (Stanford's, measured on the bunny scans, and an OpenGL camera's): columns run along
    the sensor's x, rows along its y, the sensor looks along -z, so ``cross(d/dcol, d/drow)``
    points towards the sensor.
    """

    index: np.ndarray  # (rows, cols) int64

    @property
    def shape(self) -> tuple[int, int]:
        return self.index.shape


class ScanKind(StrEnum):
    """How a scan was taken, which decides its surface and its overlap (the error E is the same for all).

    - ``SINGLE_VIEW``: one sensor position in front of the points (object scanners, RGB-D frames, a
      structured E57 scan): a range grid or a 2.5-D triangulation from the viewpoint, the paper's frustum.
    - ``PANORAMA``: the points lie all around the sensor (spinning LiDAR, terrestrial scanners): a spherical
      range image about the sensor, overlap by visibility in that image.
    - ``UNSTRUCTURED``: no single viewpoint (fused fragments, photogrammetry, merged clouds): local planes
      from the points' normals, overlap by mutual closeness.
    """

    SINGLE_VIEW = "single-view"
    PANORAMA = "panorama"
    UNSTRUCTURED = "unstructured"


class Origin(StrEnum):
    """Where a scan's value (viewpoint, units, kind) came from, in the order one overrides the next:
    given (a flag, or the program that built the scan), the JSON sidecar, the file itself, the
    convention of how such files are written (a sensor at the frame's origin), an estimate from the
    points; ``none`` when there is no such value (an unstructured cloud's viewpoint)."""

    GIVEN = "given"
    SIDECAR = "sidecar"
    FILE = "file"
    CONVENTION = "convention"
    ESTIMATE = "estimate"
    NONE = "none"

    @property
    def stated(self) -> bool:
        """Said by someone (a flag, the sidecar, the file), not inferred."""
        return self in (Origin.GIVEN, Origin.SIDECAR, Origin.FILE)


@dataclass(frozen=True)
class E57Record:
    """Which scan of which E57 file a scan was read from (core.e57_write copies its records from there):
    file path, index in the file's data3D, its stored name, "cartesian" or "spherical", and how many
    records the file flags invalid."""

    file: str
    index: int
    name: str
    coordinates: str
    invalid: int


@dataclass(frozen=True, eq=False)
class Scan:
    """points: (N, 3) float64 in ``units``; viewpoint: (3,) sensor origin in the same frame.

    viewpoint_from / units_from / kind_from: where each came from (:class:`Origin`). An unstructured scan
    has no sensor position (``viewpoint_from`` is NONE): its ``viewpoint`` then holds the standoff
    estimate of core.viewpoint only so that single-view tools asked of it still have a point to use.
    sensor_rotation: (3, 3) the sensor's orientation in the scan frame when the file stores one (a PCD's
    VIEWPOINT quaternion), else None. intensity: (N,) float64 per point (NaN where the file flags it
    invalid), or None. viewpoint_spread: the extent of per-point sensor origins a file stores (a LAS
    scan-origin track), in ``units``. at_sensor: points dropped because they sat exactly on the sensor
    (a LiDAR's "no return"). notes: what the assembly wants said about the file.
    """

    points: np.ndarray
    viewpoint: np.ndarray
    name: str = "scan"
    units: str = "unknown"
    grid: RangeGrid | None = None
    faces: np.ndarray | None = None  # (M, 3) int64, a surface stored in the file
    pose: np.ndarray | None = None  # ground truth T_world_scan
    guess: np.ndarray | None = None  # rough T_world_scan (e.g. odometry)
    dropped: int = 0  # non-finite points dropped on loading
    source: str = ""  # the file it came from
    kind: ScanKind = ScanKind.SINGLE_VIEW
    viewpoint_from: Origin = Origin.GIVEN
    units_from: Origin = Origin.NONE
    kind_from: Origin = Origin.GIVEN
    sensor_rotation: np.ndarray | None = None
    intensity: np.ndarray | None = None
    viewpoint_spread: float | None = None
    at_sensor: int = 0
    e57: E57Record | None = None
    notes: tuple[str, ...] = ()

    def __repr__(self) -> str:
        grid = "x".join(map(str, self.grid.shape)) if self.grid is not None else "no"
        vp = "none" if self.viewpoint_from is Origin.NONE else np.round(self.viewpoint, 4).tolist()
        return (f"Scan({self.name!r}, {len(self.points)} points, {self.kind}, units={self.units}, grid={grid}, "
                f"viewpoint={vp}{' (estimated)' if self.viewpoint_from is Origin.ESTIMATE else ''})")

    @property
    def viewpoint_estimated(self) -> bool:
        """The viewpoint is not the sensor's known position (estimated, or none at all)."""
        return self.viewpoint_from in (Origin.ESTIMATE, Origin.NONE)

    @property
    def units_stated(self) -> bool:
        """The units come from a flag, the sidecar or the file, not from the scale."""
        return self.units_from.stated

    def to_arrays(self) -> dict:
        """The scan as plain arrays, strings and numbers (picklable, cheap to ship to another process);
        :meth:`from_arrays` rebuilds it. The grid is its index array; the E57 record a dict."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["grid"] = None if self.grid is None else self.grid.index
        out["e57"] = None if self.e57 is None else vars(self.e57).copy()
        for key in ("kind", "viewpoint_from", "units_from", "kind_from"):
            out[key] = str(out[key])
        return out

    @classmethod
    def from_arrays(cls, d: dict) -> Scan:
        """The scan :meth:`to_arrays` gave ``d``."""
        kw = dict(d)
        kw["grid"] = None if d.get("grid") is None else RangeGrid(d["grid"])
        kw["e57"] = None if d.get("e57") is None else E57Record(**d["e57"])
        kw["kind"] = ScanKind(d.get("kind", ScanKind.SINGLE_VIEW))
        for key in ("viewpoint_from", "units_from", "kind_from"):
            if key in d:
                kw[key] = Origin(d[key])
        kw["notes"] = tuple(d.get("notes", ()))
        return cls(**kw)

    @cached_property
    def tree(self) -> cKDTree:
        return kd_tree(self.points)

    @cached_property
    def spacing(self) -> float:
        """Median distance from a point to its nearest neighbour, in ``units``."""
        n = min(len(self.points), 5000)
        idx = np.linspace(0, len(self.points) - 1, n).astype(int)
        d, _ = self.tree.query(self.points[idx], k=2)
        return float(np.median(d[:, 1]))

    # cached: a registration asks for these dozens of times (the points are never changed in place)
    @cached_property
    def size(self) -> float:
        """Diagonal of the bounding box, in ``units``."""
        return float(np.linalg.norm(self.points.max(0) - self.points.min(0)))

    @cached_property
    def centroid(self) -> np.ndarray:
        c = self.points.mean(0)
        c.flags.writeable = False
        return c

    @cached_property
    def flatness(self) -> float:
        """:func:`flatness` of the points."""
        return flatness(self.points)

    def with_viewpoint(self, viewpoint: np.ndarray, estimated: bool = False) -> Scan:
        v = np.asarray(viewpoint, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(v)):
            raise InputError(f"{self.name}: the viewpoint {v.tolist()} is not finite")
        return replace(self, viewpoint=v, viewpoint_from=Origin.ESTIMATE if estimated else Origin.GIVEN)


def clean_points(points: np.ndarray, what: str) -> tuple[np.ndarray, np.ndarray]:
    """Drop non-finite rows; refuse fewer than 3 points or points on a line.

    Returns the kept (N, 3) float64 points and the boolean mask of kept rows.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"{what}: expected x y z points, got an array of shape {pts.shape}")
    keep = np.all(np.isfinite(pts), axis=1)
    far = keep & np.any(np.abs(np.where(keep[:, None], pts, 0)) > MAX_COORDINATE, axis=1)
    if far.any():
        first = int(np.flatnonzero(far)[0])
        raise InputError(f"{what}: {int(far.sum())} of {len(pts)} points lie beyond +-{MAX_COORDINATE:.0e} units "
                         f"(point {first} is {np.round(pts[first], 6).tolist()}); coordinates that large "
                         "leave no precision for the geometry")
    pts = pts[keep]
    dropped = int((~keep).sum())
    note = f" ({dropped} NaN/inf points dropped)" if dropped else ""
    if len(pts) < 3:
        raise InputError(f"{what}: only {len(pts)} usable points{note}; a scan needs at least 3")
    s = np.linalg.svd(pts[:: max(1, len(pts) // 20000)] - pts.mean(0), compute_uv=False)
    if s[0] == 0 or s[1] / s[0] < 1e-6:
        raise InputError(f"{what}: all {len(pts)} points lie on a line (or one spot){note}; cannot make a surface")
    extent = float(np.ptp(pts, axis=0).max())  # the longest side: a norm would square it to 0
    if extent < MIN_EXTENT:
        raise InputError(f"{what}: the points span only {extent:.3g} units, too small for the geometry (at least "
                         f"{MIN_EXTENT:g}: its squared distances vanish); give them in a smaller unit")
    return pts, keep


def flatness(points: np.ndarray) -> float:
    """Smallest over largest principal spread of (N, 3) points: ~0 for a plane."""
    s = np.linalg.svd(points[:: max(1, len(points) // 20000)] - points.mean(0), compute_uv=False)
    return float(s[2] / s[0])


# The length units a scan may be in, each in metres (the intrusion test's scene width needs them), and the names
# a sidecar or a caller may spell them by. Any other name is refused: a scan's units are said wherever a length is
# printed, so an unknown word ("furlongs") would be printed as fact.
METRES = {"um": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0, "km": 1e3, "in": 0.0254, "ft": 0.3048}
_SPELLINGS = {"um": ("\u03bcm", "micron", "microns", "micrometre", "micrometres", "micrometer", "micrometers"),
              "mm": ("millimetre", "millimetres", "millimeter", "millimeters"),
              "cm": ("centimetre", "centimetres", "centimeter", "centimeters"),
              "m": ("metre", "metres", "meter", "meters"),
              "km": ("kilometre", "kilometres", "kilometer", "kilometers"),
              "in": ("inch", "inches"), "ft": ("foot", "feet")}
UNIT_NAMES = {**{u: u for u in METRES}, **{w: u for u, ws in _SPELLINGS.items() for w in ws}}


def units_name(value: object, what: str) -> str:
    """The short name ("mm", "m", ...) of a length unit however it is spelled ("Millimeters", " m "); InputError
    naming ``what`` for anything else."""
    name = UNIT_NAMES.get(value.strip().casefold()) if isinstance(value, str) else None  # µ folds to Greek mu
    if isinstance(value, str) and value.strip() == "Mm":  # the one symbol whose case is its meaning: megametres
        raise InputError(f"{what}: \"Mm\" is megametres, not a unit scans are in; write \"mm\" for millimetres")
    if name is None:
        known = ", ".join(f'"{u}"' for u in METRES)
        shown = repr(value) if isinstance(value, str) else type(value).__name__
        raise InputError(f"{what} should name a length unit ({known} or their names in words), found {shown[:40]}")
    return name


# Two scans whose sizes and point spacings both differ by this factor or more, and by the same factor
# (within SAME_FACTOR), look like one kind of data in two units (metres and centimetres: 100; metres and
# millimetres: 1000). A small part scanned finely inside a large scene differs in size far more than in
# spacing, so it passes.
UNITS_APART = 100.0
SAME_FACTOR = 3.0


def scale_mismatch(a: Scan, b: Scan) -> str | None:
    """Why ``a`` and ``b`` look like the same kind of data in units about 100 x or more apart (their sizes
    and point spacings differ by the same large factor), or None."""
    sizes, spacings = a.size / b.size if b.size else 0.0, a.spacing / b.spacing if b.spacing else 0.0
    if not (sizes > 0 and spacings > 0 and np.isfinite(sizes) and np.isfinite(spacings)):
        return None
    ls, lp = np.log10(sizes), np.log10(spacings)
    if min(abs(ls), abs(lp)) < np.log10(UNITS_APART) or ls * lp < 0 or abs(ls - lp) > np.log10(SAME_FACTOR):
        return None
    small, big = (a, b) if ls < 0 else (b, a)
    factor = float(10 ** abs((ls + lp) / 2))
    guess = {2: " (centimetres and metres?)", 3: " (millimetres and metres?)"}.get(round(np.log10(factor)), "")
    return (f"{small.name} looks about {factor:.0f} x smaller than {big.name} (size {small.size:.4g} vs "
            f"{big.size:.4g}, point spacing {small.spacing:.4g} vs {big.spacing:.4g}): the same kind of scan in "
            f"other units{guess}")
