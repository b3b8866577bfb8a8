"""The status above the panel's tabs: the pair, the run, its numbers, the threshold (named), the result.

One :class:`Progress` is taken per push from the drawn trail; the status and the lesson's sentence both quote it,
so a number in a sentence is the one the status shows. The status is HTML, not markdown: the browser sets it
on every push of a run (~14 a second), and a markdown panel re-parsed each time was the page's largest cost
after the 3-D frame (bunny SA run, load 9-14 on 2 cores: Pause from Playwright's click to "paused" median 1.6 s
as markdown, 1.2 s as HTML). Its progress rows never wrap, so the buttons below stay where they are.
"""

from __future__ import annotations

import html
from dataclasses import dataclass

import numpy as np
from rangereg.app.figures import fmt, squared_unit
from rangereg.app.views import temperature_of
from rangereg.core.events import Event
from rangereg.core.result import StopReason

ROW = "white-space:nowrap;overflow:hidden;text-overflow:ellipsis"


@dataclass(frozen=True)
class Progress:
    """The run as the status shows it: counts (ICP iterations, SA moves, local minima, candidates), the last event
    drawn, E on show and what it is (a key of E_LABEL: "initial", "event", or the run's end, :func:`outcome`), the
    temperature and where its leg began (NaN:
    none), E of the last local minimum (NaN: none), and the events drawn (``events[:n]``)."""

    n_icp: int = 0
    n_sa: int = 0
    n_min: int = 0
    candidates: int = 0
    last: Event | None = None
    E: float = float("nan")
    E_kind: str = "initial"
    temperature: float = float("nan")
    temperature_first: float = float("nan")
    minimum_E: float = float("nan")
    events: tuple = ()


# what the E on show is, as the status's E row and the replay's end of the timeline name it (the same words in both)
E_LABEL = {"initial": "initial", "event": "", "result": "the result",
           "cancelled": "cancelled: the best pose so far, not a result",
           "kept": "cancelled: the initial pose kept, not a result"}


def outcome(result) -> str:
    """Which pose a run's end shows, a key of E_LABEL: "result"; "cancelled", the best pose the run had found (the
    paper's methods, core.search.cancelled); "kept", the initial pose a cancelled Run global gives back."""
    if result.stop_reason is not StopReason.CANCELLED:
        return "result"
    return "kept" if result.found_by == "guess" else "cancelled"


def E_text(E: float, kind: str, units: str) -> str:
    """'E = 1.234 mm² (what it is)', as the status and the replay write it."""
    label = E_LABEL[kind]
    return f"E = {fmt(E)} {squared_unit(units)}" + (f" ({label})" if label else "")


def progress(trail, events: list, E0: float, result, running: bool) -> Progress:
    """The Progress of ``events`` as far as ``trail`` has drawn them (under the state's lock)."""
    n = min(trail.n, len(events))
    shown = tuple(events[:n])
    last = shown[-1] if shown else None
    n_icp, n_sa, n_min = trail.counts
    if result is not None and not running:  # one final E: the result's, as the Finished line and the export
        E, kind = float(result.error), outcome(result)
    elif last is not None:
        E, kind = float(last.error), "event"
    else:
        E, kind = float(E0), "initial"
    temp = first = float("nan")
    if last is not None and last.phase == "sa":
        temp = temperature_of(last)
        leg = [temperature_of(e) for e in shown if (e.phase, e.leg) == ("sa", last.leg)]
        first = next((t for t in leg if np.isfinite(t)), float("nan"))
    minima = [e.error for e in shown if e.local_minimum]
    return Progress(n_icp, n_sa, n_min, trail.candidates, last, E, kind, temp, first,
                    float(minima[-1]) if minima else float("nan"), shown)


def threshold_label(result, typed: bool) -> tuple[str, str]:
    """Which threshold the page shows, as (name, what it is): the pair threshold after Run global (its bound on the
    median matched d²), else the paper's E threshold, estimated from the scans' noise or as typed in Settings."""
    if result is not None and getattr(result, "details", None) is not None:
        return "Pair threshold", "Run global's test: median matched d², normals"
    return "Threshold", "the paper's, on E: " + ("as typed in Settings" if typed else "from the scans' noise")


def rows(p: Progress, *, pair: str, units: str, overlap: int, method: str, state: str, lock: str,
         threshold: float | None, threshold_name: str, guess: str, threshold_basis: str = "") -> list[str]:
    """The status's progress rows, as HTML (each one line; the threshold's value before what it is, so a narrow
    panel cuts the words, not the number)."""
    u = squared_unit(units)
    last = p.last
    phase = last.phase.upper() if last is not None else "-"
    counts = f"Iterations: ICP {p.n_icp}, SA {p.n_sa}" + (f", candidates {p.candidates}" if p.candidates else "")
    counts += f" · local minima {p.n_min}" + (f" (the last at E = {fmt(p.minimum_E)} {u})" if p.n_min else "")
    E = E_text(p.E, p.E_kind, units)
    if last is not None and last.phase == "sa" and not np.isfinite(p.temperature):
        temp = "temperature: set from the first simplex's spread of E"
    elif np.isfinite(p.temperature):
        temp = f"temperature {fmt(p.temperature)} {u}" + (
            f" (the leg began at {fmt(p.temperature_first)})" if np.isfinite(p.temperature_first) else "")
    else:
        temp = "temperature - (annealing only)"
    thr = fmt(threshold) if threshold is not None else "auto"
    e = html.escape
    basis = f" ({e(threshold_basis)})" if threshold_basis else ""
    return [f"<b>{e(pair)}</b> ({e(units)}) · overlap {overlap} points",
            f"Method <b>{e(method or '-')}</b> · {state} · phase <b>{phase}</b> · "
            + (f"locked <b>{e(lock)}</b>" if lock else "nothing locked"),
            counts, f"{E} · {temp}", f"{e(threshold_name)} {thr} {u}{basis}", e(guess)]


def page_html(progress_rows: list[str], more: list[str]) -> str:
    """The status block: one-line progress rows, then the lines that may wrap (the result, the lesson's step)."""
    body = "".join(f'<div style="{ROW}">{r}</div>' for r in progress_rows)
    body += "".join(f'<div style="margin-top:0.3em">{m}</div>' for m in more)
    return f'<div class="rangereg-status" style="font-size:0.875rem;line-height:1.45;padding:0 0.75rem">{body}</div>'
