"""The optimiser's event stream: every ICP iteration, annealing move and candidate pose, for the GUI,
the CLI's progress and ``--trace`` file (its format: core.trace) and the benchmarks. A listener may
raise :class:`Cancelled` to stop a run (the run then returns its best pose so far), or block to pause
or single-step it."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .transforms import to_params

PHASES = ("icp", "sa", "candidates")  # ICP steps, annealing moves (and hops), the global pipeline's candidates


class Cancelled(Exception):
    """Raised by a listener to stop the run; the run returns its best pose so far."""


@dataclass(frozen=True, eq=False)
class Event:
    """One step. T: (4, 4) T_target_source; error: robust E (squared units); temperature: SA only."""

    phase: str  # one of PHASES
    iteration: int  # 1-based count over the whole run (ICP + SA)
    phase_iteration: int  # 1-based count within this leg (0: a marker before the leg's first step)
    leg: int  # which ICP or SA leg of the run, from 1 (a basin-hopping hop is a one-move SA leg)
    T: np.ndarray
    error: float
    temperature: float | None = None
    accepted: bool = True
    local_minimum: bool = False  # ICP ended here above the threshold
    # under a lock (core.lock): the six coordinates the pose was made from, the locked ones exact
    coords: np.ndarray | None = None

    @property
    def params(self) -> np.ndarray:
        return to_params(self.T)

    def to_json(self) -> dict:
        d = {"phase": self.phase, "iteration": self.iteration, "phase_iteration": self.phase_iteration,
             "leg": self.leg, "params": self.params.tolist(), "transform": self.T.tolist(),
             "error": float(self.error), "temperature": None if self.temperature is None else float(self.temperature),
             "accepted": bool(self.accepted), "local_minimum": bool(self.local_minimum)}
        if self.coords is not None:
            d["coords"] = np.asarray(self.coords).tolist()
        return d

    @classmethod
    def from_json(cls, d: dict) -> Event:
        return cls(d["phase"], d["iteration"], d["phase_iteration"], d["leg"], np.asarray(d["transform"]),
                   d["error"], d.get("temperature"), d.get("accepted", True), d.get("local_minimum", False),
                   None if d.get("coords") is None else np.asarray(d["coords"], dtype=np.float64))


Listener = Callable[[Event], None]
