"""``rangereg merge``: a set of scans -> globally consistent poses -> one fused mesh (core.merge)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from core.errors import InputError


def _poses_for(conf: dict[str, np.ndarray], scans, what: str) -> list[np.ndarray]:
    missing = [s.name for s in scans if s.name not in conf]
    if missing:
        raise InputError(f"{what} has no pose for {', '.join(missing)} (it lists {', '.join(sorted(conf))})")
    return [conf[s.name] for s in scans]


def main(a) -> int:
    from core.fuse import double_layer_fraction
    from core.io import load_conf, load_scan
    from core.merge import merge
    from core.ply import write_ply
    from core.problem import ProblemConfig
    from core.register import Config
    from core.transforms import invert, pose_error

    if len(a.scans) < 2:
        raise InputError("merge needs at least two scans")
    if a.seed < 0:
        raise InputError(f"--seed must be >= 0, got {a.seed}")
    scans = [load_scan(p) for p in a.scans]
    names = [s.name for s in scans]
    if len(set(names)) != len(names):
        raise InputError(f"two scans share a name ({', '.join(names)}): rename one")
    initial = _poses_for(load_conf(a.init), scans, a.init) if a.init else None
    truth = _poses_for(load_conf(a.truth), scans, a.truth) if a.truth else None
    if truth is None and all(s.pose is not None for s in scans):
        truth = [s.pose for s in scans]  # ground truth stored with the scans (sidecar or .conf beside them)
    config = Config(seed=a.seed, problem=ProblemConfig(rotation_uncertainty_deg=25.0))
    say = (lambda msg: sys.stderr.write(f"  {msg}\n")) if not a.json else None
    res = merge(scans, initial, config, progress=say)
    out = Path(a.out)
    gap = float(np.median([s.spacing for s in scans]))
    write_ply(out, res.model.vertices, res.model.faces, comments=("rangereg fused model",))
    report = {
        "scans": names,
        "poses": [np.asarray(T).tolist() for T in res.poses],
        "pairs": [{"target": names[p.i], "source": names[p.j], "error": p.error, "overlap": p.overlap}
                  for p in res.pairs],
        "seconds": res.seconds,
        "model": {"path": str(out), "vertices": len(res.model.vertices), "triangles": len(res.model.faces),
                  "double_layer_fraction": double_layer_fraction(res.model.vertices, res.model.faces, gap)},
    }
    if truth is not None:
        errs = [pose_error(T, invert(truth[0]) @ Tt, s.points.mean(0)) for T, Tt, s in zip(res.poses, truth, scans)]
        report["rotation_error_deg"] = [e[0] for e in errs]
        report["translation_error"] = [e[1] for e in errs]
    if a.json:
        print(json.dumps(report))
        return 0
    print(f"registered {len(res.pairs)} pairs in {res.seconds:.1f} s:")
    for p in report["pairs"]:
        print(f"  {p['source']} -> {p['target']}  E={p['error']:.4g}  overlap {p['overlap']:.0%}")
    print(f"poses (into {names[0]}'s frame):")
    for k, (name, T) in enumerate(zip(names, res.poses)):
        line = f"  {name}: t={np.round(T[:3, 3], 6).tolist()}"
        if truth is not None:
            line += f"  vs truth {report['rotation_error_deg'][k]:.3f} deg, {report['translation_error'][k]:.4g} {scans[k].units}"
        print(line)
    m = report["model"]
    print(f"model: {m['vertices']} vertices, {m['triangles']} triangles, double layer on "
          f"{m['double_layer_fraction']:.2%} of triangles -> {out}")
    return 0
