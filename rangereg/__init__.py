"""rangereg: register 3-D range scans with the hybrid simulated annealing + ICP of Luck, Hoff, Underwood and
Little (ICRA 2000).

    import rangereg
    result = rangereg.register(source, target)       # paths, (N, 3) arrays, Open3D clouds or Scans
    result.T_target_source, result.below_threshold   # the pose (4, 4) and whether to trust it

:func:`register` (one pair), :func:`prepare` (a target's surface built once, for many frames),
:func:`stream` and ``listener=`` (the optimiser's events), :func:`legs`, :func:`merge` (campaigns):
rangereg.api, docs/python.md.

The repository's folders install under this one name: ``core/`` as ``rangereg.core`` (the engine, never
drawing), ``app/`` as ``rangereg.app`` (the command line and the viser workbench), ``assets/`` as the default
scenes' data. Nothing else lands at site-packages' top level.
"""

from __future__ import annotations

import importlib
import importlib.util
import os

# Python started in the repository's folder finds this folder before an installed copy (the script's folder or
# the working directory comes first on sys.path); the subpackages then lie beside it (core/, app/, assets/),
# where a non-editable install has no finder to look (an editable one maps them itself).
_CHECKOUT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if importlib.util.find_spec("rangereg.core") is None and os.path.isfile(os.path.join(_CHECKOUT, "core", "__init__.py")):
    __path__.append(_CHECKOUT)

# Loaded on first use, so that ``rangereg.app.cli`` (whose signal handlers go in before numpy loads) and
# ``rangereg.core`` import nothing more for being inside this package.
_PUBLIC = {
    **dict.fromkeys(("Leg", "Prepared", "Stream", "as_scan", "legs", "merge", "prepare", "register", "stream"),
                    "rangereg.api"),
    "InputError": "rangereg.core.errors", "Cancelled": "rangereg.core.events", "Event": "rangereg.core.events",
    "Guess": "rangereg.core.guess", "Result": "rangereg.core.result", "StopReason": "rangereg.core.result",
    "Scan": "rangereg.core.scan",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module 'rangereg' has no attribute {name!r}")
    value = getattr(importlib.import_module(_PUBLIC[name]), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_PUBLIC})
