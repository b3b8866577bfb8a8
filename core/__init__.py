"""rangereg's registration engine (Luck, Hoff, Underwood and Little, ICRA 2000), never drawing."""

from .errors import InputError
from .events import Cancelled, Event
from .io import load_conf, load_scan, read_transform, save_scan
from .panorama import image_of  # noqa: F401 (imported, a panorama's faces enter core.surface's table)
from .problem import ProblemConfig, prepare, relative_guess
from .register import METHODS, Config, Result, register
from .scan import Scan, ScanKind
from .surface import Surface
from .threads import one_blas_thread
from .unstructured import TangentPlanes  # noqa: F401 (imported, tangent planes enter the table too)

one_blas_thread()  # before any work: core.threads says why

__all__ = ["Cancelled", "Config", "Event", "InputError", "METHODS", "ProblemConfig", "Result", "Scan", "ScanKind",
           "Surface", "load_conf", "load_scan", "prepare", "read_transform", "register", "relative_guess",
           "save_scan"]
