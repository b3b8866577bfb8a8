"""The process around a command: the signals that end it, its standard streams, its one error line and
its exit. Standard library only, so that app.cli can put the handlers in place before numpy and the
engine load.

SIGINT, SIGTERM and SIGHUP raise :class:`Interrupted` in the main thread, so that every ``finally`` runs
(temporary files removed, workers stopped); the command then says one line and ends with 128 + the
signal. A closed stdout is found before anything runs; file names with undecodable bytes print as the
bytes they were.
"""

from __future__ import annotations

import codecs
import os
import signal
import sys

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class Interrupted(KeyboardInterrupt):
    """A signal asking the command to stop, raised in the main thread so that every ``finally`` runs.
    A KeyboardInterrupt, so that ``except Exception`` never swallows it."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum

    @property
    def status(self) -> int:
        return 128 + self.signum

    @property
    def text(self) -> str:
        return f"interrupted ({signal.Signals(self.signum).name})"


class Handlers:
    """The signal handlers of one ``main`` call: the first signal raises :class:`Interrupted`; a second one
    while the first is being cleaned up ends the process at once, with the same one line.

    ``whole_process`` (the entry point): from the first signal on, this process's stderr goes to
    /dev/null, so that the libraries' complaints while the command unwinds (Dask's closing connections,
    a half-imported module) do not reach the user; the one line goes to the stderr saved here."""

    def __init__(self, command: list, whole_process: bool):
        self.command, self.whole_process, self.first, self.saved = command, whole_process, None, {}
        self.stderr_fd: int | None = None

    def __call__(self, signum, frame):
        if self.first is None:
            self.first = Interrupted(signum)
            if self.whole_process:
                self._mute_stderr()
            raise self.first
        discard_open_outputs()
        self.say(self.first.text)
        os._exit(self.first.status)

    def _mute_stderr(self) -> None:
        try:
            self.stderr_fd = os.dup(2)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)
        except OSError:
            self.stderr_fd = None

    def say(self, message: str) -> None:
        """The interrupted command's one line, on the stderr the command started with."""
        if self.stderr_fd is None:
            error_line(self.command[0], message)
            return
        try:
            sys.stdout.flush()
        except (OSError, ValueError, AttributeError):
            pass
        line = f"rangereg{' ' + self.command[0] if self.command[0] else ''}: error: {message}\n"
        try:
            os.write(self.stderr_fd, line.encode(errors="rangereg.names"))
        except OSError:
            pass

    def __enter__(self):
        try:
            for s in SIGNALS:
                self.saved[s] = signal.signal(s, self)
        except ValueError:  # not the main thread (an in-process caller): leave the signals alone
            pass
        return self

    def __exit__(self, *exc):
        for s, h in self.saved.items():
            signal.signal(s, h)


def _names_as_bytes(exc):
    """Encoding error handler for stdout and stderr: a file name's undecodable bytes (carried as
    surrogates, PEP 383) are written back as the bytes they were; any other character that the stream
    cannot encode is written as a backslash escape."""
    if isinstance(exc, UnicodeEncodeError):
        bad = exc.object[exc.start:exc.end]
        if all(0xDC80 <= ord(c) <= 0xDCFF for c in bad):
            return bytes(ord(c) - 0xDC00 for c in bad), exc.end
        return codecs.backslashreplace_errors(exc)
    raise exc


codecs.register_error("rangereg.names", _names_as_bytes)


def streams_ready() -> bool:
    """Make the standard streams safe to use; False when stdout is closed (``>&-``). A closed descriptor
    0, 1 or 2 is pointed at /dev/null, so that no file this process opens later takes its number."""
    closed = []
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            closed.append(fd)
            null = os.open(os.devnull, os.O_RDWR)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
    for stream in (sys.stdout, sys.stderr):
        if stream is not None and stream is getattr(sys, f"__{'stdout' if stream is sys.stdout else 'stderr'}__"):
            try:
                stream.reconfigure(errors="rangereg.names")
            except (AttributeError, ValueError):
                pass
    ready = 1 not in closed and sys.stdout is not None
    if sys.stdout is None:
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - what is printed goes nowhere
    if 2 in closed or sys.stderr is None:
        sys.stderr = open(os.devnull, "w")  # noqa: SIM115 - nowhere to say anything; the status says it
    return ready


def quiet_stdout() -> None:
    """After a closed pipe (``| head``): point stdout at devnull so the interpreter's flush at exit is
    silent (the recipe of Python's signal module documentation)."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # a stdout with no file behind it (in-process callers)
        pass


def discard_open_outputs() -> None:
    """Temporary files of outputs still being written (a trace) go, whatever the command was doing."""
    outputs = sys.modules.get("rangereg.app.outputs")
    if outputs is not None:
        try:
            outputs.discard_open()
        except Exception:  # noqa: BLE001 - the one line and the status still matter more
            pass


def exit_now(status: int) -> None:
    """End the process after an interruption, once the command's own cleanup has run (its ``finally``
    blocks: temporary files removed, workers stopped): the exit handlers run (child processes ended,
    multiprocessing's semaphores released) but not the C++ static destructors, since a signal that landed
    inside a library's import leaves it half made and its destructors then print (Open3D's memory
    statistics, on stdout) and change the status."""
    import atexit

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError, AttributeError):
            pass
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 1)
        os.dup2(null, 2)
        atexit._run_exitfuncs()
    except BaseException:  # noqa: BLE001 - nothing more to say; the status says it
        pass
    os._exit(status)


def error_line(command: str | None, message: str) -> None:
    try:
        sys.stdout.flush()  # the result printed before a late failure comes first
    except (OSError, ValueError, AttributeError):
        quiet_stdout()
    line = f"rangereg{' ' + command if command else ''}: error: {' '.join(message.split())}\n"
    try:
        try:
            sys.stderr.write(line)
        except UnicodeEncodeError:  # a stream that cannot take a file name's bytes (see _names_as_bytes)
            sys.stderr.write(line.encode("ascii", "backslashreplace").decode("ascii"))
        sys.stderr.flush()
    except (OSError, ValueError):  # stderr gone too: the status says it
        pass
