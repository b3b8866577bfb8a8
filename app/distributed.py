"""Independent tasks (the pairwise registrations of ``merge``, the starts of ``bench``) in this process
or on Dask distributed. The only module that imports dask.

- ``workers=1``: a plain loop in this process (no Dask).
- ``workers=N > 1`` (default: as many as cores): a ``LocalCluster`` of N worker processes on
  127.0.0.1, one task at a time each (``threads_per_worker=1``: our tasks hold the GIL in numpy and
  Python between Open3D calls).
- ``scheduler="tcp://HOST:PORT"``: an existing cluster (``dask scheduler`` + ``dask worker``); its
  workers must import this project (run them with the same PYTHONPATH / environment).

Tasks get plain numpy data (Open3D geometry does not pickle). What every task needs (``shared``, e.g.
the scans) is sent once to every worker (``scatter(broadcast=True)``) and the task function builds its
geometry once per process (``core.merge._built``), not once per task. Results come back in order.

Threading, the same in both modes: each process (this one in the serial loop, each worker) runs
one task at a time, and Open3D (TBB), OpenMP and BLAS keep their default thread pools (all cores).
Dask's nanny would set ``OMP_NUM_THREADS=MKL_NUM_THREADS=OPENBLAS_NUM_THREADS=1`` in its workers; we
unset that override so workers run as this process does (a value set in the environment is passed on
unchanged). Results do not depend on it: tasks take their seeds from the task, never from the process,
and the serial and distributed poses are bitwise equal (tests/test_campaign.py).
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

from core.errors import InputError

_THREAD_VARS = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def default_workers() -> int:
    """As many workers as cores (at least 1)."""
    return max(1, os.cpu_count() or 1)


class Progress:
    """``done / total`` with elapsed time and an ETA, one line at most every ``every`` seconds (and the last)."""

    def __init__(self, total: int, label: str, write: Callable[[str], None] | None, every: float = 2.0):
        self.total, self.label, self.write, self.every = total, label, write, every
        self.done = 0
        self.t0 = time.perf_counter()
        self._last = -1e9

    def step(self) -> None:
        self.done += 1
        if self.write is None:
            return
        now = time.perf_counter()
        if self.done < self.total and now - self._last < self.every:
            return
        self._last = now
        elapsed = now - self.t0
        eta = elapsed / self.done * (self.total - self.done)
        tail = f"ETA {_clock(eta)}" if self.done < self.total else "done"
        self.write(f"{self.label} {self.done}/{self.total}, {_clock(elapsed)} elapsed, {tail}")


def _clock(seconds: float) -> str:
    s = int(round(seconds))
    return f"{s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}" if s >= 3600 else f"{s // 60}:{s % 60:02d}"


class TaskRunner:
    """A context manager that runs task maps serially or on one Dask cluster, started by the first map
    with two or more tasks and kept until the context ends.

    ``progress`` receives human-readable lines (progress, the dashboard address); None: silent.
    """

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 progress: Callable[[str], None] | None = None, connect_timeout: float = 10.0):
        if scheduler is not None:
            if not isinstance(scheduler, str) or not scheduler.startswith("tcp://") or ":" not in scheduler[6:]:
                raise InputError(f"--scheduler must look like tcp://HOST:PORT, got {scheduler!r}")
        workers = default_workers() if workers is None else workers
        if not isinstance(workers, int) or workers < 1:
            raise InputError(f"--workers must be a whole number >= 1, got {workers!r}")
        self.workers, self.scheduler, self.say, self.connect_timeout = workers, scheduler, progress, connect_timeout
        self.client = None
        self.cluster = None

    @property
    def serial(self) -> bool:
        return self.scheduler is None and self.workers == 1

    def __enter__(self) -> TaskRunner:
        return self

    def start(self) -> None:
        """Connect to the scheduler or start the local cluster (done by the first map with work for it)."""
        if self.serial or self.client is not None:
            return
        import dask
        from distributed import Client, LocalCluster

        if self.scheduler is not None:
            try:
                self.client = Client(self.scheduler, timeout=f"{self.connect_timeout}s")
            except (OSError, TimeoutError) as exc:
                raise InputError(f"cannot reach the Dask scheduler at {self.scheduler} ({exc})") from None
        else:
            env = {f"distributed.nanny.pre-spawn-environ.{k}": None for k in _THREAD_VARS}
            with dask.config.set(env):
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                            silence_logs=logging.ERROR)
            self.client = Client(self.cluster)
        # Import the engine (numpy, scipy, Open3D: seconds each) in every worker now, at the cluster's
        # start, not inside the first tasks.
        self.client.run(_warm)
        if self.say:
            n = len(self.client.scheduler_info(n_workers=-1).get("workers", {}))
            where = self.scheduler or "a local cluster"
            self.say(f"Dask: {n} workers on {where}; dashboard {self.client.dashboard_link}")

    def __exit__(self, *exc) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        self.client = self.cluster = None

    def map(self, fn: Callable, items: Sequence[Any], shared: Any = None, label: str | None = None) -> list:
        """``[fn(shared, item) ...]`` (or ``fn(item)`` when ``shared`` is None), in the order of ``items``."""
        items = list(items)
        label = label or getattr(fn, "__name__", "task").removesuffix("_task") + "s"
        bar = Progress(len(items), label, self.say)
        if self.serial or len(items) < 2:  # one task: a cluster would only add its start-up
            out = []
            for item in items:
                out.append(fn(item) if shared is None else fn(shared, item))
                bar.step()
            return out
        from distributed import as_completed

        self.start()
        # Many short tasks (e.g. 276 overlap measurements of a 24-scan campaign) go in batches of
        # consecutive items, about 16 batches per worker: the scheduler's cost per task stays small.
        n_workers = max(1, len(self.client.scheduler_info(n_workers=-1).get("workers", {})))
        size = max(1, len(items) // (16 * n_workers))
        batches = [items[k:k + size] for k in range(0, len(items), size)]
        [ref] = self.client.scatter([shared], broadcast=True, hash=False)
        futures = self.client.map(_run_batch, [fn] * len(batches), [ref] * len(batches), batches, pure=False)
        try:
            for fut in as_completed(futures):
                if fut.status == "error":
                    fut.result()  # raises the task's own exception (an InputError stays one)
                for _ in range(len(batches[futures.index(fut)])):
                    bar.step()
            return [r for part in self.client.gather(futures) for r in part]
        finally:
            for fut in futures:
                fut.release()


def _warm() -> None:
    import open3d  # noqa: F401

    import core.merge  # noqa: F401


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
