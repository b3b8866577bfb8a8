"""Independent tasks (the pairwise registrations of ``merge``, the starts of ``bench``) in this process
or on Dask distributed. The only module that imports dask.

- ``workers=1``: a plain loop in this process (no Dask).
- ``workers=N > 1``: a ``LocalCluster`` of N worker processes on 127.0.0.1, one task at a time each
  (``threads_per_worker=1``: our tasks hold the GIL in numpy and Python between Open3D calls).
- ``workers=None`` (default): the plain loop, until the work left pays for a local cluster of one
  worker per core (app.payback's :func:`cluster_pays`: the tasks' measured time x the tasks left against the
  cluster's start and the speed-up the cores the loop keeps busy already leave to it); then the rest
  of that map and every later one on the cluster. ``choice`` says which was chosen and why.
- ``scheduler="tcp://HOST:PORT"``: an existing cluster (``dask scheduler`` + ``dask worker``); its
  workers must import ``rangereg`` (run them in an environment where it is installed).

Tasks get plain numpy data (Open3D geometry does not pickle). What every task needs (``shared``, e.g.
the scans) is sent once to every worker (``scatter(broadcast=True)``) and the task function builds its
geometry once per process (``core.merge._built``), not once per task. Results come back in order.

Threading (``threads``: threads per task stream, the same knob in both modes). A task stream is the
process that runs tasks one at a time: this process in the serial loop, or one worker. ``threads=k``
limits every stream to k threads: Open3D (whose ray casts and closest-point queries run on oneAPI
TBB, which reads no environment variable) through ``open3d.utility.set_max_threads(k)``, set in this
process for the length of a serial map and in each worker by a worker plugin (also on workers that
join or restart later); OpenMP/MKL/OpenBLAS through ``OMP_NUM_THREADS`` etc., set by the nanny
before a local worker starts (this process's BLAS keeps its threads: numpy is loaded already, and
the engine's BLAS calls are too small for OpenBLAS to split; scipy's neighbour search while a scan's
surface is built, once per scan and process, uses every core). ``threads=None`` (default): the serial
loop keeps the libraries' defaults (all cores), a local cluster of N workers gives each
``max(1, cores // N)`` threads (so N workers do not ask for N x cores), and the workers of a
``scheduler`` keep their own settings. ``--threads 1`` in both modes is the fair comparison of 1
worker with N (benchmarks/campaign.py). Results do not depend on it: tasks take their seeds from
the task, never from the process, each closest point and ray is computed alone (the same answer
on any thread), and the serial and distributed poses are bitwise equal (tests/test_campaign.py).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from rangereg.app.payback import BusyCores, cluster_pays, default_workers
from rangereg.core.errors import InputError

_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
# A local cluster's housekeeping, slowed down: the workers' statistical profiler off (it samples the
# running task's stack every 10 ms) and the memory, system and event-loop monitors at 1 s / 2 s / 0.2 s
# (100 / 500 / 20 ms by default). Measured on the 24-scan campaign, 2 workers, 2 cores: CPU time of
# the pairwise stage 12.5 s per worker + 4.4 s in this process (scheduler, nannies) -> 10.4 + 1.9 s
# (the serial loop: 16.8 s); idle, 20 s: 1.0 s per worker + 1.6 s here -> 0.14 + 0.36 s. The
# dashboard's profile page stays empty and its system plots update every 2 s.
QUIET_CLUSTER = {
    "distributed.worker.profile.enabled": False,
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.admin.tick.interval": "200ms",
}


PROBE_SECONDS = 3.0  # a scheduler that accepts no connection in this time is refused (a LAN answers in ms)


def reach_scheduler(address: str, timeout: float = PROBE_SECONDS) -> None:
    """Raise InputError unless ``address`` (tcp://HOST:PORT) is well formed, something accepts a TCP connection
    there within ``timeout`` seconds (Dask's own client would retry for its whole timeout) and answers Dask's
    handshake within as long (:func:`_handshake`)."""
    from urllib.parse import urlsplit

    shape = f"--scheduler must look like tcp://HOST:PORT, got {address!r}"
    if not isinstance(address, str) or not address.startswith("tcp://"):
        raise InputError(shape)
    try:
        parts = urlsplit(address)
        host, port = parts.hostname, parts.port
    except ValueError:
        raise InputError(shape) from None
    if not host or port is None or port == 0 or parts.path not in ("", "/"):
        raise InputError(shape)
    why = None
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except socket.gaierror:
        why = f"no host named {host}"
    except ConnectionRefusedError:
        why = "connection refused: nothing listens there"
    except TimeoutError:
        why = f"no answer within {timeout:g} s"
    except OSError as exc:
        why = exc.strerror or str(exc)
    if why is not None:
        raise InputError(f"cannot reach the Dask scheduler at {address} ({why}); start it with "
                         "'dask scheduler' (and workers with 'dask worker ADDRESS') or leave --scheduler out")
    _handshake(address, timeout)


def _handshake(address: str, timeout: float) -> None:
    """Raise InputError unless what listens at ``address`` answers Dask's handshake within ``timeout`` seconds.
    Dask's own connect bounds the TCP connect but waits on the handshake for ever (distributed 2026.8:
    ``comm.core.connect`` reads it with no timeout): a service that accepts and never answers held a merge past
    600 s, and one that answers another protocol (an HTTP 400) was read as a frame 3 EiB long, a MemoryError."""
    import asyncio
    from concurrent.futures import ThreadPoolExecutor

    from distributed.comm import connect

    async def shake() -> None:
        comm = await connect(address, timeout=timeout)
        await comm.close()

    try:
        with ThreadPoolExecutor(1, thread_name_prefix="dask-handshake") as pool:  # the caller may run a loop already
            pool.submit(lambda: asyncio.run(asyncio.wait_for(shake(), timeout))).result()
    except TimeoutError:
        why = f"it accepts connections but gives no Dask handshake within {timeout:g} s"
    except Exception as exc:  # noqa: BLE001 - whatever another protocol's bytes make of Dask's reader
        why = f"it does not answer as a Dask scheduler: {type(exc).__name__}"
    else:
        return
    raise InputError(f"no Dask scheduler at {address} ({why}); start one with 'dask scheduler' or leave --scheduler "
                     "out")


class Progress:
    """``done / total`` with elapsed time and an ETA, one line at most every ``every`` seconds (and the
    last). A later map of the same work (a merge's second round of pairs) continues it: :meth:`extend`
    adds its tasks to the total and names it, so done, total and the ETA count every round. The ETA and
    :meth:`rate` leave the first 3 tasks out: the first tasks of a process build what later ones reuse
    (a merge's scans), and alone say nothing of the rest."""

    def __init__(self, total: int, label: str, write: Callable[[str], None] | None, every: float = 2.0):
        self.total, self.label, self.write, self.every = total, label, write, every
        self.done = 0
        self.t0 = time.perf_counter()
        self.durations: list[float] = []  # per task, inside maps of this work (not the time between rounds)
        self._since = self.t0
        self._last = -1e9

    def extend(self, more: int, label: str) -> None:
        self.total += more
        self.label = label
        self._since = time.perf_counter()

    def step(self, count: int = 1) -> None:
        """``count`` more tasks done (a cluster's batch: they share the wait)."""
        self.done += count
        now = time.perf_counter()
        self.durations.extend([(now - self._since) / count] * count)
        self._since = now
        if self.write is None:
            return
        if self.done < self.total and now - self._last < self.every:
            return
        self._last = now
        tail = f"ETA {_clock(self.rate() * (self.total - self.done))}" if self.done < self.total else "done"
        self.write(f"{self.label} {self.done}/{self.total}, {_clock(now - self.t0)} elapsed, {tail}")

    def rate(self) -> float:
        """Seconds per task so far, the mean less the first 3 tasks (0 before a task past them)."""
        steady = self.durations[3:]
        return sum(steady) / len(steady) if steady else 0.0


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


def _key(fn: Callable) -> str:
    """The name a kind of task is counted under (its bar and its meter): ``pair_task`` -> ``pairs``."""
    return getattr(fn, "__name__", "task").removesuffix("_task") + "s"


class TaskRunner:
    """A context manager that runs task maps serially or on one Dask cluster, started by the first map
    with two or more tasks and kept until the context ends.

    ``progress`` receives human-readable lines (progress, the dashboard address); None: silent.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 progress: Callable[[str], None] | None = None, connect_timeout: float = 10.0,
                 threads: int | None = None):
        if scheduler is not None:
            reach_scheduler(scheduler)  # before any work: a run never claims a cluster it did not reach
        self.auto = workers is None and scheduler is None
        workers = default_workers() if workers is None else workers
        if not isinstance(workers, int) or workers < 1:
            raise InputError(f"--workers must be a whole number >= 1, got {workers!r}")
        if threads is not None and (not isinstance(threads, int) or isinstance(threads, bool) or threads < 1):
            raise InputError(f"--threads must be a whole number >= 1, got {threads!r}")
        self.workers, self.scheduler, self.say, self.connect_timeout = workers, scheduler, progress, connect_timeout
        self.threads = threads
        self.client = None
        self.cluster = None
        self.bars: dict[str, Progress] = {}
        self.used_cluster = False  # a map ran (some of) its tasks on the cluster
        self.meters: dict[str, BusyCores] = {}  # per kind of task, as the bars: the plain loop's use of the cores
        self._most_left = -1.0
        if self.auto:
            self.choice = "plain loop in this process: too few tasks at a time for a local cluster to pay"
        elif scheduler is None and workers == 1:
            self.choice = "plain loop in this process (--workers 1)"
        else:
            self.choice = f"the Dask cluster at {scheduler}" if scheduler else f"a local cluster of {workers} workers"

    @property
    def serial(self) -> bool:
        """Tasks run (so far) in this process: ``workers=1``, or ``workers=None`` before a cluster paid."""
        return self.client is None and self.scheduler is None and (self.auto or self.workers == 1)

    @property
    def ran_on(self) -> str:
        """Where the tasks ran, and why: :attr:`choice`, unless a local cluster was asked for and every map held one
        task, which ran in this process."""
        if self.used_cluster or self.serial:
            return self.choice
        if self.scheduler is not None:
            return f"{self.choice} (no task ran)"
        return f"plain loop in this process: one task at a time, which {self.choice} would only delay"

    @property
    def stream_threads(self) -> int | None:
        """Threads each task stream may use (None: the libraries' defaults, or a scheduler's workers' own)."""
        if self.threads is not None or self.serial or self.scheduler is not None:
            return self.threads
        return max(1, default_workers() // self.workers)  # a local cluster shares this machine's cores

    def __enter__(self) -> TaskRunner:
        return self

    def start(self) -> None:
        """Connect to the scheduler or start the local cluster (done by the first map with work for it)."""
        if self.client is not None or (self.scheduler is None and self.workers == 1):
            return
        import dask
        from distributed import Client, LocalCluster

        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout}s")
            except (OSError, TimeoutError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {self.scheduler} ({exc})") from None
            if not self.client.scheduler_info(n_workers=-1).get("workers"):
                try:
                    self.client.wait_for_workers(1, timeout=self.connect_timeout)
                except TimeoutError:
                    self.client.close()
                    self.client = None
                    raise InputError(f"the Dask scheduler at {self.scheduler} has no workers after "
                                     f"{self.connect_timeout:g} s; start some with 'dask worker {self.scheduler}'"
                                     ) from None
        else:
            # the thread limits go into the environment before the worker's Python starts, so that its
            # BLAS and OpenMP read them
            env = {f"distributed.nanny.pre-spawn-environ.{k}": str(self.stream_threads) for k in _THREAD_VARS}
            with dask.config.set({**env, **QUIET_CLUSTER}), _ctrl_c_is_ours():
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                            silence_logs=logging.CRITICAL)  # a task error comes back as its exception
            self.client = Client(self.cluster)
        # Import the engine (numpy, scipy, Open3D: 1-2 s per worker, 5-6 s under load) in every worker
        # now, at the cluster's start, so that the first map measures its tasks, not the imports.
        if self.stream_threads is None:
            self.client.run(_warm)
        else:  # a plugin: also sets up workers that join or restart later
            self.client.register_plugin(_stream_plugin(self.stream_threads))
        if self.say:
            n = len(self.client.scheduler_info(n_workers=-1).get("workers", {}))
            where = self.scheduler or "a local cluster"
            each = "" if self.stream_threads is None else f", {self.stream_threads} thread(s) each"
            self.say(f"Dask: {n} workers on {where}{each}; dashboard {self.client.dashboard_link}")

    def threading(self) -> dict[str, dict]:
        """What each task stream runs with now: {"this process" or a worker's address: {"open3d": max
        threads, "OMP_NUM_THREADS": ..., ...}} (the workers once the cluster has started; this process as
        it runs a serial map)."""
        if self.client is None:
            with open3d_threads(self.threads):
                return {"this process": _thread_settings()}
        return self.client.run(_thread_settings)

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    def map(self, fn: Callable, items: Sequence[Any], shared: Any = None, label: str | None = None,
            done: Callable[[int], None] | None = None) -> list:
        """``[fn(shared, item) ...]`` (or ``fn(item)`` when ``shared`` is None), in the order of ``items``.
        ``label`` names the work in progress lines; a later map of the same ``fn`` continues its count.
        ``done(count)``: called as tasks finish with this map's count so far (the caller then renders
        the progress: this runner writes no count lines of its own for the map)."""
        items = list(items)
        if not items:
            return []
        bar = self._bar(fn, items, label, quiet=done is not None)
        meter = self.meters.setdefault(_key(fn), BusyCores())
        one = (lambda item: fn(item)) if shared is None else (lambda item: fn(shared, item))
        # one task: a local cluster would only add its start (a scheduler named is used for it too)
        if self.client is None and (self.serial or (len(items) < 2 and self.scheduler is None)):
            out = []
            with open3d_threads(self.threads):
                for k, item in enumerate(items):
                    meter.start()
                    out.append(one(item))
                    meter.stop()
                    bar.step()
                    if done is not None:
                        done(k + 1)
                    if self.auto and self._pays(bar.rate() * (len(items) - k - 1), len(items) - k - 1, meter):
                        return out + self._on_cluster(fn, items[k + 1:], shared, bar, done, k + 1)
            return out
        return self._on_cluster(fn, items, shared, bar, done)

    def _bar(self, fn: Callable, items: list, label: str | None, quiet: bool = False) -> Progress:
        key = _key(fn)
        label = label or key
        if key in self.bars:
            self.bars[key].extend(len(items), label)
        else:
            self.bars[key] = Progress(len(items), label, self.say)
        self.bars[key].write = None if quiet else self.say
        return self.bars[key]

    def _pays(self, seconds_left: float, left: int, meter: BusyCores) -> bool:
        """workers=None: start the local cluster now (and say why) when the work left pays for it. Not before the
        loop's busy cores are measured on tasks past the first 3 (the first of a process build what the later reuse)."""
        if left < 2 or meter.cores is None:
            return False
        pays, why = cluster_pays(seconds_left, busy=meter.cores, tasks=left)
        if pays or seconds_left >= self._most_left:  # the plain loop's reason: its closest call
            self._most_left = seconds_left
            self.choice = (f"a local cluster of {self.workers} workers: {why}" if pays
                           else f"plain loop in this process: {why}")
        if pays and self.say:
            self.say(f"starting {self.choice}")
        return pays

    def _on_cluster(self, fn: Callable, items: list, shared: Any, bar: Progress,
                    done: Callable[[int], None] | None = None, before: int = 0) -> list:
        from distributed import as_completed

        self.start()
        self.used_cluster = True
        # Many short tasks (e.g. 276 overlap measurements of a 24-scan campaign) go in batches of
        # consecutive items, about 16 batches per worker: the scheduler's cost per task stays small.
        n_workers = max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))
        size = max(1, len(items) // (16 * n_workers))
        batches = [items[k:k + size] for k in range(0, len(items), size)]
        [ref] = self.client.scatter([shared], broadcast=True, hash=False)
        futures = self.client.map(_run_batch, [fn] * len(batches), [ref] * len(batches), batches, pure=False)
        from concurrent.futures import CancelledError

        from distributed import KilledWorker
        from distributed.comm.core import CommClosedError

        try:
            finished = before
            for fut in as_completed(futures):
                if fut.status == "error":
                    fut.result()  # raises the task's own exception (an InputError stays one)
                count = len(batches[futures.index(fut)])
                bar.step(count)
                finished += count
                if done is not None:
                    done(finished)
            return [r for part in self.client.gather(futures) for r in part]
        # the cluster, not the input: one line (app.cli); a lost scheduler cancels the futures
        except (KilledWorker, CommClosedError, CancelledError) as exc:
            raise OSError(f"the Dask cluster lost a worker or its connection ({type(exc).__name__}); run again, "
                          "or with --workers 1") from exc
        finally:
            for fut in futures:
                fut.release()


@contextmanager
def _ctrl_c_is_ours() -> Iterator[None]:
    """While the local cluster starts: its worker processes are started through a two-line shell that sets
    SIGINT to be ignored before it runs Python, which then installs no KeyboardInterrupt handler. So a
    Ctrl-C (which the terminal sends to every process of its group) reaches only this process, whose
    cleanup stops the workers in order (no traceback from each). Neither a blocked mask (the spawn clears
    it) nor ignoring SIGINT here for the start (a Ctrl-C in those seconds would be lost) would do."""
    import multiprocessing
    import multiprocessing.spawn as spawn
    import shlex
    import tempfile

    before = spawn.get_executable()
    if os.name != "posix" or not os.path.exists("/bin/sh"):
        yield
        return
    with tempfile.TemporaryDirectory(prefix="rangereg-workers-") as tmp:
        shell = os.path.join(tmp, "python")
        with open(shell, "w") as f:
            f.write(f"#!/bin/sh\ntrap '' INT\nexec {shlex.quote(os.fsdecode(before))} \"$@\"\n")
        os.chmod(shell, 0o755)
        spawn.set_executable(shell)
        try:
            yield
        except BaseException:  # interrupted while the cluster started: no object to close it by, so its
            for p in multiprocessing.active_children():  # worker processes are ended here
                p.terminate()
            for p in multiprocessing.active_children():
                p.join(2)
            raise
        finally:  # the workers run by now; one restarted later starts as any process would
            spawn.set_executable(before)


@contextmanager
def open3d_threads(threads: int | None) -> Iterator[None]:
    """Open3D (TBB) limited to ``threads`` in this process inside the block (None: unchanged)."""
    if threads is None:
        yield
        return
    import open3d as o3d

    before = o3d.utility.get_max_threads()
    o3d.utility.set_max_threads(threads)
    try:
        yield
    finally:
        o3d.utility.set_max_threads(before)


def _warm() -> None:
    import open3d  # noqa: F401
    import rangereg.core.merge  # noqa: F401


def _thread_settings() -> dict:
    import open3d as o3d

    return {"open3d": o3d.utility.get_max_threads(), **{k: os.environ.get(k) for k in _THREAD_VARS}}


def _setup_stream(threads: int) -> None:
    """In a worker: import the engine and limit Open3D (and OpenMP/BLAS in what it starts) to ``threads``."""
    import open3d as o3d

    _warm()
    o3d.utility.set_max_threads(threads)
    os.environ.update({k: str(threads) for k in _THREAD_VARS})


def _stream_plugin(threads: int):
    """A Dask worker plugin that runs :func:`_setup_stream` on every worker, present and future (defined
    here, not at module level, so that the serial path never imports dask)."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class StreamThreads(WorkerPlugin):
        name = "rangereg-stream-threads"

        def __init__(self, threads: int):
            self.threads = threads

        def setup(self, worker) -> None:
            _setup_stream(self.threads)

    return StreamThreads(threads)


def _run_batch(fn: Callable, shared: Any, batch: list) -> list:
    return [fn(item) if shared is None else fn(shared, item) for item in batch]


def map_tasks(fn: Callable, items: Sequence[Any], workers: int | None = 1, scheduler: str | None = None,
              progress: Callable[[str], None] | None = None, shared: Any = None) -> list:
    """Run ``fn(item)`` (or ``fn(shared, item)``) for every item, serially (``workers=1``), on a local
    cluster of ``workers`` processes (None: one per core) or on ``scheduler``; results in order.

    ``fn`` must be importable by the workers (a module-level function of this project) and return
    picklable values; ``shared`` is sent once per worker.
    """
    with TaskRunner(workers, scheduler, progress) as runner:
        return runner.map(fn, items, shared)


def stderr_lines(line: str) -> None:
    """A progress sink: one line on stderr."""
    sys.stderr.write(f"  {line}\n")
    sys.stderr.flush()
