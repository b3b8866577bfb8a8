"""What a registration returns: the pose, its error, why the search stopped, and the counts."""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np


class StopReason(StrEnum):
    """Why a search stopped. Control flow compares members; the readable text is :class:`Stop`'s."""

    BELOW_THRESHOLD = "error below threshold"
    ICP_ABOVE_THRESHOLD = "ICP converged above the threshold"
    NO_BETTER_POINT = "annealing found no better point"
    MIN_TEMPERATURE = "minimum temperature reached"
    RESTARTS_SPENT = "restart budget spent"
    HOPS_SPENT = "hop budget spent"
    CANCELLED = "cancelled"
    TRUSTED = "a candidate refined below the pair threshold"  # method "global" (core.global_search)


@dataclass(frozen=True)
class Stop:
    """A stop reason and its readable text (with the counts it names, e.g. "after 3 ICP runs")."""

    reason: StopReason
    text: str = ""

    def __str__(self) -> str:
        return self.text or self.reason.value


@dataclass(frozen=True, eq=False)
class Result:
    """transform: (4, 4) T_target_source; error: final robust E (squared units); threshold: the E
    below which the pose is trusted (squared units; method "global": the pair threshold's bound on the
    median matched d^2 where the normals agree at their floor, core.threshold); iterations: {"icp": n,
    "sa": n} (more keys may follow); evaluations: of E over the run; seconds: wall time from the call to
    the result."""

    transform: np.ndarray
    error: float
    iterations: dict
    local_minima: int
    evaluations: int
    seconds: float
    method: str
    threshold: float
    stop: Stop
    cut: str = "frustum"  # the overlap cut under the guess (core.cut.CUTS: widened when the frustum's was empty)
    trusted: bool | None = None  # method "global": the pair threshold's verdict (core.threshold.PairThreshold)
    details: dict = field(default_factory=dict)  # method "global": threshold derivation, candidate sources, score

    @property
    def stop_reason(self) -> StopReason:
        return self.stop.reason

    @property
    def stop_text(self) -> str:
        """Why the search stopped, in words, e.g. "restart budget (40 ICP runs) spent"."""
        return str(self.stop)

    @property
    def below_threshold(self) -> bool:
        """Trust this pose: E ended below the threshold (method "global": the pair threshold's test on
        the candidates' fixed basis held)."""
        return bool(self.trusted) if self.trusted is not None else bool(self.error < self.threshold)

    @property
    def trust_text(self) -> str:
        """Why to trust this pose or not, in words."""
        misfit, derivation = self.details.get("misfit"), self.details.get("threshold_derivation")
        if self.trusted is None or derivation is None:
            return f"E is {'below' if self.below_threshold else 'above'} the threshold ({self.threshold:.6g})"
        if self.trusted:
            return (f"where the scans overlap they agree at the noise level in distance and normals (misfit "
                    f"{misfit:.3g} < {derivation['factor']:g})")
        if self.details.get("within_region") is False:
            return ("the pose lies farther from the guess than twice its stated uncertainty (a twin of a symmetric "
                    "scene may fit as well there; state a larger uncertainty to accept it)")
        if misfit is None:
            return "too little of the scans overlaps at this pose to judge it"
        return (f"the scans do not agree at the noise level where they overlap, or overlap too little (misfit "
                f"{misfit:.3g}, trusted below {derivation['factor']:g})")

    def __repr__(self) -> str:
        it = self.iterations
        return (f"Result({self.method}: E={self.error:.6g}, iterations icp={it['icp']} sa={it['sa']}, "
                f"local_minima={self.local_minima}, {self.seconds:.2f} s, stopped: {self.stop_text})")

    def to_json(self) -> dict:
        return {"transform": self.transform.tolist(), "error": self.error, "iterations": dict(self.iterations),
                "local_minima": self.local_minima, "evaluations": self.evaluations, "seconds": self.seconds,
                "method": self.method, "threshold": self.threshold, "stop_reason": self.stop_text,
                "below_threshold": self.below_threshold, "cut": self.cut, **self.details}
