"""Numbers typed on the page, parsed as typed.

viser's number inputs rewrite what is typed (``2.5e-3`` became -2.53, ``12,5`` became 125, a seed
of ``1e30`` became 130) and clamp out-of-range values without a word, so the page takes numbers in
text fields and parses them here: a bad number or one out of range is an InputError (a notification),
never a mangled or clamped value.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

from rangereg.core.errors import InputError


@dataclass(frozen=True)
class Range:
    """Allowed values: lo..hi (each end closed unless ``*_open``); ``integer``: whole numbers only."""

    lo: float = -math.inf
    hi: float = math.inf
    lo_open: bool = False
    hi_open: bool = False
    integer: bool = False

    def describe(self) -> str:
        kind = "a whole number" if self.integer else "a number"
        lo, hi = (f"{self.lo:g}", f"{self.hi:g}")
        if math.isinf(self.lo) and math.isinf(self.hi):
            return kind
        if math.isinf(self.hi):
            return f"{kind} {'>' if self.lo_open else '>='} {lo}"
        if math.isinf(self.lo):
            return f"{kind} {'<' if self.hi_open else '<='} {hi}"
        return f"{kind} {'above' if self.lo_open else 'from'} {lo} {'and below' if self.hi_open else 'to'} {hi}"

    def holds(self, v: float) -> bool:
        above = v > self.lo if self.lo_open else v >= self.lo
        below = v < self.hi if self.hi_open else v <= self.hi
        return above and below


_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")


def parse_number(text, what: str, allowed: Range = Range()) -> float | int:
    """``text`` as typed -> a finite number in ``allowed``; anything else raises InputError naming ``what``."""
    t = str(text).strip()
    if "," in t and _NUMBER.fullmatch(t.replace(",", ".")):
        raise InputError(f"{what}: {t!r} has a comma; write decimals with a point ({t.replace(',', '.')})")
    if not _NUMBER.fullmatch(t):
        raise InputError(f"{what} must be {allowed.describe()}, got {t!r}")
    v = float(t)
    if not math.isfinite(v):
        raise InputError(f"{what} must be {allowed.describe()}, got {t!r}")
    if allowed.integer:
        if v != math.floor(v):
            raise InputError(f"{what} must be {allowed.describe()}, got {t!r}")
        v = int(t) if re.fullmatch(r"[+-]?\d+", t) else int(v)  # digits exactly; 1e3 via the float
    if not allowed.holds(v):
        raise InputError(f"{what} must be {allowed.describe()}, got {t!r}")
    return v


def parse_setting(text, name: str, label: str, auto: bool = False) -> float | int | None:
    """A setting typed on the page -> its value, checked against ``app.options.KNOBS[name]`` (the table the
    CLI checks too); a refusal names the page's ``label``. ``auto``: 'auto' or empty -> None (the core's default)."""
    from rangereg.app.options import parse_value

    t = str(text).strip()
    if auto and t.lower() in ("", "auto"):
        return None
    if "," in t and _NUMBER.fullmatch(t.replace(",", ".")):
        raise InputError(f"{label}: {t!r} has a comma; write decimals with a point ({t.replace(',', '.')})")
    try:
        return parse_value(name, t, label)
    except InputError as exc:
        raise InputError(f"{exc} (or 'auto')" if auto else str(exc)) from None


def parse_vector(text, what: str, n: int = 3) -> tuple[float, ...]:
    """``n`` numbers separated by spaces or commas."""
    parts = [p for p in re.split(r"[\s,;]+", str(text).strip()) if p]
    if len(parts) != n:
        raise InputError(f"{what} needs {n} numbers separated by spaces, got {str(text).strip()!r}")
    return tuple(float(parse_number(p, what)) for p in parts)


def show_number(v: float) -> str:
    """A number for a text field: exact enough to apply again unchanged to ~1e-10; round-off (|v| < 1e-12, such as
    a rotation of -2.8e-17 degrees) is shown as 0."""
    return "0" if abs(float(v)) < 1e-12 else f"{float(v):.10g}"


def show_vector(v) -> str:
    """A vector for a text field in 4 significant digits, as every number on the page (round-off shown as 0); the
    field's owner keeps the exact vector for a field left as shown."""
    from rangereg.app.figures import fmt

    return " ".join(fmt(0.0 if abs(float(x)) < 1e-12 else float(x)) for x in v)
