"""Reading the files a user names: regular files only, their size bounded before a byte is read.

Every reader of user files (scans, sidecars, a ``.conf`` beside a scan, ``--init``, traces, the page's
data folder) opens them here, so that
- a FIFO, a device, a socket or a folder is refused by what it is, before anything is read (a FIFO
  waits for a writer that may never come; ``/dev/zero`` never ends), and a symbolic link that leads
  back to itself is called a loop, not a missing file;
- a file larger than its kind may be is refused from its size alone (``st_size``: a sparse file's
  holes count, since they read as zeros), so a 50 GB sparse file is never read;
- the opened file is checked again (``fstat``), so a path swapped for a FIFO between the two checks is
  still refused, and the open itself never blocks (``O_NONBLOCK``).

Pipes. A pipe named for a small text input (``--init <(...)``, process substitution) is what the user
meant, so :func:`read_bytes` with ``pipe=True`` reads it once, up to the same size limit, and gives up
when nothing arrives for :data:`PIPE_WAIT` seconds (a named FIFO that no program writes to). Nothing
else accepts a pipe.
"""

from __future__ import annotations

import errno
import os
import select
import stat
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

from .errors import InputError

PIPE_WAIT = 5.0  # s without a byte before a pipe given as a side file is given up (the contract's bound is 10 s)
HEADER_LIMIT = 1 << 20  # bytes of a header (PLY, PCD) read before its end must have been seen

# Side files are small: 16 numbers; a sidecar of a viewpoint, two poses and names; a .conf of a line per scan.
TRANSFORM_LIMIT = 1 << 20
SIDECAR_LIMIT = 16 << 20
CONF_LIMIT = 16 << 20
TRACE_LIMIT = 1 << 30  # a trace holds an event per iteration: a long hybrid run writes ~10-40 MB

# Peak memory while a scan is read, as a multiple of its file's size (measured on 2M points, core.io readers
# and clean_points): binary PLY 3.9 x; ASCII PLY 7.8 x, XYZ text 9.2 x. With room for what follows the read.
BINARY_FACTOR = 5
TEXT_FACTOR = 12


def size_text(n: float) -> str:
    """``n`` bytes for people: "345 bytes", "1.2 MB", "50 GB"."""
    if n < 1000:
        return f"{int(n)} bytes"
    for unit, scale in (("kB", 1e3), ("MB", 1e6), ("GB", 1e9), ("TB", 1e12)):
        if n < scale * 1000 or unit == "TB":
            v = n / scale
            return f"{v:.3g} {unit}" if v < 100 else f"{v:.0f} {unit}"
    return f"{n} bytes"  # pragma: no cover


def kind(mode: int) -> str:
    """What a non-regular file is, in words ("a named pipe (FIFO)", "a character device", ...)."""
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a pipe (FIFO)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def _stat(path: Path, what: str) -> os.stat_result:
    """os.stat following links; every failure as one InputError naming its real cause."""
    try:
        return os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            raise InputError(f"{what}: a symbolic link to {os.readlink(path)}, which does not exist") from None
        raise InputError(f"{what}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise InputError(f"{what}: too many levels of symbolic links (a link that leads back to itself)") from None
        if exc.errno == errno.ENOTDIR:
            raise InputError(f"{what}: no such file (a part of the path is a file, not a folder)") from None
        if exc.errno == errno.ENAMETOOLONG:
            raise InputError(f"{what}: the name is too long for a file") from None
        raise InputError(f"{what}: cannot read it ({exc.strerror or exc})") from None
    except ValueError:  # a NUL in the name
        raise InputError(f"{what}: not a usable file name") from None


def _refuse_kind(path: Path, st: os.stat_result, what: str, expected: str) -> None:
    if stat.S_ISREG(st.st_mode):
        return
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what}: is a folder, not {expected}")
    link = ""
    if os.path.islink(path):
        link = f"links to {os.path.realpath(path)}, which "
    raise InputError(f"{what}: {link}is {kind(st.st_mode)}, not {expected}: only regular files are read")


def stat_regular(path: str | os.PathLike, what: str, expected: str = "a regular file",
                 pipe: bool = False) -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a regular file (or a pipe, with ``pipe``); else one InputError.

    what: the message's prefix (the file, or the flag and the file); expected: what it should be
    ("a scan file", "a JSON sidecar").
    """
    path = Path(path)
    st = _stat(path, what)
    if not (pipe and stat.S_ISFIFO(st.st_mode)):
        _refuse_kind(path, st, what, expected)
    return st


def check_folder(path: str | os.PathLike, what: str) -> os.stat_result:
    """The ``os.stat`` of ``path`` when it is a folder; else one InputError naming what it is."""
    path = Path(path)
    try:
        st = _stat(path, what)
    except InputError as exc:
        raise InputError(str(exc).replace("no such file", "no such folder")) from None
    if not stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what}: is {'a file' if stat.S_ISREG(st.st_mode) else kind(st.st_mode)}, not a folder")
    return st


def check_size(size: int, limit: int, what: str, expected: str, st: os.stat_result | None = None,
               why: str = "") -> None:
    """Refuse ``size`` bytes above ``limit``; ``st`` names a sparse file as such; ``why`` says where the limit comes from."""
    if size <= limit:
        return
    sparse = ""
    if st is not None and hasattr(st, "st_blocks") and st.st_blocks * 512 < size // 2:
        sparse = f" (a sparse file: {size_text(st.st_blocks * 512)} stored on disk, the rest reads as zeros)"
    raise InputError(f"{what}: {size_text(size)}{sparse} is more than {expected} may be "
                     f"({why or 'at most ' + size_text(limit)})")


def read_bytes(path: str | os.PathLike, what: str, limit: int, expected: str = "a regular file",
               pipe: bool = False) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (or, with ``pipe``, of a pipe, read once
    until its writer closes it, at most ``limit`` bytes and :data:`PIPE_WAIT` seconds of silence)."""
    path = Path(path)
    st = stat_regular(path, what, expected, pipe)
    if stat.S_ISFIFO(st.st_mode):
        return _read_pipe(path, what, limit, expected)
    check_size(st.st_size, limit, what, expected, st)
    with open_regular(path, what, expected) as f:
        data = f.read(limit + 1)
    check_size(len(data), limit, what, expected)  # it grew since the stat
    return data


@contextmanager
def open_regular(path: str | os.PathLike, what: str, expected: str = "a regular file") -> Iterator[BinaryIO]:
    """``open(path, "rb")`` of a regular file: opened without blocking and checked again on the open file."""
    path = Path(path)
    stat_regular(path, what, expected)
    try:
        fd = _open_fd(path)
    except OSError as exc:
        _stat(path, what)  # a loop or a vanished file: say which
        raise InputError(f"{what}: cannot read {expected} ({exc.strerror or exc})") from None
    try:
        _refuse_kind(path, os.fstat(fd), what, expected)
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    with os.fdopen(fd, "rb") as f:
        yield f


def _open_fd(path: Path) -> int:
    """A read-only descriptor that never waits (a FIFO without a writer opens at once)."""
    return os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))


def _read_pipe(path: Path, what: str, limit: int, expected: str) -> bytes:
    """A pipe's bytes until its writer closes it; refused over ``limit`` bytes or after PIPE_WAIT s of silence."""
    try:
        fd = _open_fd(path)
    except OSError as exc:
        raise InputError(f"{what}: cannot read the pipe ({exc.strerror or exc})") from None
    chunks, total = [], 0
    try:
        while True:
            # Linux reports a FIFO that no writer has opened yet as not ready (no hang-up) until one
            # does, so a FIFO nobody writes to ends here after PIPE_WAIT seconds.
            ready, _, _ = select.select([fd], [], [], PIPE_WAIT)
            if not ready:
                shown = "nothing" if not total else f"{size_text(total)}, then nothing more"
                raise InputError(f"{what}: is a pipe that sent {shown} for {PIPE_WAIT:g} s (and was not closed); "
                                 f"give {expected} as a regular file")
            try:
                chunk = os.read(fd, 1 << 16)
            except BlockingIOError:
                time.sleep(0.01)
                continue
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
            if total > limit:
                raise InputError(f"{what}: the pipe sent more than {size_text(limit)}, more than {expected} may be")
    finally:
        os.close(fd)
    return b"".join(chunks)


def memory_available() -> int | None:
    """Bytes of memory this machine can give now without swapping (Linux MemAvailable), None when unknown."""
    try:
        with open("/proc/meminfo", "rb") as f:
            for line in f:
                if line.startswith(b"MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(size: int, factor: float, what: str, st: os.stat_result | None = None,
                 available: int | None = None) -> None:
    """Refuse a scan file of ``size`` bytes whose reading would need more than the memory free now
    (``factor`` x its size, the measured peak of its format)."""
    available = memory_available() if available is None else available
    if available is None:
        return
    check_size(size, int(available / factor), what, "a scan this machine can read now", st,
               f"reading it takes about {factor:g} x its size in memory; {size_text(available)} is free")
