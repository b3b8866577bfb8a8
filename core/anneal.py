"""Simplex simulated annealing (paper section 2.3; Numerical Recipes' ``amebsa``, paper [16]).

A Nelder-Mead simplex of n + 1 vertices walks downhill by replacing its worst vertex. Thermal
fluctuation: a positive random amount ``-T log(u)`` is added to every stored vertex value and
subtracted from every tried replacement, so true downhill moves are always taken and some uphill
ones too. The temperature starts from the spread of E over the first simplex, falls geometrically
(``cooling`` after every ``moves_per_temperature`` moves) and annealing ends below
``t_min_ratio`` times the start. While hot, the simplex roams (paper 2.3: "at high temperatures
... the simplex roams freely"); only below ``settle_below`` times the start temperature is it
restarted at the best point found after each temperature, so that it settles there (a roaming
simplex can end flattened away from the minimum). Measured against restarting it from the first
temperature on (10 starts): the hybrid on bun090 -> bun000 50 -> 90 % in half the time (settling
below 0.1; 0.01 does as well, slower), annealing alone on the corner 30 -> 70 % (settling below
0.01; 0.1 gives 20 %). In the hybrid it also ends as soon as it finds a point below
``stop_below`` (a better starting point for ICP).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .errors import InputError


@dataclass(frozen=True)
class AnnealConfig:
    t_start: float | None = None  # None: the spread (max - min) of E over the first simplex ...
    t_start_cap: float | None = 1.0  # ... but at most this times E at the start point
    t_min_ratio: float = 1e-2  # stop when the temperature falls below this fraction of the start
    cooling: float = 0.9  # temperature factor after each block of moves
    moves_per_temperature: int = 15
    max_evaluations: int = 20000
    ftol: float = 1e-6  # a simplex this flat (relative) waits for the next temperature
    # below this fraction of the start temperature the simplex restarts at the best point found after
    # every temperature (it settles there); above, it roams. See the module docstring.
    settle_below: float = 0.1

    def validate(self) -> None:
        if not 0 < self.cooling < 1:
            raise InputError(f"cooling must be between 0 and 1, got {self.cooling}")
        if not 0 < self.t_min_ratio < 1:
            raise InputError(f"the minimum temperature ratio must be between 0 and 1, got {self.t_min_ratio}")
        if self.moves_per_temperature < 1 or self.max_evaluations < 7:
            raise InputError("annealing needs at least 1 move per temperature and 7 evaluations")
        if not 0 <= self.settle_below <= 1:
            raise InputError(f"settle_below must be between 0 and 1, got {self.settle_below}")
        if self.t_start is not None and not self.t_start > 0:
            raise InputError(f"the start temperature must be positive, got {self.t_start}")


@dataclass(frozen=True, eq=False)
class AnnealResult:
    x: np.ndarray  # best point found, (n,)
    value: float
    evaluations: int
    improved: bool  # found a point below stop_below
    temperature: float

    def __repr__(self) -> str:
        return f"AnnealResult(value={self.value:.6g}, evaluations={self.evaluations}, improved={self.improved})"


OnEval = Callable[[np.ndarray, float, float, bool], None]  # (x, value, temperature, accepted)


class _Found(Exception):
    pass


def anneal(f: Callable[[np.ndarray], float], x0: np.ndarray, steps: np.ndarray, rng: np.random.Generator,
           config: AnnealConfig = AnnealConfig(), stop_below: float | None = None,
           on_eval: OnEval | None = None, f0: float | None = None) -> AnnealResult:
    """Minimise ``f`` from ``x0`` (n,) with a first simplex of ``x0`` and ``x0 + steps[i] e_i``."""
    x0 = np.asarray(x0, dtype=np.float64)
    n = len(x0)
    p = np.tile(x0, (n + 1, 1))
    p[1:] += np.diag(np.asarray(steps, dtype=np.float64))
    state = {"evals": 0, "temp": 0.0, "best_x": x0.copy(), "best_y": np.inf}

    def fx(x, accepted_hint=True):
        y = float(f(x))
        state["evals"] += 1
        if y < state["best_y"]:
            state["best_x"], state["best_y"] = x.copy(), y
        return y

    def report(x, y, accepted):
        if on_eval is not None:
            on_eval(x, y, state["temp"], accepted)
        if stop_below is not None and state["best_y"] < stop_below:
            raise _Found

    y = np.empty(n + 1)
    try:
        if f0 is not None:
            y[0] = f0
            state["best_y"] = f0
        else:
            y[0] = fx(p[0])
            report(p[0], y[0], True)
        for i in range(1, n + 1):
            y[i] = fx(p[i])
            report(p[i], y[i], True)
        finite = y[np.isfinite(y)]
        spread = float(finite.max() - finite.min())
        t0 = config.t_start
        if t0 is None:
            t0 = spread if config.t_start_cap is None else min(spread, config.t_start_cap * abs(y[0]))
            t0 = max(t0, 1e-12 * max(abs(y.min()), 1e-300))
        state["temp"] = t0
        t_min = t0 * config.t_min_ratio
        steps = np.asarray(steps, dtype=np.float64)
        while state["temp"] >= t_min and state["evals"] < config.max_evaluations:
            _moves(p, y, fx, report, rng, state, config)
            state["temp"] *= config.cooling
            if state["temp"] < config.settle_below * t0:
                # Restart the simplex at the best point found, sized for the new temperature (thermal
                # spread in a quadratic well goes as sqrt(T)); NR suggests such restarts for amebsa.
                size = steps * np.sqrt(state["temp"] / t0)
                p[:] = state["best_x"]
                p[1:] += np.diag(size)
                y[0] = state["best_y"]
                for i in range(1, n + 1):
                    y[i] = fx(p[i])
                    report(p[i], y[i], True)
    except _Found:
        pass
    improved = stop_below is not None and state["best_y"] < stop_below
    return AnnealResult(state["best_x"], state["best_y"], state["evals"], improved, state["temp"])


def _moves(p, y, fx, report, rng, state, config):
    """``moves_per_temperature`` amebsa moves at the current temperature."""
    n = p.shape[1]
    T = state["temp"]
    psum = p.sum(0)
    budget = config.moves_per_temperature
    while budget > 0 and state["evals"] < config.max_evaluations:
        yv = y - T * np.log(rng.random(n + 1))  # stored values plus a positive fluctuation
        order = np.argsort(yv)
        ilo, ihi, inhi = order[0], order[-1], order[-2]
        ylo, yhi, ynhi = yv[ilo], yv[ihi], yv[inhi]
        if np.isfinite(yhi) and 2.0 * abs(yhi - ylo) <= config.ftol * (abs(yhi) + abs(ylo)) + 1e-300:
            return
        budget -= 1
        ytry, yhi = _amotsa(p, y, psum, ihi, yhi, -1.0, fx, report, rng, T)
        if ytry <= ylo:
            _amotsa(p, y, psum, ihi, yhi, 2.0, fx, report, rng, T)
        elif ytry >= ynhi:
            ysave = yhi
            ytry, yhi = _amotsa(p, y, psum, ihi, yhi, 0.5, fx, report, rng, T)
            if ytry >= ysave:  # shrink towards the lowest vertex
                for i in range(n + 1):
                    if i != ilo:
                        p[i] = 0.5 * (p[i] + p[ilo])
                        y[i] = fx(p[i])
                        report(p[i], y[i], True)
                psum[:] = p.sum(0)


def _amotsa(p, y, psum, ihi, yhi, fac, fx, report, rng, T):
    n = p.shape[1]
    fac1 = (1.0 - fac) / n
    fac2 = fac1 - fac
    ptry = psum * fac1 - p[ihi] * fac2
    ytry = fx(ptry)
    yflu = ytry + T * np.log(rng.random())  # the tried point minus a positive fluctuation
    accepted = bool(yflu < yhi)
    if accepted:
        y[ihi] = ytry
        yhi = yflu
        psum += ptry - p[ihi]
        p[ihi] = ptry
    report(ptry, ytry, accepted)
    return yflu, yhi
