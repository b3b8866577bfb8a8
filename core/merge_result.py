"""What a merge found (core.merge): each pair's last registration, each scan's placement, the poses and
the model, as frozen objects with a readable repr; and the typed words they are said in (where a
pair's registration started, whether it was used and why not, whether a scan is placed). Poses are
``T_reference_scan``; a pair's ``T_i_j`` maps scan j into scan i's frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from .fuse import FusedModel
from .result import Stop

__all__ = ["MergeResult", "PairResult", "PairStatus", "Rejection", "ScanReport", "ScanStatus", "Start"]


class Start(StrEnum):
    """Where a pair's registration starts: its guess and region."""

    ROUGH_POSES = "rough poses"  # the initial poses, in twice the stated per-scan region
    NO_GUESS = "no guess"  # over all rotations and translations
    IDENTITY = "identity"  # consecutive frames of a sequence with no poses: the identity, in the stated region
    GRAPH_POSE = "graph pose"  # the pose graph's poses, in MergeConfig.found_rotation_deg


class PairStatus(StrEnum):
    """A registered pair in the final graph: an edge it kept (joined to the reference) or not."""

    USED = "used"
    REJECTED = "rejected"


class Rejection(StrEnum):
    """Why a registered pair is not used (the reason's kind; the reason itself says it with its figures)."""

    NOT_REGISTERED = "not registered"  # the registration refused the pair (e.g. nothing overlaps at the guess)
    NOT_TRUSTED = "not trusted"  # the pair threshold did not trust its pose
    OUTLIER = "outlier"  # trusted, but its E or misfit is far above the campaign's trusted pairs'
    DOES_NOT_CLOSE = "does not close"  # the pose graph switched it off (its cycles do not close, or ambiguous)
    NOT_JOINED = "not joined"  # its scans are not joined to the reference by used pairs


class ScanStatus(StrEnum):
    PLACED = "placed"
    NOT_PLACED = "not placed"


@dataclass(frozen=True, eq=False)
class PairResult:
    """One pair's last registration. ``T_i_j`` maps scan j into scan i's frame; ``start``: where it began;
    ``status``: used (an edge the graph kept, joined to the reference) or rejected, ``rejection`` the kind
    of why not and ``reason`` the why in words; ``cycle``: (degrees, units) the residual of the cycle it
    closes (used) or by which it misses the final poses (rejected), None when on no cycle; ``earlier``:
    why its previous registration was not used, when it was registered again; ``stop``: why its
    registration's search stopped (None: not registered, ``failure`` says why)."""

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
    start: Start
    status: PairStatus = PairStatus.REJECTED
    reason: str = ""
    cycle: tuple | None = None
    earlier: str | None = None
    stop: Stop | None = None
    failure: str = ""  # why the registration refused the pair ('' when it registered)
    # not trusted, its overlap leaving a motion free at T_i_j: what that overlap pins (core.threshold.Constraint, in
    # scan i's frame); None otherwise
    free: object = field(default=None, repr=False)
    rejection: Rejection | None = None
    # its pose puts points where the other scan's sensor looked through empty space (core.intrusion): a twin, which no
    # loop of the campaign corroborates
    twin: bool = False

    @property
    def key(self) -> tuple[int, int]:
        return self.i, self.j

    @property
    def registered(self) -> bool:
        return self.stop is not None

    @property
    def stop_text(self) -> str:
        """Why the search stopped in words, or why the pair was not registered."""
        return str(self.stop) if self.stop is not None else f"not registered: {self.failure}"

    def __repr__(self) -> str:
        return (f"PairResult({self.j}->{self.i}, E={self.error:.4g}, {'trusted' if self.trusted else 'untrusted'}, "
                f"{self.status}{': ' + self.reason if self.reason else ''})")


@dataclass(frozen=True)
class ScanReport:
    """status: placed (joined to the reference scan by used pairs) or not; trusted: partners (indices) of
    its trusted pairs; cycle: (degrees, units) the largest residual of the used cycles through it (None:
    on none); why: why it is not placed ("" when placed)."""

    name: str
    status: ScanStatus
    trusted: tuple
    cycle: tuple | None
    why: str = ""

    @property
    def placed(self) -> bool:
        return self.status is ScanStatus.PLACED


@dataclass(frozen=True)
class Ring:
    """A turntable's ring of scans closed by the pose graph: ``order`` the scans round it, ``closing``
    the pair that closes it, ``residual`` (degrees, units) by which that pair misses the ring's poses
    before the graph reconciles it (the drift the ring would have had), ``after`` the same against the
    final poses."""

    order: tuple
    closing: tuple
    residual: tuple
    after: tuple


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
    rings: tuple = ()  # Ring per closed loop of the final graph's cycle basis (the largest first)
    skipped: int = 0  # candidate pairs not registered because their overlap rules them out
    forecasts: tuple = ()  # core.merge_progress.Forecast per map of tasks long enough to estimate

    @property
    def used(self) -> list:
        return [p for p in self.pairs if p.status is PairStatus.USED]

    @property
    def placed(self) -> list[bool]:
        return [s.placed for s in self.scans]

    def __repr__(self) -> str:
        return (f"MergeResult({sum(self.placed)} of {len(self.poses)} scans placed, {len(self.used)} of "
                f"{len(self.pairs)} pairs used, {self.rounds} round(s), {self.seconds:.1f} s, {self.model!r})")
