"""What a registration returns: the pose, its error, why the search stopped, and the counts."""

from __future__ import annotations

from dataclasses import dataclass
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
    WORK_BOUND = "nothing trusted within the search's work"  # method "global": its steps or candidates are spent
    TIME_BOUND = "nothing trusted within the time bound"  # method "global" with seconds asked for: they are gone
    # method "global" asked to end there (core.candidates.CandidateConfig.end_on_weak): a pose that passes every test
    # but the score's rise, left to the caller's own evidence (a campaign's loops)
    WEAKLY_PINNED = "a candidate refined to a weakly pinned pose"


@dataclass(frozen=True)
class Stop:
    """A stop reason and its readable text (with the counts it names, e.g. "after 3 ICP runs")."""

    reason: StopReason
    text: str = ""

    def __str__(self) -> str:
        return self.text or self.reason.value


@dataclass(frozen=True)
class Iterations:
    """Steps per phase over a run: ICP iterations, annealing moves (and hops), candidates scored."""

    icp: int = 0
    sa: int = 0
    candidates: int = 0

    @property
    def total(self) -> int:
        return self.icp + self.sa + self.candidates

    def to_json(self) -> dict:
        """{"icp": n, "sa": n}, and "candidates" where any were scored (the global method)."""
        return {"icp": self.icp, "sa": self.sa, **({"candidates": self.candidates} if self.candidates else {})}


@dataclass(frozen=True, eq=False)
class Verdict:
    """The pair threshold's verdict on a pose (core.verdict), whichever method found it.

    threshold: the pair threshold (core.threshold.PairThreshold); misfit: its misfit at the pose (None when too
    little matches to judge); constraint: core.threshold.Constraint at the pose, what the matched overlap pins (None:
    not measured); intrusion: core.intrusion.intrusion at the pose (None: not measured); holds: the threshold's
    test held."""

    threshold: object
    misfit: float | None
    constraint: object = None
    intrusion: float | None = None
    holds: bool = False

    @property
    def pinned(self) -> bool:
        """The matched overlap pins all six degrees of freedom (core.threshold.constraint); True when unmeasured."""
        return self.constraint is None or self.constraint.pins(self.threshold.min_constraint)

    @property
    def looked_through(self) -> bool:
        """The pose puts the pair threshold's share of points or more where the other scan's sensor looked through
        empty space (core.intrusion): a twin of the overlap, not a right pose in doubt."""
        return self.intrusion is not None and self.intrusion >= self.threshold.max_intrusion

    @property
    def slid_through(self) -> bool:
        """The pose is pinned weakly (the score's rise along its free motion was asked, and passed) and puts the share
        of points a weakly pinned pose may (core.threshold.PairThreshold.slide_bound) or more where the other scan's sensor
        looked through empty space: a slide along that motion carries one scan's walls past where the other saw
        them end."""
        c = self.constraint
        return (c is not None and c.rise is not None and self.pinned and self.intrusion is not None
                and self.intrusion >= self.threshold.slide_bound)

    @property
    def text(self) -> str:
        """Why the test held or not, in words."""
        factor = self.threshold.factor
        if self.holds:
            return (f"where the scans overlap they agree at the noise level in distance and normals (misfit "
                    f"{self.misfit:.3g} < {factor:g})")
        if self.misfit is None:
            return "too little of the scans overlaps at this pose to judge it"
        if self.misfit < factor and self.looked_through:
            return (f"where the scans overlap they agree at the noise level, but {100 * self.intrusion:.1f} % of one "
                    "scan's points lie where the other's sensor looked through empty space (trusted below "
                    f"{100 * self.threshold.max_intrusion:g} %): the overlap fits a twin of itself, as a room's corner "
                    "fits itself turned about its diagonal, or a room itself turned a quarter turn")
        if self.misfit < factor and self.slid_through:
            return (f"where the scans overlap they agree at the noise level, but the overlap pins the pose weakly (it "
                    f"may slide by {self.constraint.free_motion}) and {100 * self.intrusion:.1f} % of one scan's points "
                    "lie where the other's sensor looked through empty space (a weakly pinned pose is trusted below "
                    f"{100 * self.threshold.slide_bound:g} %): slid along that motion, one scan's walls pass where the "
                    "other saw them end")
        if not self.pinned and self.misfit < factor:
            c, t = self.constraint, self.threshold
            if not c.matched:
                return "too little of the scans overlaps at this pose to judge what it pins"
            if c.ratio < t.min_constraint:
                free = t.free
                which = ("all six degrees of freedom" if free is None else
                         f"the {free.count} degrees of freedom the lock leaves free")
                return (f"where the scans overlap they agree at the noise level, but the overlap does not pin {which}: "
                        f"it lets the pose slide by {c.free_motion} (the matched point-to-plane "
                        f"system's weakest{'' if free is None else ' free'} / strongest eigenvalue {c.ratio:.3g} < "
                        f"{t.min_constraint:g})")
            return ("where the scans overlap they agree at the noise level, but the overlap pins the pose weakly "
                    f"and it slides freely by {c.free_motion}: slid that way by 3-8 match distances it scores "
                    f"only {c.rise:.3g} x as high (pinned from {t.min_rise:g} x)"
                    + ("" if c.stable_rise is None else
                       f", the points facing that motion {c.stable_rise:.3g} x (pinned from "
                       f"{t.min_stable_rise:g} x)"))
        return (f"the scans do not agree at the noise level where they overlap, or overlap too little (misfit "
                f"{self.misfit:.3g}, trusted below {factor:g})")

    def to_json(self) -> dict:
        return {"threshold_derivation": self.threshold.to_json(), "misfit": self.misfit,
                **({} if self.constraint is None else {"constraint": self.constraint.to_json()}),
                **({} if self.intrusion is None else {"intrusion": self.intrusion})}


@dataclass(frozen=True, eq=False)
class GlobalDetails:
    """What the ``global`` method (core.global_search) found out beside the pose.

    region: the stated region (core.region.Region); within_region: the pose lies inside it; beyond: where it lies
    otherwise, in words ('' inside); score: the pose's score on the pair's fixed basis (squared units); candidates:
    poses scored; candidate_sources: per stage, how many poses it gave or why it gave none; found_by: the stage
    whose refined pose this is ("guess", "kiss-matcher", "rotation samples", "fpfh-ransac 5 spacings", ...,
    "hybrid"). The pair threshold's verdict is the Result's (:class:`Verdict`)."""

    region: object
    within_region: bool
    beyond: str
    score: float
    candidates: int
    candidate_sources: dict
    found_by: str = ""

    def to_json(self) -> dict:
        return {"within_region": self.within_region, "region": self.region.to_json(), "beyond": self.beyond,
                "score": self.score, "candidates": self.candidates, "candidate_sources": dict(self.candidate_sources),
                "found_by": self.found_by}


@dataclass(frozen=True, eq=False)
class Result:
    """transform: (4, 4) T_target_source; error: final robust E (squared units); threshold: the E
    below which the pose is trusted (squared units; method "global": the pair threshold's bound on the
    median matched d^2 where the normals agree at their floor, core.threshold); iterations: steps per
    phase; evaluations: of E over the run; seconds: wall time from the call to the result; trusted: whether to
    trust the pose (None: E below the threshold decides); verdict: the pair threshold's test at the pose
    (core.verdict; the paper's methods ask it only when E ends below the threshold: None otherwise); details:
    what method "global" found beside the pose (None for the paper's methods)."""

    transform: np.ndarray
    error: float
    iterations: Iterations
    local_minima: int
    evaluations: int
    seconds: float
    method: str
    threshold: float
    stop: Stop
    cut: str = "frustum"  # the overlap cut under the guess (core.cut.CUTS: widened when the frustum's was empty)
    trusted: bool | None = None  # global: the verdict held; a paper method: E below the threshold and the verdict held
    verdict: Verdict | None = None
    details: GlobalDetails | None = None

    @property
    def T_target_source(self) -> np.ndarray:
        """(4, 4) the pose found: maps the source's points into the target's frame (``transform``)."""
        return self.transform

    @property
    def found_by(self) -> str:
        """Method "global": the stage whose refined pose this is ("guess", "rotation samples", ...); else ''."""
        return "" if self.details is None else self.details.found_by

    @property
    def stop_reason(self) -> StopReason:
        return self.stop.reason

    @property
    def stop_text(self) -> str:
        """Why the search stopped, in words, e.g. "restart budget (40 ICP runs) spent"."""
        return str(self.stop)

    @property
    def below_threshold(self) -> bool:
        """Trust this pose: the pair threshold's test held at it (core.verdict) and, for the paper's methods, E ended
        below the threshold as well; E below the threshold alone where no verdict was asked."""
        return bool(self.trusted) if self.trusted is not None else bool(self.error < self.threshold)

    @property
    def within_region(self) -> bool | None:
        """Method "global": the pose lies inside the stated region (core.region); None otherwise."""
        return None if self.details is None else self.details.within_region

    @property
    def trust_text(self) -> str:
        """Why to trust this pose or not, in words (and, for a pose beyond the stated region, where it lies)."""
        v, d = self.verdict, self.details
        if v is None:
            return f"E is {'below' if self.error < self.threshold else 'above'} the threshold ({self.threshold:.4g})"
        if d is None:  # a paper method whose E ended below the threshold: the pair threshold's test decides
            return (f"E is below the threshold ({self.threshold:.4g}), and {v.text}" if v.holds else
                    f"E is below the threshold ({self.threshold:.4g}) on the sample it was minimised on, but the pair "
                    f"threshold's test does not hold: {v.text}")
        return f"{v.text}; {d.beyond}" if d.beyond else v.text

    def __repr__(self) -> str:
        it = self.iterations
        found = f", found by {self.found_by}" if self.found_by else ""
        region = {None: "", True: ", within the stated region", False: ", beyond the stated region"}[self.within_region]
        steps = f"icp={it.icp} sa={it.sa}" + (f" candidates={it.candidates}" if it.candidates else "")
        rows = np.array2string(self.transform, precision=6, suppress_small=True, prefix="  T_target_source=")
        return (f"Result({self.method}: trusted {'yes' if self.below_threshold else 'no'}, E={self.error:.4g} "
                f"(threshold {self.threshold:.4g}){found}{region}, iterations {steps}, local_minima={self.local_minima}, "
                f"{self.seconds:.2f} s, stopped: {self.stop_text},\n  T_target_source={rows})")

    def to_json(self) -> dict:
        return {"transform": self.transform.tolist(), "error": self.error, "iterations": self.iterations.to_json(),
                "local_minima": self.local_minima, "evaluations": self.evaluations, "seconds": self.seconds,
                "method": self.method, "threshold": self.threshold, "stop_reason": self.stop_text,
                "below_threshold": self.below_threshold, "cut": self.cut,
                **({} if self.verdict is None else {"trusted": self.trusted, **self.verdict.to_json()}),
                **({} if self.details is None else self.details.to_json())}
