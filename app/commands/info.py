"""``rangereg info``: describe a scan (points, bounds, units, viewpoint, range grid, triangles, spacing)."""

from __future__ import annotations

import json
from argparse import Namespace

import numpy as np

# Above this many points without a range grid or stored faces, ``info`` skips the Delaunay that the
# triangle count needs unless asked (--triangles): 2M points took ~30 s of a 33 s ``info`` here.
COUNT_TRIANGLES_UP_TO = 200_000


def run(a: Namespace) -> int:
    from core.io import load_scan
    from core.surface import Surface

    scan = load_scan(a.scan, viewpoint=a.viewpoint)
    cheap = scan.grid is not None or scan.faces is not None or len(scan.points) <= COUNT_TRIANGLES_UP_TO
    tri = Surface.from_scan(scan).n_triangles if cheap or a.triangles else None
    info = {"points": len(scan.points), "bounds": [scan.points.min(0).tolist(), scan.points.max(0).tolist()],
            "units": scan.units, "viewpoint": scan.viewpoint.tolist(), "viewpoint_estimated": scan.viewpoint_estimated,
            "grid": scan.grid is not None, "triangles": tri, "spacing": scan.spacing, "dropped": scan.dropped,
            "ground_truth": scan.pose is not None}
    if a.json:
        print(json.dumps(info))
        return 0
    lo, hi = info["bounds"]
    print(f"{a.scan}")
    print(f"  points      {info['points']}" + (f" ({scan.dropped} NaN/inf dropped)" if scan.dropped else ""))
    print(f"  bounds      {np.round(lo, 5).tolist()} .. {np.round(hi, 5).tolist()} {scan.units}")
    print(f"  viewpoint   {np.round(scan.viewpoint, 5).tolist()}" + (" (estimated)" if scan.viewpoint_estimated else ""))
    print(f"  range grid  {'x'.join(map(str, scan.grid.shape)) if scan.grid is not None else 'no'}")
    print(f"  triangles   {tri}" if tri is not None else
          f"  triangles   not counted (no range grid, {len(scan.points)} points; --triangles counts them)")
    print(f"  spacing     {scan.spacing:.6g} {scan.units} (median nearest-neighbour)")
    if scan.pose is not None:
        print("  ground truth pose: yes")
    return 0
