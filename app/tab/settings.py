"""The page's settings as plain values, and the one mapping from them to a core ``Config``.

``page_config`` is the only place the page turns settings into a config; it goes through
app/options.py, the settings path shared by the CLI, the page and merge.
"""

from __future__ import annotations

from dataclasses import dataclass

from app.options import Settings, to_config
from core.problem import ProblemConfig
from core.register import Config


@dataclass(frozen=True)
class PageSettings:
    threshold: float | None = None  # None: auto (from the scans' noise)
    t_start: float | None = None  # None: auto (from the first simplex)
    t_min_ratio: float | None = None  # None: each method's own (hybrid 1e-2, annealing alone 1e-5)
    cooling: float = 0.9
    seed: int = 0
    icp_max: int = 100
    sa_max: int = 20000
    frustum: str = "convex"
    max_points: int = 300
    coarse_to_fine: bool = False
    polish: bool = False
    lock: str = ""  # locked degrees of freedom as --lock takes them ("rx,ry,tz", "rotation", "turntable:..."); "": none


def problem_config(s: PageSettings) -> ProblemConfig:
    return ProblemConfig(max_points=s.max_points, frustum=s.frustum)


def page_config(s: PageSettings, method: str) -> Config:
    """The core Config for ``method`` from the page's settings (validated: bad values raise InputError),
    through app.options, the one settings path the CLI, the page and merge share.

    The annealing settings reach both methods that anneal: the hybrid's legs and annealing alone.
    """
    return to_config(Settings(method=method, seed=s.seed, threshold=s.threshold, max_points=s.max_points,
                              frustum=s.frustum, t_start=s.t_start, t_min_ratio=s.t_min_ratio, cooling=s.cooling,
                              icp_max_iterations=s.icp_max, sa_max_evaluations=s.sa_max, polish=s.polish,
                              coarse_to_fine=s.coarse_to_fine, lock=s.lock.strip() or None))
