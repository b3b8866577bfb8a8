"""The page's settings: one entry per field, read into ``app.options.Settings`` and turned into a core
``Config`` by ``app.options.to_config``, the path the CLI takes too. Each number's kind and range is
``app.options.KNOBS`` under the same name (the one table); a refusal names the page's field.

So the page and the CLI run the same method from the same settings: a field left at ``auto`` keeps the
core's own default for each method (annealing alone cools and stops otherwise than the hybrid's legs).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import viser
from rangereg.app.options import KNOBS, Settings, parse_lock, to_config, to_guess
from rangereg.app.tab.fields import parse_setting
from rangereg.core.guess import DEFAULT_ROTATION_DEG, Guess
from rangereg.core.problem import ProblemConfig
from rangereg.core.register import Config

ANNEALS = "applies to Run hybrid and Run SA (the methods that anneal)"
_CORE = Config()


@dataclass(frozen=True)
class NumberField:
    """A number typed on the page: its label (what a refusal names), the text it starts with, its hint.
    ``auto``: 'auto' (or empty) leaves the core's default."""

    label: str
    initial: str
    hint: str
    auto: bool = False

    def full_hint(self, name: str) -> str:
        return f"{self.hint}; {KNOBS[name].describe()}{' or auto' if self.auto else ''}"


def _per_method(anneal: float, alone: float) -> str:
    return f"auto: {anneal:g} for the hybrid, {alone:g} for annealing alone"


# app.options.Settings field -> its field on the page, in the order drawn
NUMBERS: dict[str, NumberField] = {
    "threshold": NumberField("Threshold", "auto", "stop below this E; auto: from the scans' noise; 0: search until "
                             "annealing gives up", auto=True),
    "t_start": NumberField("Start temperature", "auto", f"auto: from the spread of E over the first simplex; {ANNEALS}",
                           auto=True),
    "t_min_ratio": NumberField("Minimum temperature ratio", "auto", "annealing stops below this fraction of its start "
                               f"temperature; {_per_method(_CORE.anneal.t_min_ratio, _CORE.sa_alone.t_min_ratio)}; "
                               f"{ANNEALS}", auto=True),
    "cooling": NumberField("Cooling", "auto", "temperature factor per block of moves; "
                           f"{_per_method(_CORE.anneal.cooling, _CORE.sa_alone.cooling)}; {ANNEALS}", auto=True),
    "seed": NumberField("Seed", str(_CORE.seed), "the same seed, the same run"),
    "icp_max_iterations": NumberField("ICP iteration cap", str(_CORE.icp.max_iterations), "iterations per ICP leg"),
    "sa_max_evaluations": NumberField("SA evaluation cap", "auto", "evaluations of E per annealing leg; "
                                      f"{_per_method(_CORE.anneal.max_evaluations, _CORE.sa_alone.max_evaluations)}; "
                                      f"{ANNEALS}", auto=True),
    "max_points": NumberField("Overlap sample size", str(_CORE.problem.max_points), "source points in E"),
    "rotation_uncertainty": NumberField("Rotation uncertainty (deg)", f"{DEFAULT_ROTATION_DEG:g}",
                                        "how far off the initial pose may be in rotation, about the source frame's "
                                        "origin; the paper's methods search twice this round the pose, Run global adds "
                                        "the move it implies at the centroid; 180: any rotation"),
    "translation_uncertainty": NumberField("Translation uncertainty", "auto", "how far off the initial pose may be in "
                                           "translation, in the scans' units; auto: 15 % of the target's size (Run "
                                           "global: free from a rotation of 90 deg up)", auto=True),
}
NO_GUESS_LABEL = "No guess (Run global)"
LOCK_LABEL = "Locked parameters"


FRUSTUM = _CORE.problem.frustum  # the dropdown starts at the core's default


@dataclass(eq=False)
class SettingsHandles:
    numbers: dict[str, viser.GuiTextHandle]  # by app.options.Settings field, as NUMBERS
    frustum: viser.GuiDropdownHandle
    coarse_to_fine: viser.GuiCheckboxHandle
    polish: viser.GuiCheckboxHandle
    lock: viser.GuiTextHandle
    no_guess: viser.GuiCheckboxHandle


def read_number(h: SettingsHandles, name: str) -> float | int | None:
    """One number field as typed, checked (InputError naming the field; never a clamped or rewritten value)."""
    f = NUMBERS[name]
    return parse_setting(h.numbers[name].value, name, f.label, f.auto)


def read_settings(h: SettingsHandles) -> Settings:
    """The settings as typed on the page, method left to the button that runs them."""
    return Settings(**{name: read_number(h, name) for name in NUMBERS}, frustum=h.frustum.value,
                    coarse_to_fine=bool(h.coarse_to_fine.value), polish=bool(h.polish.value),
                    lock=checked_lock(str(h.lock.value)), no_guess=bool(h.no_guess.value))


def checked_lock(text: str) -> str | None:
    """The lock as typed, once core takes it (a bad one raises InputError naming the field); None: none."""
    parse_lock(text.strip() or None, LOCK_LABEL)
    return text.strip() or None


def guess_text(s: Settings, T_init, source, target) -> str:
    """The initial pose's stated region as Run global takes it (core.region), in the user's words."""
    return page_guess(s, T_init, "global").region(source, target).describe()


def page_guess(s: Settings, T_init, method: str = "hybrid") -> Guess:
    """The initial pose ``T_init`` (4, 4) with the page's stated uncertainty, as ``method`` takes it (no guess:
    Run global only); the paper's methods by default, as the overlap cut the page shows (problem_config)."""
    page_config(s, method)  # every field checked, as a run would
    return to_guess(replace(s, method=method), T_init)


def problem_config(s: Settings) -> ProblemConfig:
    """The overlap cut the page shows (E, the slice, the residuals): the paper's, round the initial pose."""
    return page_config(s, "hybrid").problem


def page_config(s: Settings, method: str) -> Config:
    """The core Config for ``method`` from the page's settings (validated: bad values raise InputError)."""
    return to_config(replace(s, method=method))
