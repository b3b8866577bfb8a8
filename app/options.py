"""Plain settings -> a core ``Config``: the one mapping the CLI, the page and ``merge`` share.

Every number a user may type is declared once in :data:`KNOBS` (kind, range, why the bound) and
checked once by :func:`parse_value`, whether it arrives as CLI text, page text or a number. A
:class:`Settings` holds checked values (``None``: the core's own default) and :func:`to_config` is
the only place that turns them into ``core.register.Config`` + ``ProblemConfig``, and :func:`to_guess`
the only place that turns the stated uncertainty (or no guess) and a pose into a ``core.guess.Guess``.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
from rangereg.core.errors import InputError


@dataclass(frozen=True)
class Knob:
    """A number setting: ``kind`` int or float; ``low``/``high`` bounds (None: open-ended);
    ``low_open``/``high_open``: the bound itself is refused."""

    flag: str
    kind: type
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def bounds(self) -> str:
        """The range in words, e.g. ``>= 2 and <= 201``."""
        num = lambda v: f"{int(v)}" if float(v).is_integer() else f"{v:g}"  # noqa: E731
        parts = [f"{'>' if self.low_open else '>='} {num(self.low)}" if self.low is not None else "",
                 f"{'<' if self.high_open else '<='} {num(self.high)}" if self.high is not None else ""]
        return " and ".join(p for p in parts if p)

    def describe(self) -> str:
        return f"{'a whole number' if self.kind is int else 'a number'} {self.bounds()}".strip()


# Upper bounds keep a typo from running for hours or a number from meaning nothing.
KNOBS: dict[str, Knob] = {
    "seed": Knob("--seed", int, 0, 2**32 - 1),  # as numpy's legacy seeds; exact in every JSON and page field
    "max_points": Knob("--max-points", int, 3, 100_000),  # paper: 165-341; one E over 300 points: 0.24 ms
    # beyond 180: the other way; below 0.01 deg a scan 1000 spacings wide turns by < 0.1 spacing at its edge (the
    # noise), and the annealing simplex, scaled by it, collapses
    "rotation_uncertainty": Knob("--rotation-uncertainty", float, 0.01, 180),
    "translation_uncertainty": Knob("--translation-uncertainty", float, 0, None, low_open=True),
    "threshold": Knob("--threshold", float, 0, None),
    "t_start": Knob("--t-start", float, 0, None, low_open=True),
    "t_min_ratio": Knob("--t-min-ratio", float, 0, 1, low_open=True, high_open=True),
    "cooling": Knob("--cooling", float, 0, 1, low_open=True, high_open=True),
    "icp_max_iterations": Knob("--icp-max-iterations", int, 1, 100_000),
    "sa_max_evaluations": Knob("--sa-max-evaluations", int, 7, 10_000_000),  # 10^7 x 0.24 ms: 40 min
    "hops": Knob("--hops", int, 0, 100_000),  # each hop is an ICP run (~5-50 ms here): at most about an hour
    "restarts": Knob("--restarts", int, 1, 100_000),  # likewise
    "recut_rounds": Knob("--recut-rounds", int, 1, 20),  # measured: a second round rarely differs (core/register.py)
    "steps": Knob("--steps", int, 2, 201),  # 201 x 201 evaluations take about 10 s here (0.24 ms each)
    "runs": Knob("--runs", int, 1, 1000),  # a full bench of 10 starts takes about 15 min
    "rotation_samples": Knob("--rotation-samples", int, 0, 100_000),  # scored in one batch: 720 take ~50 ms
    "workers": Knob("--workers", int, 1, 1024),  # Dask worker processes (merge); more than the cores only queue
    "threads": Knob("--threads", int, 1, 1024),  # threads per task stream (merge): Open3D's, OpenMP's, BLAS's
    "port": Knob("--port", int, 1, 65535),  # TCP ports
    "time_limit": Knob("--time-limit", float, 0, 86_400, low_open=True),  # seconds; a day is beyond any use here
    "upload_cap_mb": Knob("--upload-cap-mb", float, 0, 100_000, low_open=True),  # 100 GB: beyond any memory here
}

_WHOLE = re.compile(r"[+-]?\d+")


def parse_value(name: str, value, label: str | None = None) -> int | float:
    """``value`` (text as typed, or a number) checked against ``KNOBS[name]``; raises InputError
    ``"<label> must be ..., got ..."`` (label defaults to the CLI flag)."""
    knob = KNOBS[name]
    label = label or knob.flag
    problem = check_value(knob, value)
    if isinstance(problem, str):
        raise InputError(f"{label}: {problem}")
    return problem


def check_value(knob: Knob, value) -> int | float | str:
    """The checked value, or a message (str) saying what is wrong with it."""
    shown = repr(value) if isinstance(value, str) else f"{value}"
    if isinstance(value, bool):
        return f"expected {knob.describe()}, got {value}"
    if isinstance(value, str):
        text = value.strip()
        if knob.kind is int:
            if not _WHOLE.fullmatch(text):
                return f"expected a whole number, got {shown}"
            v: int | float = int(text)
        else:
            try:
                v = float(text)
            except ValueError:
                return f"expected a number, got {shown}"
    elif isinstance(value, (int, float, np.integer, np.floating)):
        v = value.item() if isinstance(value, np.generic) else value
        if knob.kind is int:
            if isinstance(v, float) and not (math.isfinite(v) and v.is_integer()):
                return f"expected a whole number, got {shown}"
            v = int(v)
    else:
        return f"expected {knob.describe()}, got {shown}"
    if knob.kind is float:
        v = float(v)
        if not math.isfinite(v):
            return f"expected a finite number, got {shown}"
    too_low = knob.low is not None and (v <= knob.low if knob.low_open else v < knob.low)
    too_high = knob.high is not None and (v >= knob.high if knob.high_open else v > knob.high)
    if too_low or too_high:
        return f"must be {knob.bounds()}, got {shown}"
    return v


_AUTO = ("", "auto", "none")


@dataclass(frozen=True)
class Settings:
    """Checked plain values for one registration. ``None``: the core's own default. Values may be
    given as text (the page's fields): ``Settings(seed="3", threshold="auto")``."""

    method: str | None = None  # None: core.config.Config's default
    seed: int = 0
    threshold: float | None = None  # None: estimated from the scans' noise; 0: until annealing gives up
    max_points: int | None = None
    frustum: str | None = None
    rotation_uncertainty: float | None = None  # degrees
    translation_uncertainty: float | None = None  # units; None: a share of the target's size
    t_start: float | None = None  # None: from the spread of E over the first simplex
    t_min_ratio: float | None = None  # reaches annealing in hybrid and annealing alone
    cooling: float | None = None
    icp_max_iterations: int | None = None
    sa_max_evaluations: int | None = None
    hops: int | None = None
    restarts: int | None = None
    recut_rounds: int | None = None
    polish: bool = False
    coarse_to_fine: bool = False
    candidates: bool = True  # method global: candidate poses beyond the guess (False: the guess alone)
    rotation_samples: int | None = None  # method global: over all of SO(3)
    full_search: bool = False  # method global: no bound on the search (the paper's hybrid runs to its end)
    no_guess: bool = False  # method global: the guess says nothing (any rotation, any translation; core.region)
    time_limit: float | None = None  # method global: seconds of search at most (None: no bound on time)
    lock: object = None  # text (``--lock``: "rx,ry,tz", "rotation", "turntable:px,py,pz,dx,dy,dz") or a core Lock

    def __post_init__(self):
        from rangereg.core.frustum import KINDS
        from rangereg.core.register import METHODS

        for f in fields(self):
            v = getattr(self, f.name)
            if f.name in KNOBS:
                if v is None or (isinstance(v, str) and v.strip().lower() in _AUTO and f.name != "seed"):
                    v = None
                else:
                    v = parse_value(f.name, v)
                object.__setattr__(self, f.name, v)
        if self.seed is None:
            raise InputError("--seed: expected a whole number >= 0, got nothing")
        if self.method is not None and self.method not in METHODS:
            raise InputError(f"--method: unknown method {self.method!r}; choose one of {', '.join(METHODS)}")
        if self.frustum is not None and self.frustum not in KINDS:
            raise InputError(f"--frustum: choose one of {', '.join(KINDS)}, got {self.frustum!r}")
        object.__setattr__(self, "lock", parse_lock(self.lock))

    @classmethod
    def from_mapping(cls, values: dict, **overrides) -> Settings:
        """Settings from any mapping (argparse's ``vars(args)``, the page's fields); unknown keys are ignored."""
        names = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in {**values, **overrides}.items() if k in names})


def to_config(s: Settings):
    """The one mapping from settings to ``core.register.Config`` (with its ``ProblemConfig``), validated.

    A setting left ``None`` keeps the core's default. The annealing knobs reach both the hybrid's
    annealing and annealing alone (each keeps its own default where not given).
    """
    from rangereg.core.register import Config

    def given(**kw):
        return {k: v for k, v in kw.items() if v is not None}

    base = Config()
    problem = replace(base.problem, **given(max_points=s.max_points, frustum=s.frustum))
    anneal = given(t_start=s.t_start, t_min_ratio=s.t_min_ratio, cooling=s.cooling, max_evaluations=s.sa_max_evaluations)
    cfg = replace(base, threshold=s.threshold, seed=s.seed, problem=problem,
                  icp=replace(base.icp, **given(max_iterations=s.icp_max_iterations)),
                  anneal=replace(base.anneal, **anneal), sa_alone=replace(base.sa_alone, **anneal),
                  polish=s.polish, coarse_to_fine=s.coarse_to_fine, lock=s.lock,
                  candidates=replace(base.candidates, enabled=s.candidates,
                                     **given(rotation_samples=s.rotation_samples),
                                     **({"fallback_steps": None, "search_steps": None, "max_candidates": None,
                                         "time_limit": None} if s.full_search else {})
                                     | given(time_limit=s.time_limit)),
                  **given(method=s.method, hops=s.hops, restarts=s.restarts, recut_rounds=s.recut_rounds))
    cfg.validate()
    return cfg


def to_guess(s: Settings, T_target_source=None):
    """The one mapping from settings to a ``core.guess.Guess``: the pose ``T_target_source`` ((4, 4); None: the
    identity) with the stated uncertainty (None: the core's default); ``no_guess`` (the global method only, as
    the paper's methods keep their search region): any pose."""
    from rangereg.core.guess import DEFAULT_ROTATION_DEG, Guess
    from rangereg.core.register import Config

    T = np.eye(4) if T_target_source is None else T_target_source
    if s.no_guess and (s.method or Config().method) == "global":
        return Guess.none(T)
    rotation = DEFAULT_ROTATION_DEG if s.rotation_uncertainty is None else s.rotation_uncertainty
    return Guess(T, rotation, s.translation_uncertainty)


def has_guess(init, source, target) -> bool:
    """Whether the user gave a guess: an initial transform ``init`` (any value but None), or rough poses stored
    with both scans (``Scan.guess``)."""
    return init is not None or (source.guess is not None and target.guess is not None)


def says_nothing(init, source, target, s: Settings) -> bool:
    """No guess at all: no initial transform, no rough poses stored with both scans and no uncertainty stated.
    The global method then searches every rotation and translation (core.region); ``register`` on the
    command line and ``rangereg.register`` both ask this."""
    return not has_guess(init, source, target) and s.rotation_uncertainty is None and s.translation_uncertainty is None


def parse_lock(value, label: str = "--lock"):
    """``--lock`` as a core ``Lock``: text (``rx,ry,tz``: those parameters locked; ``rotation`` or
    ``translation``: three at once; ``turntable:px,py,pz,dx,dy,dz``: rotation about that line in the
    target's frame only; ``turntable+translation:...``: and free translation; ``none``), a Lock, or None.
    A refusal names ``label`` (the page names its field)."""
    from rangereg.core.lock import Lock

    if isinstance(value, Lock):
        try:
            value.validate()
        except InputError as exc:
            raise InputError(f"{label}: {exc}") from None
        return value
    if value is not None and not isinstance(value, str):
        raise InputError(f"{label}: expected text such as rx,ry,tz or turntable:px,py,pz,dx,dy,dz, got {value!r}")
    try:
        return Lock.parse(value)
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None


def read_text_file(path: str | Path, what: str, limit: int | None = None, pipe: bool = False) -> str:
    """The UTF-8 text of a side file (``--init``, ``.conf``, a trace) given by flag ``what``: a regular file
    of at most ``limit`` bytes (or, with ``pipe``, a pipe read once: core.files), every failure as InputError."""
    from rangereg.core.files import TRACE_LIMIT, read_bytes

    data = read_bytes(path, f"{what} {path}", TRACE_LIMIT if limit is None else limit, "a text file", pipe)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        raise InputError(f"{what} {path}: not a text file") from None


_SEPARATORS = re.compile(r"[,;\s\[\]]+")


def parse_init(text: str) -> np.ndarray:
    """``--init``: 16 numbers (row-major T_target_source, spaces or commas) given inline, or a file
    holding them (or JSON with ``transform``), read once: a pipe (``--init <(...)``) is read as it comes
    (core.files). Returns a checked rigid (4, 4) float64 matrix."""
    from rangereg.core.files import TRANSFORM_LIMIT
    from rangereg.core.sidefiles import names_a_file, parse_transform, transform_from_text

    if text is None or not str(text).strip():
        raise InputError("--init: expected 16 numbers or a file, got nothing")
    p = Path(text)
    try:
        link = p.is_symlink()
    except (OSError, ValueError):  # 16 numbers too long to be a file name: the system refuses to look
        link = False
    if names_a_file(text) or link:  # a file, a pipe, a link (even a broken or looping one)
        content = read_text_file(p, "--init", TRANSFORM_LIMIT, pipe=True)
        try:
            return transform_from_text(content.strip(), str(p))
        except InputError as exc:
            raise InputError(f"--init: {exc}") from None
    if len([t for t in _SEPARATORS.split(str(text).strip()) if t]) < 2:
        raise InputError(f"--init {text}: no such file (and not 16 numbers)")
    try:
        return parse_transform(str(text))
    except InputError as exc:
        raise InputError(f"--init: {exc}") from None


def parse_numbers(text: str, flag: str, count: int, positive: bool = True) -> tuple[float, ...]:
    """``count`` finite numbers given as ``a,b``; ``positive``: each > 0."""
    try:
        values = tuple(float(t) for t in str(text).replace(" ", "").split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise InputError(f"{flag}: expected {count} finite numbers separated by commas, got {text!r}")
    if positive and not all(v > 0 for v in values):
        raise InputError(f"{flag}: every number must be > 0, got {text!r}")
    return values
