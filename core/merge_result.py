"""What a merge found (core.merge): each pair's last registration, each scan's placement, the poses and
the model, as frozen objects with a readable repr. Poses are ``T_reference_scan``; a pair's ``T_i_j``
maps scan j into scan i's frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fuse import FusedModel

__all__ = ["MergeResult", "PairResult", "ScanReport"]


@dataclass(frozen=True, eq=False)
class PairResult:
    """One pair's last registration. ``T_i_j`` maps scan j into scan i's frame; ``start``: where it began
    ("rough poses", "no guess", "graph pose"); ``status`` "used" (an edge the graph kept, joined to the
    first scan) or "rejected", ``reason`` why; ``cycle``: (degrees, units) the residual of the cycle it
    closes (used) or by which it misses the final poses (rejected), None when on no cycle; ``earlier``:
    why its previous registration was not used, when it was registered again."""

    i: int
    j: int
    T_i_j: np.ndarray
    error: float
    overlap: float  # the share of the pair matching at T_i_j (core.merge_tasks.share_at)
    trusted: bool
    misfit: float | None
    within_region: bool | None
    seconds: float
    round: int
    start: str
    status: str = "rejected"
    reason: str = ""
    cycle: tuple | None = None
    earlier: str | None = None
    stop: str = ""  # why its registration's search stopped (core.result.Stop's text)

    def __repr__(self) -> str:
        return (f"PairResult({self.j}->{self.i}, E={self.error:.4g}, {'trusted' if self.trusted else 'untrusted'}, "
                f"{self.status}{': ' + self.reason if self.reason else ''})")


@dataclass(frozen=True)
class ScanReport:
    """placed: joined to the first scan by used pairs; trusted: partners (indices) of its trusted pairs;
    cycle: (degrees, units) the largest residual of the used cycles through it (None: on none); why:
    why it is not placed ("" when placed)."""

    name: str
    placed: bool
    trusted: tuple
    cycle: tuple | None
    why: str = ""


@dataclass(frozen=True, eq=False)
class MergeResult:
    poses: list  # (4, 4) T_reference_scan per scan (the first scan's frame, see reference); None where not placed
    pairs: list  # PairResult per registered pair (its last registration)
    scans: list  # ScanReport per scan
    model: FusedModel | None
    seconds: float
    pair_seconds: float = 0.0  # wall time of the pairwise stages (overlaps, cue, registrations), all rounds
    overlap_seconds: float = 0.0  # of which measuring overlaps and the cue
    mode: str = "init"
    rounds: int = 1
    registrations: int = 0  # pair registrations run, in all rounds
    reference: int = 0  # the scan whose frame the poses are in: the first, unless its group is not the largest

    @property
    def used(self) -> list:
        return [p for p in self.pairs if p.status == "used"]

    @property
    def placed(self) -> list[bool]:
        return [s.placed for s in self.scans]

    def __repr__(self) -> str:
        return (f"MergeResult({sum(self.placed)} of {len(self.poses)} scans placed, {len(self.used)} of "
                f"{len(self.pairs)} pairs used, {self.rounds} round(s), {self.seconds:.1f} s, {self.model!r})")
