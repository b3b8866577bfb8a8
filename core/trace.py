"""The trace file (``register --trace``): JSON lines, one header line, one event (core.events.Event) per
line, and a closing ``{"result": {...}}`` line (core.result.Result.to_json: the pose the run returned).

The header (:class:`TraceHeader`) says what the run was (both scans by content, the guess it started
from, every knob, the seed, the method, rangereg's version), so that a reader can refuse a trace of
other scans. A trace without a header is still read; it cannot be checked by content.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .events import PHASES, Event
from .guess import Guess
from .transforms import check_rigid

TRACE_FORMAT = "rangereg-trace"
TRACE_VERSION = 1  # bumped when a reader of the previous version would misread the header


def points_sha256(points: np.ndarray) -> str:
    """Hex SHA-256 of (N, 3) points as little-endian float64 in C order: the scan's content, whatever its file name."""
    return hashlib.sha256(np.ascontiguousarray(points, dtype="<f8").tobytes()).hexdigest()


def rangereg_version() -> str:
    try:
        return importlib.metadata.version("rangereg")
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def _plain(value):
    """A config value as JSON: dataclasses as dicts, tuples and arrays as lists, a non-finite float as text."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in (value.tolist() if isinstance(value, np.ndarray) else value)]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return repr(value)


@dataclass(frozen=True)
class ScanPrint:
    """One scan as a trace names it: the path given, its name, and its content (point count, SHA-256 of the points)."""

    path: str
    name: str
    points: int
    sha256: str

    @classmethod
    def of(cls, scan, path: str | None = None) -> ScanPrint:
        """``scan``: a core.scan.Scan as loaded; ``path``: the file as the user gave it (default: the scan's own)."""
        return cls(str(path if path is not None else scan.source), str(scan.name), int(len(scan.points)),
                   points_sha256(scan.points))

    def same_content(self, other: ScanPrint) -> bool:
        return self.points == other.points and self.sha256 == other.sha256

    def __str__(self) -> str:
        return f"{self.name} ({self.points} points)"


@dataclass(frozen=True, eq=False)
class TraceHeader:
    """The first line of a trace. T_init: (4, 4) T_target_source the run started from; config: every knob as
    the run used it (core.config.Config as plain JSON, with the guess's stated uncertainty under ``guess``);
    version: rangereg's."""

    source: ScanPrint
    target: ScanPrint
    T_init: np.ndarray
    method: str
    seed: int
    config: dict
    version: str
    format_version: int = TRACE_VERSION

    @classmethod
    def of(cls, source, target, guess, config, source_path: str | None = None,
           target_path: str | None = None) -> TraceHeader:
        """The header of a run of ``config`` (a core Config) registering ``source`` onto ``target`` from ``guess``
        (a core.guess.Guess, or a (4, 4) pose: the default uncertainty)."""
        guess = Guess.of(guess)
        return cls(ScanPrint.of(source, source_path), ScanPrint.of(target, target_path),
                   np.array(guess.T_target_source), str(config.method), int(config.seed), _stated(config, guess),
                   rangereg_version())

    def __repr__(self) -> str:
        return (f"TraceHeader({self.source} -> {self.target}, method {self.method}, seed {self.seed}, "
                f"rangereg {self.version}, format {self.format_version})")

    def to_json(self) -> dict:
        return {"header": {"format": TRACE_FORMAT, "format_version": self.format_version, "rangereg": self.version,
                           "source": dataclasses.asdict(self.source), "target": dataclasses.asdict(self.target),
                           "T_init": self.T_init.tolist(), "method": self.method, "seed": self.seed,
                           "config": self.config}}

    @classmethod
    def from_json(cls, d: dict) -> TraceHeader:
        """From a header line's object; InputError (without the file's name) when it is not one this reader knows."""
        h = d.get("header") if isinstance(d, dict) else None
        if not isinstance(h, dict) or h.get("format") != TRACE_FORMAT:
            raise InputError(f"a header that is not a {TRACE_FORMAT} header")
        version = h.get("format_version")
        if not isinstance(version, int) or version < 1:
            raise InputError(f"a header without a format_version, got {version!r}")
        if version > TRACE_VERSION:
            raise InputError(f"written by a newer rangereg ({h.get('rangereg', '?')}, trace format {version}; "
                             f"this one reads format {TRACE_VERSION})")
        try:
            prints = [ScanPrint(str(s["path"]), str(s["name"]), int(s["points"]), str(s["sha256"]))
                      for s in (h["source"], h["target"])]
            T = check_rigid(np.asarray(h["T_init"], dtype=np.float64), "its T_init")
            config = h["config"]
            if not isinstance(config, dict):
                raise TypeError("config is not an object")
            return cls(prints[0], prints[1], T, str(h["method"]), int(h["seed"]), config, str(h["rangereg"]), version)
        except KeyError as exc:
            raise InputError(f"a header without {exc}") from None
        except (TypeError, ValueError) as exc:
            raise InputError(f"a header that does not read ({exc})") from None

    def check_scans(self, source, target, name: str = "trace") -> None:
        """Refuse (InputError) when ``source`` and ``target`` (core Scans) are not the scans this run registered."""
        here = ScanPrint.of(source), ScanPrint.of(target)
        ok = self.source.same_content(here[0]), self.target.same_content(here[1])
        if all(ok):
            return
        if self.source.same_content(here[1]) and self.target.same_content(here[0]):
            raise InputError(f"{name} registered {self.source} onto {self.target}: these scans are the other way "
                             "round (swap SOURCE and TARGET)")
        which = [(w, theirs, mine) for w, theirs, mine, good in
                 zip(("source", "target"), (self.source, self.target), here, ok, strict=True) if not good]
        said = "; ".join(f"its {w} is {theirs} from {theirs.path}, this {w} is {mine} from {mine.path or '(no file)'}"
                         for w, theirs, mine in which)
        raise InputError(f"{name} was recorded on other scans: {said}")

    def differences(self, guess, config=None, only: tuple[str, ...] = (), units: str = "units") -> list[str]:
        """What differs from a run started here from ``guess`` (a core.guess.Guess, or a (4, 4) pose: the default
        uncertainty) with ``config`` (a core Config): readable, for display (a trace of the same scans from another
        guess or with other settings is still drawn). ``only``: the config keys (dotted, by prefix) worth saying;
        empty: all."""
        guess = Guess.of(guess)
        T_init = guess.T_target_source
        out = []
        if not np.allclose(self.T_init, T_init, rtol=0.0, atol=1e-9):
            from .transforms import invert

            d = invert(np.asarray(T_init, dtype=np.float64)) @ self.T_init
            angle = float(np.degrees(np.arccos(np.clip((np.trace(d[:3, :3]) - 1) / 2, -1.0, 1.0))))
            out.append(f"initial guess ({angle:.3g} deg, {np.linalg.norm(d[:3, 3]):.3g} {units} apart)")
        if config is not None:
            mine = _flatten(_stated(config, guess))
            theirs = _flatten(self.config)
            out += [f"{k} {theirs.get(k, '-')} (here {mine.get(k, '-')})"
                    for k in sorted(set(mine) | set(theirs))
                    if mine.get(k) != theirs.get(k) and (not only or k.startswith(only))]
        return out


def _stated(config, guess: Guess) -> dict:
    """``config`` as plain JSON with the guess's stated uncertainty under ``guess``."""
    return _plain(config) | {"guess": {"rotation_deg": guess.rotation_deg, "translation": guess.translation}}


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


@dataclass(frozen=True, eq=False)
class Trace:
    """A trace file read back: its header (None for a trace without one, which cannot be checked
    against the scans) and its events, in order."""

    name: str
    header: TraceHeader | None
    events: list[Event]
    result: dict | None = None  # the closing line's Result.to_json (None: a trace without one)

    def __repr__(self) -> str:
        end = f", result E={self.result['error']:.6g}" if self.result is not None else ""
        return f"Trace({self.name!r}, {len(self.events)} events, {self.header!r}{end})"

    @property
    def end(self) -> np.ndarray:
        """(4, 4) the run's outcome: the pose the run returned (its closing line), else the last event's."""
        return np.asarray(self.result["transform"], dtype=np.float64) if self.result is not None else self.events[-1].T

    def check_scans(self, source, target) -> bool:
        """Refuse (InputError) a trace whose header names other scans; False when it has no header to check."""
        if self.header is None:
            return False
        self.header.check_scans(source, target, self.name)
        return True

    @property
    def start(self) -> np.ndarray | None:
        """The pose the run started from (the header's T_init), None without a header."""
        return None if self.header is None else self.header.T_init


NO_HEADER = "no header: cannot check it was recorded on these scans"


def read_trace(text: str, name: str = "trace") -> Trace:
    """A ``register --trace`` file (JSON lines: an optional header line first, then events, then an optional
    result line); anything else is one InputError naming the file and the line."""
    events, header, result = [], None, None
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            if result is not None:
                raise ValueError("the result line closes the trace: nothing may follow it")
            if isinstance(d, dict) and "result" in d and "phase" not in d:
                result = _result(d["result"])
                continue
            if isinstance(d, dict) and "header" in d and "phase" not in d:
                if events or header is not None:
                    raise ValueError("a header belongs on the first line only")
                header = TraceHeader.from_json(d)
                continue
            if not isinstance(d, dict):
                raise ValueError(f"a JSON object expected, got {type(d).__name__}")
            e = Event.from_json(d)
            check_rigid(e.T, "its transform")
            if e.phase not in PHASES or not np.isfinite(float(e.error)):
                raise ValueError(f"a phase ({'/'.join(PHASES)}) and a finite error expected")
        except (json.JSONDecodeError, RecursionError):  # (arrays nested past the stack: not a trace either)
            raise InputError(f"{name}: line {lineno} is not JSON: not a rangereg trace (JSON lines from "
                             "register --trace)") from None
        except InputError as exc:
            raise InputError(f"{name}: line {lineno} is not a rangereg trace line ({exc})") from None
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise InputError(f"{name}: line {lineno} is not a rangereg trace event ({exc})") from None
        events.append(e)
    if not events:
        raise InputError(f"{name}: holds no events")
    return Trace(name, header, events, result)


def _result(d) -> dict:
    """A result line's object, its transform rigid and its error finite (ValueError otherwise)."""
    if not isinstance(d, dict):
        raise ValueError("a result object expected")
    check_rigid(np.asarray(d["transform"], dtype=np.float64), "its result transform")
    if not np.isfinite(float(d["error"])):
        raise ValueError("a finite result error expected")
    return d


def parse_trace(text: str, name: str = "trace") -> list[Event]:
    """The events of a trace file (:func:`read_trace` without its header)."""
    return read_trace(text, name).events
