"""Output files that never lose anything: checked before the work starts, written atomically.

- :func:`check_output` refuses, before any work, a path whose folder is missing or not writable, a
  folder, an unknown suffix, or one of the inputs (or an input scan's JSON sidecar).
- :func:`write_output` writes through a temporary file in the same folder and renames it onto the
  target, so a failed or interrupted write leaves an existing file as it was. Rename is atomic only
  onto regular files: a device (``/dev/null``, ``/dev/full``) or a pipe gets a plain write.
- :class:`TraceFile` collects a run's JSON lines in a temporary file and puts it in place only at
  :meth:`TraceFile.commit`; a run that fails never empties an existing trace.

Every failure is an InputError naming the flag and the path (one line on the CLI).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

from rangereg.core.errors import InputError


def _is_special(p: Path) -> bool:
    """An existing non-regular, non-folder file: a device or a pipe (no atomic rename onto it)."""
    return p.exists() and not p.is_file() and not p.is_dir()


def _same(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
    except OSError:
        pass
    try:
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):  # a link loop (its reader says so): not the same as anything
        return os.path.abspath(a) == os.path.abspath(b)


def check_output(text: str | os.PathLike | None, flag: str, suffixes: tuple[str, ...] = (),
                 inputs: Iterable[str | os.PathLike] = (), scans: Iterable[str | os.PathLike] = ()) -> Path:
    """The output path ``text`` checked before the work starts; raises InputError.

    suffixes: allowed suffixes, lower case with the dot (empty: any); inputs: files the command
    reads, which it must never overwrite; scans: input scans, whose JSON sidecars are protected too.
    """
    if text is None or not str(text).strip():
        raise InputError(f"{flag}: expected a file name, got nothing")
    p = Path(text).expanduser()
    if p.is_dir():
        raise InputError(f"{flag} {p}: is a folder; give a file name")
    if _is_special(p):
        if not os.access(p, os.W_OK):
            raise InputError(f"{flag} {p}: cannot write to it (permission denied)")
        return p
    if suffixes and p.suffix.lower() not in suffixes:
        raise InputError(f"{flag} {p}: unknown suffix {p.suffix or '(none)'!r}; use {' or '.join(suffixes)}")
    folder = p.parent
    if not folder.exists():
        raise InputError(f"{flag} {p}: the folder {folder} does not exist")
    if not folder.is_dir():
        raise InputError(f"{flag} {p}: {folder} is not a folder")
    scans = [Path(s) for s in scans]
    for other in [Path(i) for i in inputs] + scans:
        if _same(p, other):
            raise InputError(f"{flag} {p}: is an input file; refusing to overwrite it")
    for scan in scans:
        side = scan.with_suffix(".json")
        if _same(p, side):
            raise InputError(f"{flag} {p}: is the sidecar of the input scan {scan}; refusing to write it")
    _probe_writable(folder, flag, p)
    return p


def check_distinct(outputs: dict[str, Path | None]) -> None:
    """Refuse two flags writing the same file (the second would overwrite the first)."""
    seen: dict[Path, str] = {}
    for flag, p in outputs.items():
        if p is None or _is_special(p):
            continue
        key = p.resolve()
        if key in seen:
            raise InputError(f"{flag} {p}: {seen[key]} writes the same file")
        seen[key] = flag


def check_output_folder(text: str | os.PathLike, flag: str) -> Path:
    """A folder to write into: an existing writable folder, or one whose parent exists (it is created)."""
    if not str(text).strip():
        raise InputError(f"{flag}: expected a folder, got nothing")
    p = Path(text).expanduser()
    if p.exists() and not p.is_dir():
        raise InputError(f"{flag} {p}: is a file, expected a folder")
    folder = p if p.exists() else p.parent
    if not folder.is_dir():
        raise InputError(f"{flag} {p}: the folder {folder} does not exist")
    _probe_writable(folder, flag, p)
    return p


def _probe_writable(folder: Path, flag: str, p: Path) -> None:
    # os.access says yes to root even on a read-only mount: create (and remove) a file to know
    try:
        fd, probe = tempfile.mkstemp(prefix=".rangereg-", dir=folder)
        try:
            os.close(fd)
        finally:  # even when a signal lands here
            os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{flag} {p}: cannot write in {folder} ({exc.strerror or exc})") from None


@contextlib.contextmanager
def atomic_path(target: Path, suffix: str = "") -> Iterator[Path]:
    """A temporary path to write, with the target's suffix (else ``suffix``: writers such as matplotlib
    add their own to a bare name); on success it replaces ``target`` (atomic rename for a regular file
    or a new one; a plain copy onto a device or pipe). On failure it is removed."""
    target = Path(target)
    special = _is_special(target)
    real = target.resolve() if target.is_symlink() and not special else target
    folder = None if special else real.parent
    fd, tmp = tempfile.mkstemp(prefix=f".{real.stem}-", suffix=real.suffix or suffix, dir=folder)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        if special:
            with open(tmp_path, "rb") as src, open(target, "wb") as dst:
                shutil.copyfileobj(src, dst)
        else:
            mode = real.stat().st_mode & 0o777 if real.exists() else 0o666 & ~_umask()
            os.chmod(tmp_path, mode)
            os.replace(tmp_path, real)
    finally:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_output(target: Path, flag: str, write: Callable[[Path], None], suffix: str = "") -> None:
    """Call ``write(tmp_path)`` and put the file in place atomically; an OSError becomes one InputError.
    ``suffix``: the temporary file's when the target has none (``/dev/null``)."""
    try:
        with atomic_path(target, suffix) as tmp:
            write(tmp)
    except OSError as exc:
        raise InputError(f"{flag} {target}: cannot write it ({exc.strerror or exc})") from None


def write_outputs(jobs: list[tuple]) -> None:
    """Write every (target, flag, write[, suffix]) job even when one fails, then raise one InputError
    naming all that failed (so the result printed before is never lost and stderr gets one line)."""
    failed = []
    for target, flag, write, *suffix in jobs:
        if target is None:
            continue
        try:
            write_output(target, flag, write, *suffix)
        except InputError as exc:
            failed.append(str(exc))
    if failed:
        raise InputError("; ".join(failed))


class TraceFile:
    """JSON lines written during a run into a temporary file, put in place by :meth:`commit`.

    A write error during the run is remembered (the run goes on) and reported by ``commit``.
    """

    def __init__(self, target: Path, flag: str = "--trace"):
        self.target, self.flag, self.error = Path(target), flag, None
        self._cm = atomic_path(self.target)
        self._tmp = self._cm.__enter__()
        _OPEN.add(self)
        self._file = open(self._tmp, "w")  # noqa: SIM115 - closed in commit/discard

    def write(self, line: str) -> None:
        if self.error is None:
            try:
                self._file.write(line + "\n")
            except OSError as exc:
                self.error = exc

    def commit(self) -> None:
        """Put the trace in place; raises InputError if any write failed (the old file is kept)."""
        try:
            if self.error is not None:
                raise self.error
            self._file.close()
            self._cm.__exit__(None, None, None)
            _OPEN.discard(self)
        except OSError as exc:
            self.discard()
            raise InputError(f"{self.flag} {self.target}: cannot write it ({exc.strerror or exc})") from None

    def discard(self) -> None:
        """Drop what was written; an existing trace stays as it was."""
        with contextlib.suppress(OSError):
            self._file.close()
        with contextlib.suppress(Exception):
            self._cm.__exit__(InputError, InputError("discarded"), None)
        _OPEN.discard(self)


_OPEN: set[TraceFile] = set()  # traces being written: an interrupted command discards them (discard_open)


def discard_open() -> None:
    """Drop every trace still being written (its temporary file removed, an existing trace kept): for a
    command interrupted between a trace's start and the block that would discard it."""
    for trace in list(_OPEN):
        trace.discard()


@contextlib.contextmanager
def library_prints_to_stderr(active: bool = True) -> Iterator[None]:
    """While active, what is written to file descriptor 1 (a C++ library's prints: Open3D's warnings)
    goes to stderr, so that stdout holds only what the command prints on purpose (``--json``)."""
    if not active:
        yield
        return
    sys.stdout.flush()
    saved = os.dup(1)  # a library writes to the process's file descriptor 1, whatever sys.stdout is
    os.dup2(2, 1)
    try:
        yield
    finally:
        sys.stdout.flush()
        _flush_c_streams()  # what the C library holds in its buffer for fd 1 belongs to stderr too
        os.dup2(saved, 1)
        os.close(saved)


def _flush_c_streams() -> None:
    """fflush(NULL): the C library's buffered streams written out (a pipe or file is fully buffered)."""
    import ctypes

    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask (not a POSIX system): nothing is held there
        pass


def strict_json(obj) -> str:
    """``obj`` as JSON any strict parser reads: a NaN or infinite number (a pair that did not register
    has no finite E) is written ``null``, never ``NaN`` or ``Infinity``."""
    import json
    import math

    def clean(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: clean(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v) for v in x]
        if hasattr(x, "item") and getattr(x, "ndim", None) == 0:  # a numpy scalar
            return clean(x.item())
        return x

    return json.dumps(clean(obj), allow_nan=False)

