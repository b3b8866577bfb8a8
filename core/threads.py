"""BLAS on one thread, unless the user's environment says otherwise; Open3D's RANSAC on one thread, always.

The engine's products are tall and thin (an (N, 3) cloud times a 3 x 3 rotation, 6 x 6 normal equations):
OpenBLAS splits them over its threads, which then wait for one another and for the engine's own threads (the
surface built beside the search, Open3D's queries, KISS-Matcher's child). Measured on these 2 cores with other
work running (load 2-4): a 250k x 3 times 3 x 3 product took 96 ms on OpenBLAS's two threads and 3.3 ms on one;
files to pose, the whole ``register --json`` command in turn, 5 pairs of runs: the shared LiDAR pair 0.82 x the
wall and CPU time with one thread, the Kinect pair capture0002 -> 0001 0.72 x, the same pose to the last digit.
Where OPENBLAS_NUM_THREADS, OMP_NUM_THREADS or MKL_NUM_THREADS is set (as Dask's nanny sets it on a worker),
that choice stands.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def usable_cpus() -> list[int] | None:
    """The CPUs this process may run on (its affinity mask, where the system keeps one: a container's cpuset), or
    None."""
    try:
        return sorted(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return None


def usable_cores() -> int:
    """How many cores this process may use: its affinity mask where there is one, else the machine's (at least 1)."""
    cpus = usable_cpus()
    return max(1, len(cpus) if cpus else os.cpu_count() or 1)


def one_blas_thread() -> bool:
    """Limit every BLAS library loaded (numpy's and scipy's) to one thread, unless an environment variable of
    ``BLAS_THREAD_VARIABLES`` is set. Returns whether it did."""
    if any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES):
        return False
    import numpy  # noqa: F401 (both BLAS copies loaded first: threadpoolctl limits the libraries it finds)
    import scipy.linalg  # noqa: F401
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
    return True


# Open3D's feature-matching RANSAC is not repeatable on several threads, seed or not: its threads share the
# iterations and stop early at whichever finds the confident hypothesis first, so the order the operating system
# runs them in decides the result (Open3D's maintainers: "the only way to completely avoid it is with single
# threaded processing", isl-org/Open3D#7475). Measured on the simulated turntable's crops 0 (12 neighbour pairs,
# 5-spacing FPFH, two seeds each, three runs): on Open3D's two threads 2 of 12 pairs gave other hypotheses from run
# to run, and so another campaign; on one, none. The lock keeps two callers (the page's runs) from restoring each
# other's count halfway.
_OPEN3D_THREADS = threading.Lock()


@contextmanager
def open3d_one_thread() -> Iterator[None]:
    """Open3D's parallel loops on one thread while the block runs (the count before is restored after it)."""
    import open3d as o3d

    with _OPEN3D_THREADS:
        before = o3d.utility.get_max_threads()
        o3d.utility.set_max_threads(1)
        try:
            yield
        finally:
            o3d.utility.set_max_threads(before)


class cached_property:  # noqa: N801 - functools' name, as Python 3.12 has it
    """A value worked out on first access and kept in the instance (functools.cached_property as Python 3.12 has
    it), for every class of the engine. Python 3.11's holds one lock per property across every instance, so two
    threads building two scans' k-d trees (the pair's files read side by side, the whole target's surface made
    beside the search) waited for each other, and so did two surfaces' vertex trees or two clouds' coarse trees;
    here two threads asking for the same instance's value at once may both work it out (the same value)."""

    def __init__(self, func: Callable[[Any], Any]) -> None:
        self.func = func
        self.__doc__ = func.__doc__

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, instance: Any, owner: type | None = None) -> Any:
        if instance is None:
            return self
        value = self.func(instance)
        instance.__dict__[self.name] = value
        return value
