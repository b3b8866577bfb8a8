"""``rangereg info``: describe scans (points, kind, bounds, units, viewpoint, range grid, triangles, spacing),
each with where it came from (core.assemble); an E57 file given without ``#K`` is listed scan by scan (core.e57).
Several files are described in turn (``rangereg info frames/*.pcd``): one that cannot be read gets its one error
line and the others are still described; the status is then 2."""

from __future__ import annotations

import json
from argparse import Namespace

import numpy as np

# Above this many points without a range grid or stored faces, ``info`` skips the Delaunay that the
# triangle count needs unless asked (--triangles): 2M points took ~30 s of a 33 s ``info`` here.
COUNT_TRIANGLES_UP_TO = 200_000


def run(a: Namespace) -> int:
    from rangereg.core.errors import InputError

    paths = [a.scan] if isinstance(a.scan, str) else list(a.scan)
    if len(paths) == 1:
        return describe(a, paths[0])
    if a.viewpoint is not None:
        raise InputError("--viewpoint is for one scan: give it with one file")
    from rangereg.app.cli import _failed

    status, said = 0, False
    for path in paths:
        try:
            scan = read(a, path)
        except OSError as exc:
            if exc.filename is None:  # not the file's: the output's (a full disk, a closed pipe)
                raise
            status = _failed("info", exc)
            continue
        except (InputError, MemoryError) as exc:  # said in one line; the other files are still described
            status = _failed("info", exc)
            continue
        if said and not a.json:
            print()  # a blank line between two descriptions
        show(a, path, scan)
        said = True
    return status


def describe(a: Namespace, path: str) -> int:
    """Print the description of one scan file (``path``; an E57 without ``#K``: its list of scans)."""
    show(a, path, read(a, path))
    return 0


def read(a: Namespace, path: str):
    """What ``path`` holds: its Scan, or for an E57 without ``#K`` the list of its scans' headers (core.e57)."""
    from rangereg.core.e57 import SUFFIX, list_scans, split_selection
    from rangereg.core.errors import InputError
    from rangereg.core.io import load_scan

    file, selector = split_selection(path)
    if file.suffix.lower() == SUFFIX and selector is None:
        if a.viewpoint is not None:
            raise InputError(f"{file}: --viewpoint is for one scan; pick it with {file}#K")
        return list_scans(file)
    return load_scan(path, viewpoint=a.viewpoint, kind=getattr(a, "scan_kind", None))


def show(a: Namespace, path: str, scan) -> None:
    """Print what :func:`read` gave for ``path``."""
    from rangereg.core.assemble import kind_text, units_text, viewpoint_text
    from rangereg.core.e57 import split_selection
    from rangereg.core.scan import Origin

    if isinstance(scan, list):
        list_e57(a, split_selection(path)[0], scan)
        return
    tri, why_not = _triangles(scan, a.triangles)
    has_vp = scan.viewpoint_from is not Origin.NONE
    info = {"file": str(path), "points": len(scan.points), "bounds": [scan.points.min(0).tolist(), scan.points.max(0).tolist()],
            "kind": str(scan.kind), "kind_from": str(scan.kind_from),
            "units": scan.units, "units_from": str(scan.units_from),
            "viewpoint": scan.viewpoint.tolist() if has_vp else None, "viewpoint_from": str(scan.viewpoint_from),
            "viewpoint_estimated": scan.viewpoint_estimated,
            "grid": scan.grid is not None, "grid_shape": None if scan.grid is None else list(scan.grid.shape),
            "triangles": tri, "spacing": scan.spacing, "dropped": scan.dropped, "at_sensor": scan.at_sensor,
            "intensity": scan.intensity is not None,
            "ground_truth": scan.pose is not None, "stored_pose": scan.guess is not None, "notes": list(scan.notes)}
    if a.json:
        print(json.dumps(info))
        return
    lo, hi = info["bounds"]
    dropped = [f"{scan.dropped} NaN/inf"] if scan.dropped else []
    dropped += [f"{scan.at_sensor} on the sensor (no return)"] if scan.at_sensor else []
    print(f"{path}")
    print(f"  points      {info['points']}" + (f" ({', '.join(dropped)} dropped)" if dropped else "")
          + (", with intensity" if scan.intensity is not None else ""))
    print(f"  kind        {kind_text(scan)}")
    print(f"  bounds      {np.round(lo, 5).tolist()} .. {np.round(hi, 5).tolist()} {scan.units}")
    print(f"  units       {units_text(scan)}")
    print(f"  viewpoint   {viewpoint_text(scan)}")
    if scan.sensor_rotation is not None and not np.allclose(scan.sensor_rotation, np.eye(3)):
        print(f"  sensor      turned {np.degrees(_angle(scan.sensor_rotation)):.1f} deg from the scan frame's axes "
              "(the file's orientation; the points are as stored)")
    print(f"  range grid  {'x'.join(map(str, scan.grid.shape)) if scan.grid is not None else 'no'}")
    print(f"  triangles   {tri}" if tri is not None else f"  triangles   not counted ({why_not})")
    print(f"  spacing     {scan.spacing:.6g} {scan.units} (median nearest-neighbour)")
    if scan.pose is not None:
        print("  ground truth pose: yes")
    if scan.guess is not None:
        print(f"  stored pose {_pose_text(scan.guess)} (the rough guess)")
    for note in scan.notes:
        print(f"  note        {note}")


def _triangles(scan, asked: bool) -> tuple[int | None, str]:
    """The surface's triangle count, or None and why not."""
    from rangereg.core.errors import InputError
    from rangereg.core.surface import Surface

    cheap = scan.grid is not None or scan.faces is not None or len(scan.points) <= COUNT_TRIANGLES_UP_TO
    if not (cheap or asked):
        return None, f"no range grid, {len(scan.points)} points; --triangles counts them"
    try:
        return Surface.from_scan(scan).n_triangles, ""
    except InputError as exc:
        return None, str(exc)


def _angle(R: np.ndarray) -> float:
    from rangereg.core.transforms import rotation_angle

    return float(rotation_angle(R))


def _pose_text(T: np.ndarray) -> str:
    from rangereg.core.transforms import rotation_angle

    return f"t={np.round(T[:3, 3], 4).tolist()} rotation {np.degrees(rotation_angle(T[:3, :3])):.2f} deg"


def list_e57(a: Namespace, path, entries: list) -> int:
    """The scans of an E57 file from its headers (``entries``, core.e57.list_scans): index, name, points,
    coordinates, grid, pose."""
    if a.json:
        print(json.dumps({"file": str(path), "scans": [
            {"index": e.index, "name": e.name, "points": e.points, "coordinates": e.coordinates,
             "structured": e.structured, "grid": list(e.grid) if e.grid else None, "intensity": e.intensity,
             "pose": None if e.pose is None else e.pose.tolist()} for e in entries]}))
        return 0
    n = len(entries)
    print(f"{path}: {n} scan{'s' * (n != 1)} ({path}#K names one, K counted from 0; or {path}#NAME)")
    for e in entries:
        grid = "grid " + "x".join(map(str, e.grid)) if e.grid else ("grid" if e.structured else "no grid")
        pose = f"pose {_pose_text(e.pose)}" if e.pose is not None else "no pose"
        print(f"  #{e.index:<3d} {e.name or '(no name)'}  {e.points} points, {e.coordinates}, {grid}"
              f"{', intensity' if e.intensity else ''}; {pose}")
    return 0
