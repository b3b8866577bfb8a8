"""One palette and one unit-label helper, shared by the page (viser, Plotly, uPlot) and the PNG export."""

from __future__ import annotations

import re

import numpy as np

TARGET_RGB = (60, 120, 220)
SOURCE_RGB = (240, 140, 30)
TARGET_OVERLAP_RGB = (120, 230, 255)
SOURCE_OVERLAP_RGB = (255, 225, 60)
# the path's legs: ICP green, annealing magenta, the global pipeline's candidate poses dark teal (not orange: that is
# the source's; every two colours of the legend are >= 25 apart in CIE76 Delta E, tests/test_views.py)
PHASE_RGB = {"icp": (30, 170, 70), "sa": (210, 50, 200), "candidates": (0, 110, 110)}
MINIMUM_RGB = (230, 30, 30)
MODEL_RGB = (200, 200, 190)
FRUSTUM_FADE = 0.55  # a frustum's lines are its scan's colour this far toward white: context, not content
SOURCE_PICK_RGB = (255, 60, 0)  # picked point pairs: darker than the scans they sit on
TARGET_PICK_RGB = (0, 40, 160)
PHASE_LABEL = {"icp": "ICP", "sa": "SA", "candidates": "candidates"}
# the drawn paths keep each event's phase as a row of PHASE_TABLE (phase_code), so a colour is one lookup;
# a phase without a colour (a stage added to core.events.PHASES alone) is drawn black, and a test says so
PHASE_NAMES = tuple(PHASE_RGB)
PHASE_TABLE = np.array([*PHASE_RGB.values(), (0, 0, 0)], np.uint8)  # (len(PHASE_NAMES) + 1, 3)


def phase_code(phase: str) -> int:
    """The row of PHASE_TABLE for ``phase`` (the last row, black, for a phase with no colour)."""
    return PHASE_NAMES.index(phase) if phase in PHASE_RGB else len(PHASE_NAMES)


def hex_colour(rgb: tuple[int, int, int]) -> str:
    """'#rrggbb' for a 0-255 RGB triple."""
    return "#{:02x}{:02x}{:02x}".format(*rgb)


def unit_fraction(rgb: tuple[int, int, int]) -> tuple[float, float, float]:
    """An RGB triple in 0-1 (matplotlib)."""
    return tuple(c / 255.0 for c in rgb)


def unit_label(param: str, units: str = "") -> str:
    """The unit a pose parameter is shown in: rotations in degrees, translations in the scan's own units."""
    if param.startswith("r"):
        return "deg"
    return units if units and units != "unknown" else "units"


def axis_label(param: str, units: str = "") -> str:
    return f"{param} ({unit_label(param, units)})"


def squared_unit(units: str = "") -> str:
    """The unit of E, a mean squared distance: the scans' length unit squared."""
    return f"{unit_label('t', units)}²"


# ---- numbers as people read them ------------------------------------------------------------------------------
DIGITS = 4  # significant digits of every number the page, the PNG and the recording show


def fmt(value: float | None, digits: int = DIGITS) -> str:
    """``value`` with ``digits`` significant digits: positional from 1e-5 to 1e6 (0.0009285, 706.1, 12340),
    else in exponent form (7.733e-09); "-" for None or NaN."""
    if value is None or not np.isfinite(value):
        return "-" if value is None or np.isnan(value) else ("inf" if value > 0 else "-inf")
    v = float(f"{float(value):.{digits}g}")
    if v == 0:
        return "0"
    if 1e-5 <= abs(v) < 1e6:
        decimals = max(0, digits - 1 - int(np.floor(np.log10(abs(v)))))
        text = f"{v:.{decimals}f}"
        return text.rstrip("0").rstrip(".") if "." in text else text
    return f"{v:.{digits - 1}e}"


_LONG_NUMBER = re.compile(r"(?<![\w.])-?\d+\.\d{4,}(?:e[-+]?\d+)?|(?<![\w.])-?\d\.\d+e[-+]?\d+")


def tidy(text: str, digits: int = DIGITS) -> str:
    """``text`` with every number written to more than ``digits`` significant digits shortened to them
    (core's messages print E with 6)."""
    return _LONG_NUMBER.sub(lambda m: fmt(float(m.group(0)), digits), text)


# ---- the legend: every colour the scene draws ---------------------------------------------------------------
LEGEND = (("source", SOURCE_RGB), ("target", TARGET_RGB), ("source overlap", SOURCE_OVERLAP_RGB),
          ("target overlap", TARGET_OVERLAP_RGB), ("ICP", PHASE_RGB["icp"]), ("annealing (SA)", PHASE_RGB["sa"]),
          ("candidates", PHASE_RGB["candidates"]), ("local minimum", MINIMUM_RGB))


RESIDUAL_STOPS = ((68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37))  # viridis, 0 to 1


def residual_legend(unit: str) -> tuple:
    """The legend while the source is coloured by its distance to the target (viridis: near dark purple, far
    yellow): the source's two colours give way to the scale, the rest stay."""
    scale = (f"source: distance to the target, 0 → 2√t ({unit})", RESIDUAL_STOPS)
    return (scale, *(e for e in LEGEND if e[0] not in ("source", "source overlap")))


def faded(rgb: tuple[int, int, int], fade: float = FRUSTUM_FADE) -> tuple[int, int, int]:
    """``rgb`` moved ``fade`` of the way toward white."""
    return tuple(int(round(c + fade * (255 - c))) for c in rgb)


def _swatch(rgb) -> str:
    """A CSS background: one colour, or a left-to-right gradient through several (a colour scale)."""
    if isinstance(rgb[0], int):
        return hex_colour(rgb)
    return "linear-gradient(to right, " + ", ".join(hex_colour(c) for c in rgb) + ")"


def legend_html(entries=LEGEND) -> str:
    """One line of coloured swatches and their names (the page's and the recording's legend); an entry's colour may
    be a tuple of colours, drawn as a scale."""
    items = "".join(f'<span style="white-space:nowrap;margin-right:10px"><span style="display:inline-block;'
                    f'width:{10 if isinstance(rgb[0], int) else 40}px;height:10px;border-radius:2px;margin-right:4px;'
                    f'background:{_swatch(rgb)}"></span>{name}</span>' for name, rgb in entries)
    return f'<div class="rangereg-legend" style="font-size:12px;line-height:1.6">{items}</div>'


def log_values(sl) -> np.ndarray:
    """(A, B) log10 E of a slice (a zero E, which has no log, at the smallest positive one): the scale of the page's
    contour, the PNG and the terrain."""
    v = np.asarray(sl.values, np.float64)
    return np.log10(np.maximum(v, np.nanmin(v[v > 0]) if np.any(v > 0) else 1e-300))
