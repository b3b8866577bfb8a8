"""What the campaign benchmarks share: one campaign merged by ``rangereg merge``'s engine and by the peer
(benchmarks/multiway.py) from the same scans and poses, every scan scored against the truth.

The rule (the reading of the issues): a scan is right when it lies within RIGHT_DEG degrees and
RIGHT_MM millimetres of the truth relative to the first scan (translation at its centroid). A scan
our merge does not place is "not placed"; one placed beyond the rule is "wrong" (placed wrong).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace

import numpy as np
from rangereg.app.distributed import TaskRunner
from rangereg.core.guess import Guess
from rangereg.core.merge import clear_geometry_cache, merge
from rangereg.core.register import Config
from rangereg.core.transforms import invert, pose_error

from benchmarks.multiway import multiway

RIGHT_DEG, RIGHT_MM = 2.0, 2.0
MM = {"m": 1000.0, "mm": 1.0, "cm": 10.0}


@dataclass(frozen=True)
class Outcome:
    """One method on one campaign: per scan (degrees, mm) against the truth or None (not placed)."""

    errors: list
    seconds: float
    note: str = ""

    @property
    def right(self) -> int:
        return sum(e is not None and e[0] < RIGHT_DEG and e[1] < RIGHT_MM for e in self.errors)

    @property
    def unplaced(self) -> int:
        return sum(e is None for e in self.errors)

    @property
    def wrong(self) -> int:
        return len(self.errors) - self.right - self.unplaced

    def worst(self) -> str:
        placed = [e for e in self.errors if e is not None]
        if not placed:
            return "-"
        return f"{max(e[0] for e in placed):.3g} deg / {max(e[1] for e in placed):.3g} mm"


def score(poses: list, truth: list[np.ndarray], scans, reference: int = 0) -> list:
    """(degrees, mm) of each pose (T_reference_scan, None: not placed) against the truth relative to the
    reference (the first scan, unless our merge placed the others in another's frame: then the first
    counts as not placed)."""
    out = []
    for T, Tt, s in zip(poses, truth, scans):
        if T is None:
            out.append(None)
            continue
        rot, move = pose_error(T, invert(truth[reference]) @ Tt, s.points.mean(0))
        out.append((rot, move * MM.get(s.units, 1.0)))
    return out


def ours(scans, truth, initial, rotation_deg: float = 15.0, seed: int = 0, workers: int | None = None,
         progress=None) -> tuple[Outcome, object]:
    """``rangereg merge``'s engine from ``initial`` (None: no poses; else told the rotation
    ``rotation_deg`` per scan and no translation), the default runner (``workers=None``)."""
    clear_geometry_cache()
    plain = [replace(s, guess=None, pose=None) for s in scans]
    config = Config(method="global", seed=seed)
    t0 = time.perf_counter()
    with TaskRunner(workers, progress=progress) as runner:
        res = merge(plain, initial, config, build_model=False, map_tasks=runner.map, progress=progress,
                    stated=Guess.identity(rotation_deg))
    seconds = time.perf_counter() - t0
    cycles = [r.cycle for r in res.scans if r.cycle is not None]
    worst = "-" if not cycles else "{:.3f} deg / {:.3g}".format(*max(cycles))
    note = (f"{res.rounds} rounds, {res.registrations} registrations, {len(res.used)}/{len(res.pairs)} pairs used; "
            f"largest cycle residual {worst}; {runner.choice}")
    if res.reference != 0:
        note += f"; poses in {scans[res.reference].name}'s frame"
    return Outcome(score(res.poses, truth, scans, res.reference), seconds, note), res


def peer(scans, truth, initial) -> Outcome:
    poses, seconds = multiway(scans, initial if initial is not None else [np.eye(4) for _ in scans])
    return Outcome(score(poses, truth, scans), seconds)


def table(rows: list[tuple[str, Outcome, Outcome | None]]) -> str:
    """A markdown table: per campaign, ours and the peer (right / wrong / not placed, worst, seconds)."""
    head = ("| campaign | scans | ours: right / placed wrong / not placed | ours: worst placed | ours: s | "
            "Open3D multiway: right / wrong | multiway: worst | multiway: s |")
    lines = [head, "|" + "---|" * 8]
    for name, a, b in rows:
        n = len(a.errors)
        peer_cols = ("-", "-", "-") if b is None else (f"{b.right} / {b.wrong}", b.worst(), f"{b.seconds:.1f}")
        lines.append(f"| {name} | {n} | **{a.right}** / {a.wrong} / {a.unplaced} | {a.worst()} | {a.seconds:.1f} | "
                     f"{peer_cols[0]} | {peer_cols[1]} | {peer_cols[2]} |")
    return "\n".join(lines)


def load() -> str:
    return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
