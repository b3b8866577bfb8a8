"""Open3D imported without its plotly drawing, which the engine never uses.

``import open3d`` imports ``open3d.visualization.draw_plotly``, which imports plotly and dash (a web
framework, with flask, werkzeug, requests and IPython behind it): 0.33 s of the 0.69 s the import takes
(python -X importtime, Open3D 0.20, this machine), a quarter of a `rangereg register`'s imports.
:func:`defer_plotly` puts a stand-in for that one module in place before Open3D is imported: it carries
the three names Open3D's package takes from it, each loading the real module when first called, and any
other name loads it at once. Whoever draws with plotly gets the real thing; nobody else pays for it.
"""

from __future__ import annotations

import importlib
import sys
import types

PLOTLY_MODULE = "open3d.visualization.draw_plotly"
NAMES = ("get_plotly_fig", "draw_plotly", "draw_plotly_server")  # what open3d.visualization takes from it


class _Deferred(types.ModuleType):
    """The stand-in: attribute access beyond :data:`NAMES` loads the real module and answers from it."""

    def __getattr__(self, name: str):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(_real(), name)


def _real() -> types.ModuleType:
    """The real plotly module, imported now in place of the stand-in (once)."""
    here = sys.modules.get(PLOTLY_MODULE)
    if here is not None and not isinstance(here, _Deferred):
        return here
    sys.modules.pop(PLOTLY_MODULE, None)
    real = importlib.import_module(PLOTLY_MODULE)
    visualization = sys.modules.get("open3d.visualization")
    if visualization is not None:  # the package's names now point at the real functions
        for name in NAMES:
            if isinstance(getattr(visualization, name, None), _Forward):
                setattr(visualization, name, getattr(real, name))
    return real


class _Forward:
    """One of :data:`NAMES`: calls the real function, loading its module on the first call."""

    def __init__(self, name: str):
        self.__name__ = self.__qualname__ = name
        self.__doc__ = f"open3d.visualization.{name} (its module, plotly and dash load on the first call)"

    def __call__(self, *args, **kwargs):
        return getattr(_real(), self.__name__)(*args, **kwargs)

    def __repr__(self) -> str:
        return f"<open3d.visualization.{self.__name__}, not loaded yet>"


def defer_plotly() -> None:
    """Put the stand-in for Open3D's plotly module in place (module notes), so that every later ``import open3d``
    in this process skips plotly and dash; nothing when Open3D or that module is imported already."""
    if "open3d" in sys.modules or PLOTLY_MODULE in sys.modules:
        return
    stand_in = _Deferred(PLOTLY_MODULE, "open3d's plotly drawing, loaded on first use (rangereg.core.open3d_import)")
    for name in NAMES:
        setattr(stand_in, name, _Forward(name))
    sys.modules[PLOTLY_MODULE] = stand_in
