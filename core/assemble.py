"""One step from what a file holds to a :class:`core.scan.Scan`, by one precedence rule for every format.

Readers (core.io for PLY/PCD/text/meshes, core.e57, core.las) return a :class:`RawScan`: the points as
stored and whatever the file itself says (a range grid, faces, a stored viewpoint and pose, units,
intensity), nothing decided. :func:`assemble` then settles each value by the first source that has it:

    given (flags)  >  the JSON sidecar  >  the file  >  convention  >  an estimate from the points

- **viewpoint**: ``--viewpoint``; the sidecar's ``viewpoint``; the file's (a PCD's VIEWPOINT, an E57
  scan frame's origin, LAS scan-origin fields), but a format's default (PCD's ``0 0 0 1 0 0 0``, written
  into every file) only where the points lie as a sensor there sees them, and one they were plainly not
  sampled from, while they were from the frame's origin (a pose in a map's frame), not at all; by
  convention the frame's origin, when the points lie around it or in front of it as a sensor there would have sampled them
  (LiDAR and RGB-D frames are written so); else estimated (core.viewpoint) where a single view is
  plausible, and none otherwise.
- **units**: given; the sidecar's ``units``; the file's (E57: metres by the standard); the format's
  convention (LAS: metres); else from the scale (:func:`units_from_scale`), said as such.
- **pose** (ground truth): the sidecar's ``pose``; the file's; a Stanford ``.conf`` beside the file.
  **guess**: the sidecar's ``guess``; the file's (an E57 scan's pose).
- **kind** (core.scan.ScanKind): given (``--scan-kind``); the sidecar's ``kind``; else from how the
  points lie about the viewpoint: all around it, a panorama; in front of it, a single view; with no
  viewpoint and no single view plausible, unstructured.

A range grid whose facing the format leaves open (PCD, E57) is mirrored, if need be, so that
``cross(d/dcol, d/drow)`` faces the sensor (core.scan.RangeGrid's convention). Points exactly at a
viewpoint known (not estimated) are a LiDAR's "no return" placeholders and are dropped (not a mesh's
vertices, nor when most points sit there: that viewpoint is wrong).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from .errors import InputError
from .lattice import pixel_grid
from .rows import cross, norms
from .scan import E57Record, Origin, RangeGrid, Scan, ScanKind, clean_points, kd_tree
from .viewpoint import (
    AROUND_SHARE,
    CLOSER_FIT,
    CONVENTION_REACH,
    GRAZING_SHARE,
    LAYERED_SHARE,
    RANGE_SPREAD,
    SENSOR_SLOPE,
    check_viewpoint,
    estimate_viewpoint,
    grazing_share,
    layered_share,
    range_correlation,
    sample,
    sensor_slope,
    share_around,
    surrounds,
)

ORIENT_SAMPLE = 20_000  # grid cells that decide which way a grid faces (a whole scan faces one way)

# Units from the scale. The median point spacing of real scans, in metres: the bunny 0.0005, the Kinect
# frames 0.004, the spinning-LiDAR frames 0.012; the simulated scenes in millimetres 5.6-16.6. A spacing
# below SPACING_METRES would be finer than 50 micrometres in millimetres (no range scanner we meet), one
# above SPACING_MILLIMETRES coarser than 2 m in metres (the LiDAR frames thinned on the 0.3-1 m voxels of a
# global registration are 0.2-0.62 apart: the shared frames at 1 m, 0.62, were "mm" when this bound was 0.5);
# between them the scale cannot tell (a street at 20 cm or an object at 0.2 mm) and the units stay unknown,
# unless the points surround their sensor: a panorama is a scene, in metres.
SPACING_METRES = 0.05
SPACING_MILLIMETRES = 2.0


@dataclass(frozen=True, eq=False)
class RawScan:
    """What a reader found in one scan of a file, nothing decided (see the module notes).

    points: (N, 3) float64 as stored (non-finite rows allowed; :func:`assemble` drops them);
    grid: (rows, cols) int64 index into ``points`` (-1: empty cell) or None; grid_faces_sensor: the
    format fixes its facing (Stanford's range-grid PLY) rather than leaving it to the sensor's position;
    faces: (M, 3) int64 or None; viewpoint: (3,) sensor position stored in the file, or None (named in
    messages by viewpoint_label); viewpoint_default: that stored value is the format's default, which its
    writers put in every file, a sensor there or not (a PCD's ``VIEWPOINT 0 0 0 1 0 0 0``); viewpoint_pose: the
    stored value is a pose, which writers may fill with the sensor's pose in another frame (a PCD's VIEWPOINT);
    sensor_rotation: (3, 3) its stored orientation, or None; pose / guess: (4, 4) T_world_scan stored
    in the file (ground truth / a rough pose); units: the units the file states; units_convention: the
    format's usual units when the file states none; intensity: (N,) float64 or None; sidecar: the file
    whose JSON sidecar and ``.conf`` apply (None: none do); what: the file (and scan) for messages;
    dropped: records the reader left out already (non-finite); notes: what the reader wants said.
    """

    points: np.ndarray
    what: str
    name: str
    grid: np.ndarray | None = None
    grid_faces_sensor: bool = False
    faces: np.ndarray | None = None
    viewpoint: np.ndarray | None = None
    viewpoint_label: str = "the stored viewpoint"
    viewpoint_default: bool = False
    viewpoint_pose: bool = False
    sensor_rotation: np.ndarray | None = None
    viewpoint_spread: float | None = None
    pose: np.ndarray | None = None
    guess: np.ndarray | None = None
    units: str | None = None
    units_convention: str | None = None
    intensity: np.ndarray | None = None
    e57: E57Record | None = None
    sidecar: Path | None = None
    dropped: int = 0
    notes: tuple[str, ...] = ()


@dataclass(frozen=True, eq=False)
class Given:
    """What the user says on the command line (or a program passes), above everything in the file:
    viewpoint (3,) in the scan's frame, units, kind, name; None where not said."""

    viewpoint: np.ndarray | None = None
    units: str | None = None
    kind: ScanKind | None = None
    name: str | None = None


def scan_kind(value: ScanKind | str | None) -> ScanKind | None:
    """A ScanKind from its name ("single-view", "panorama", "unstructured"; underscores allowed)."""
    if value is None or isinstance(value, ScanKind):
        return value
    try:
        return ScanKind(str(value).strip().lower().replace("_", "-"))
    except ValueError:
        raise InputError(f"unknown scan kind {value!r}; use one of {', '.join(k.value for k in ScanKind)}") from None


def assemble(raw: RawScan, given: Given = Given()) -> Scan:
    """The Scan of ``raw`` with each value taken by the precedence rule (module notes). Raises InputError."""
    from .sidefiles import pose_from_conf_beside, read_sidecar, vector3

    what = raw.what
    parts = _Parts.of(raw)
    side = read_sidecar(raw.sidecar) if raw.sidecar is not None else {}

    stated = None
    for value, origin, label in ((given.viewpoint, Origin.GIVEN, "the viewpoint"),
                                 (side.get("viewpoint"), Origin.SIDECAR, "the sidecar's viewpoint"),
                                 (raw.viewpoint, Origin.FILE, raw.viewpoint_label)):
        if value is not None:
            stated = (vector3(value, f"{what}: {label}"), origin)
            break
    kind, kind_from = given.kind, Origin.GIVEN
    if kind is None and side.get("kind") is not None:
        kind, kind_from = side["kind"], Origin.SIDECAR

    notes, placed, about_origin, rotation = raw.notes, None, None, raw.sensor_rotation
    if stated is not None and stated[1] is Origin.FILE and raw.viewpoint_default:
        placed = _default_viewpoint(parts.points, stated[0])
        about_origin = (None, placed[4])  # its k-d tree, if one was built, serves the rest
        if placed[0] is None:  # the format's default says nothing of these points: as if the file gave none
            notes += (f"the file's {raw.viewpoint_label} is the format's default (the origin), and the points do "
                      "not lie as a sensor there sees them: not used",)
            stated, placed = None, None
        elif kind is not None:  # a kind given or in the sidecar: the default holds as a viewpoint, the kind as said
            placed = None
    elif stated is not None and stated[1] is Origin.FILE and raw.viewpoint_pose and np.any(stated[0] != 0):
        elsewhere, about_origin = _elsewhere(parts.points, stated[0])
        if elsewhere and kind in (None, about_origin[0]):  # (a kind given otherwise: the viewpoint as stated)
            notes += (f"the file's {raw.viewpoint_label} {np.round(stated[0], 3).tolist()} is not where these points "
                      "were sampled from (their spacing grows with the range from the frame's origin, not from it: "
                      "a pose in another frame?); the frame's origin is used",)
            stated, rotation = None, None  # the stored orientation is that pose's too
    if placed is None:
        placed = _place(parts, stated, kind, kind_from, what, about_origin)
        if placed[4] is None and about_origin is not None:
            placed = (*placed[:4], about_origin[1])
    vp, vp_from, kind, kind_from, tree = placed
    if vp_from is not Origin.ESTIMATE and kind is not ScanKind.UNSTRUCTURED and parts.faces is None:
        parts = parts.without_points_at(vp)
    if tree is not None and not _holds(tree, parts.points):  # (one of the points off the origin, which these keep)
        tree = None
    grid, faces_sensor = parts.grid, raw.grid_faces_sensor
    if grid is None and parts.faces is None and kind is ScanKind.SINGLE_VIEW and vp_from is not Origin.ESTIMATE:
        grid, faces_sensor = pixel_grid(parts.points, vp), False  # an RGB-D frame as bare points (core.lattice)
        if grid is not None:
            notes += (f"the points lie on a depth camera's pixel lattice: its {grid.shape[0]} x {grid.shape[1]} range "
                      "grid is recovered",)
    if grid is not None and not faces_sensor and vp_from not in (Origin.ESTIMATE, Origin.NONE):
        grid = orient_grid(grid, parts.points, vp)
    if kind is ScanKind.SINGLE_VIEW and vp_from.stated:
        check_viewpoint(parts.points, vp, None if grid is None else RangeGrid(grid), parts.faces, what)

    pose = side.get("pose")
    if pose is None:
        pose = raw.pose
    if pose is None and raw.sidecar is not None:
        pose = pose_from_conf_beside(raw.sidecar)
    guess = side.get("guess") if side.get("guess") is not None else raw.guess
    scan = Scan(points=parts.points, viewpoint=vp, name=given.name or raw.name, units="unknown",
                grid=None if grid is None else RangeGrid(grid), faces=parts.faces,
                pose=None if pose is None else np.asarray(pose, dtype=np.float64),
                guess=None if guess is None else np.asarray(guess, dtype=np.float64),
                dropped=parts.dropped, source=what, kind=kind, viewpoint_from=vp_from, kind_from=kind_from,
                sensor_rotation=rotation, intensity=parts.intensity,
                viewpoint_spread=raw.viewpoint_spread, at_sensor=parts.at_sensor, e57=raw.e57, notes=notes)
    if tree is not None:
        scan.__dict__["tree"] = tree  # the placement's k-d tree of these very points (a cached_property)
    units, units_from = _units(given, side, raw, scan)
    return _same_points(replace(scan, units=units, units_from=units_from), scan)


def _same_points(new: Scan, old: Scan) -> Scan:
    """``new`` with ``old``'s cached geometry (tree, spacing, size): they share their points."""
    for key in ("tree", "spacing", "size", "centroid"):
        if key in old.__dict__:
            new.__dict__[key] = old.__dict__[key]
    return new


# ---- the points and what rides with them ----

@dataclass(frozen=True, eq=False)
class _Parts:
    """The kept points (N, 3) and what indexes them: grid (rows, cols) or None, faces (M, 3) or None,
    intensity (N,) or None; dropped: non-finite records left out; at_sensor: points on the sensor left out."""

    points: np.ndarray
    grid: np.ndarray | None
    faces: np.ndarray | None
    intensity: np.ndarray | None
    dropped: int
    at_sensor: int = 0

    @classmethod
    def of(cls, raw: RawScan) -> _Parts:
        points, keep = clean_points(raw.points, raw.what)
        full = _Parts(np.asarray(raw.points, dtype=np.float64), raw.grid, raw.faces, raw.intensity, 0)
        kept = full.subset(keep)
        return replace(kept, points=points, dropped=int((~keep).sum()) + raw.dropped)

    def subset(self, keep: np.ndarray) -> _Parts:
        """These parts restricted to the points where ``keep`` (N,) bool: grid cells and faces of a
        point left out are left out, the rest renumbered."""
        remap = np.cumsum(keep) - 1
        grid = faces = None
        if self.grid is not None:
            g = self.grid.copy()
            occupied = g >= 0
            valid = occupied.copy()
            valid[occupied] = keep[g[occupied]]
            g[~valid] = -1
            g[valid] = remap[g[valid]]
            grid = g
        if self.faces is not None:
            faces = remap[self.faces[np.all(keep[self.faces], axis=1)]]
        intensity = None if self.intensity is None else np.asarray(self.intensity, dtype=np.float64)[keep]
        return _Parts(self.points[keep], grid, faces, intensity, self.dropped, self.at_sensor)

    def without_points_at(self, viewpoint: np.ndarray) -> _Parts:
        """Left out: points exactly on the sensor (a scanner writes a missing return there)."""
        on = np.all(self.points == viewpoint, axis=1)
        if not on.any() or on.mean() > 0.5 or len(on) - on.sum() < 3:  # most there: a wrong viewpoint (say so)
            return self
        return replace(self.subset(~on), at_sensor=self.at_sensor + int(on.sum()))


# ---- where the sensor stood, and the kind ----

def _place(parts: _Parts, stated, kind: ScanKind | None, kind_from: Origin, what: str, about_origin=None):
    """(viewpoint (3,), its Origin, kind, the kind's Origin, a k-d tree of parts.points (or of those off the
    origin: :func:`_holds` tells) or None);
    ``about_origin``: :func:`_about_origin` of the points when already asked."""
    points = parts.points
    if stated is not None:
        vp, vp_from = stated
        if kind is None:
            kind = ScanKind.PANORAMA if surrounds(points[sample(points, 20_000)], vp) else ScanKind.SINGLE_VIEW
            kind_from = Origin.ESTIMATE
        return vp, vp_from, kind, kind_from, None
    origin = np.zeros(3)
    if kind is ScanKind.PANORAMA:  # a panorama with no stated sensor: about the frame's origin
        return origin, Origin.CONVENTION, kind, kind_from, None
    about, tree = _about_origin(points) if about_origin is None else about_origin
    if about is not None and kind in (None, about):
        return origin, Origin.CONVENTION, about, (kind_from if kind is not None else Origin.ESTIMATE), tree
    oriented_grid = None if parts.grid is None else RangeGrid(parts.grid)
    vp = estimate_viewpoint(points, oriented_grid, parts.faces)
    if kind is None:
        if parts.grid is not None or parts.faces is not None:
            kind = ScanKind.SINGLE_VIEW
        else:
            tree = tree if _holds(tree, points) else kd_tree(points)
            kind = ScanKind.SINGLE_VIEW if _one_view(points, tree, vp) else ScanKind.UNSTRUCTURED
        kind_from = Origin.ESTIMATE
    return vp, Origin.NONE if kind is ScanKind.UNSTRUCTURED else Origin.ESTIMATE, kind, kind_from, tree


def _default_viewpoint(points: np.ndarray, origin: np.ndarray):
    """A format's default viewpoint (the origin, which PCL and Open3D write into every PCD) taken where the
    points lie as a sensor there sees them: sampled from there (:func:`_about_origin`: a LiDAR or RGB-D frame
    as captured), or one layer deep in front of it (such a frame thinned on a voxel grid, whose spacing no
    longer grows with the range). Else (None, ...): a cloud fused from many views, thinned all round, or
    far from the origin (the default then says nothing). Returns _place's five values.

    Measured (2026-12-06): the shared LiDAR and Kinect frames are sampled from their origin; the Kinect
    frame thinned at 1-5 cm lies in front of it with layered shares 0.15-0.36, as do RGB-D fragments fused
    from 5 frames (0.03-0.12); 15 frames walked along 90 degrees of a room put 0.5-1.7 % beside the first
    camera (before, refused: "some points lie beside or behind the viewpoint"), 30 frames along 180
    degrees 30 % all round (before, a panorama: 0.49 deg / 4 cm off and doubted, 10 s; as a PLY, without
    the default, 0.04 deg / 0.1 cm and trusted, 2.9 s), and the shared LiDAR pair thinned at 0.1 and
    0.25 m all round with slopes 0.25 and 0.13 (before, a panorama: 34 and 1.3 deg off; as a PLY 0.38 and
    0.39 deg, trusted).
    """
    about, tree = _about_origin(points)
    if (about is None and tree is not None and share_around(points, origin) == 0
            and _one_view(points, tree if _holds(tree, points) else kd_tree(points), origin)):
        about = ScanKind.SINGLE_VIEW
    if about is None:
        return None, None, None, None, tree
    return origin, Origin.FILE, about, Origin.ESTIMATE, tree


def _elsewhere(points: np.ndarray, viewpoint: np.ndarray) -> tuple[bool, tuple[ScanKind | None, cKDTree | None]]:
    """Whether a sensor at the frame's origin, not one at the file's ``viewpoint`` (3,), sampled the points: they
    lie as :func:`_about_origin` asks, their spacing grows with the range from the origin (core.viewpoint:
    SENSOR_SLOPE, RANGE_SPREAD), and it follows that range clearly better than the range from the viewpoint
    (core.viewpoint.CLOSER_FIT): PCL's VIEWPOINT holding the sensor's pose in a map while the points stay in the
    sensor's frame. Also :func:`_about_origin`'s answer (its k-d tree serves the rest).

    Measured (2026-12-06): the shared LiDAR frames, and the Kinect frame capture0002 written as bare points, with a
    map's pose 11-128 m off in VIEWPOINT were read as one view from there: the LiDAR pair was trusted 1.06 deg /
    3.2 cm off (0.11 deg at the origin), the Kinect pair doubted after 7 s. The same frames in the map's frame,
    their VIEWPOINT the sensor's position there, are sampled from it and keep it."""
    about = _about_origin(points)
    if about[0] is None:
        return False, about
    idx = sample(points)
    d = _spacings(about[1], points[idx])
    slope, spread = sensor_slope(points[idx], d, np.zeros(3))
    if not (spread >= RANGE_SPREAD and slope > SENSOR_SLOPE):
        return False, about  # the origin is no likelier than the viewpoint
    closer = range_correlation(points[idx], d, np.zeros(3)) - range_correlation(points[idx], d, viewpoint)
    return closer >= CLOSER_FIT, about


def _about_origin(points: np.ndarray) -> tuple[ScanKind | None, cKDTree | None]:
    """How the points lie about the frame's origin when a sensor there sampled them: PANORAMA (all
    around it), SINGLE_VIEW (in front of it), or None (no sensor there: too far, or spaced as no sensor
    there would space them). Also the k-d tree of the points off the origin when one was built (None otherwise)."""
    r = norms(points)
    seen = points[r > 0]
    if len(seen) < 3:
        return None, None
    size = float(np.linalg.norm(seen.max(0) - seen.min(0)))
    if not np.median(r[r > 0]) <= CONVENTION_REACH * size:
        return None, None
    share = share_around(seen, np.zeros(3))
    if 0 < share <= AROUND_SHARE:
        return None, None  # neither in front (a few behind) nor all around
    around = share > AROUND_SHARE
    # the points on the origin (a scanner's missing returns) are nobody's neighbours; a scan keeps the
    # others only (_Parts.without_points_at), so this tree serves it
    tree = kd_tree(seen)
    idx = sample(points)
    slope, spread = sensor_slope(points[idx], _spacings(tree, points[idx]), np.zeros(3))
    if spread >= RANGE_SPREAD and slope <= SENSOR_SLOPE:
        return None, tree  # the spacing does not grow with the range: not sampled from there
    if around and spread < RANGE_SPREAD:
        return None, tree  # all around at one range: nothing tells a sensor from a shell about its centre
    return (ScanKind.PANORAMA if around else ScanKind.SINGLE_VIEW), tree


def _spacings(tree: cKDTree, points: np.ndarray) -> np.ndarray:
    """Each of (n, 3) ``points``' distance (n,) to its nearest other point in ``tree`` (of the points off the
    origin); 0 at the points on the origin, as among the duplicates there (no sample: sensor_slope leaves it out)."""
    away = norms(points) > 0
    d = np.zeros(len(points))
    if away.any():
        d[away] = tree.query(points[away], k=2)[0][:, 1]
    return d


def _holds(tree: cKDTree | None, points: np.ndarray) -> bool:
    """Whether ``tree`` is a k-d tree of exactly (N, 3) ``points`` (its indices are theirs)."""
    return tree is not None and tree.n == len(points) and np.array_equal(tree.data, points)


def _one_view(points: np.ndarray, tree: cKDTree, viewpoint: np.ndarray) -> bool:
    """Whether bare points could be one view from ``viewpoint``: one surface along each ray, in layers
    only at occluding contours (core.viewpoint.LAYERED_SHARE), and few surfaces seen edge-on
    (core.viewpoint.GRAZING_SHARE)."""
    return (layered_share(points, tree, viewpoint) <= LAYERED_SHARE
            and grazing_share(points, tree, viewpoint) <= GRAZING_SHARE)


def orient_grid(grid: np.ndarray, points: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """The grid (rows, cols), mirrored left-right when most of its cells' ``cross(d/dcol, d/drow)`` face
    away from ``viewpoint`` (PCD and E57 leave the direction rows and columns run to the scanner)."""
    a, b, r = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1]
    cells = np.flatnonzero((a >= 0) & (b >= 0) & (r >= 0))
    if not len(cells):
        return grid
    cells = cells[:: max(1, len(cells) // ORIENT_SAMPLE)]  # a spread-out sample: all 1M cells took 0.3 s
    pa, pb, pr = points[a.ravel()[cells]], points[b.ravel()[cells]], points[r.ravel()[cells]]
    facing = np.einsum("ij,ij->i", cross(pb - pa, pr - pa), viewpoint - pa)
    return grid if np.sum(facing > 0) >= np.sum(facing < 0) else np.ascontiguousarray(grid[:, ::-1])


# ---- units ----

def _units(given: Given, side: dict, raw: RawScan, scan: Scan) -> tuple[str, Origin]:
    for value, origin in ((given.units, Origin.GIVEN), (side.get("units"), Origin.SIDECAR),
                          (raw.units, Origin.FILE), (raw.units_convention, Origin.CONVENTION)):
        if value:
            return str(value).strip(), origin
    units = units_from_scale(scan.spacing, scan.kind)
    return units, (Origin.ESTIMATE if units != "unknown" else Origin.NONE)


def units_from_scale(spacing: float, kind: ScanKind = ScanKind.SINGLE_VIEW) -> str:
    """"m", "mm" or "unknown" from a scan's median point spacing (in its units) and its kind (see
    :data:`SPACING_METRES`)."""
    if spacing < SPACING_METRES:
        return "m"
    if spacing > SPACING_MILLIMETRES:
        return "mm"
    return "m" if kind is ScanKind.PANORAMA else "unknown"


# ---- saying where each value came from (info, register, the page) ----

_FROM = {Origin.GIVEN: "given", Origin.SIDECAR: "from the sidecar", Origin.FILE: "from the file",
         Origin.CONVENTION: "the format's convention", Origin.ESTIMATE: "from the scale"}


def units_text(scan: Scan) -> str:
    """"m (from the file)", "mm (from the scale)", "unknown (the scale cannot tell)", ..."""
    if scan.units_from is Origin.NONE:
        return f"{scan.units} (not stated; the scale cannot tell)"
    return f"{scan.units} ({_FROM[scan.units_from]})"


def viewpoint_text(scan: Scan, digits: int = 5) -> str:
    """The viewpoint and where it came from: "[0.0, 0.0, 0.0] (from the file)", "none (...)"."""
    if scan.viewpoint_from is Origin.NONE:
        return "none (no one sensor position: not a single view)"
    where = {Origin.GIVEN: "given", Origin.SIDECAR: "from the sidecar", Origin.FILE: "from the file",
             Origin.CONVENTION: "the frame's origin, where such files put the sensor",
             Origin.ESTIMATE: "estimated"}[scan.viewpoint_from]
    return f"{np.round(scan.viewpoint, digits).tolist()} ({where})"


def kind_text(scan: Scan) -> str:
    """The kind and why: "panorama (the points lie all around the viewpoint)", ..."""
    if scan.kind_from is Origin.GIVEN:
        why = "given"
    elif scan.kind_from is Origin.SIDECAR:
        why = "from the sidecar"
    elif scan.kind is ScanKind.PANORAMA:
        why = "the points lie all around the viewpoint"
    elif scan.kind is ScanKind.UNSTRUCTURED:
        why = "no sensor position, and the points are no single view from anywhere"
    elif scan.viewpoint_from is Origin.ESTIMATE:
        why = "a range grid" if scan.grid is not None else (
            "a stored surface" if scan.faces is not None else "the points look like one view")
    else:
        why = "the points lie in front of the viewpoint"
    return f"{scan.kind} ({why})"
