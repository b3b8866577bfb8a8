"""When a local Dask cluster pays for its start: the default task runner's choice (app.distributed, ``workers=None``).

The plain loop runs the tasks until the work left, at the rate its tasks have taken, outlasts what a cluster of one
worker per core would take including its start; the speed-up such a cluster can give is what the cores the loop
keeps busy already leave to it (:class:`BusyCores`), no more workers than tasks left.
"""

from __future__ import annotations

import os
import time

from rangereg.core.threads import usable_cores, usable_cpus

# When a local cluster pays (workers=None). A cluster of N workers on C cores runs what the plain loop runs at most
# CLUSTER_EFFICIENCY x C / B times as fast, B the cores the loop keeps busy already (its own threads, Open3D's
# ray casts, KISS-Matcher's child, whatever else runs here: measured over its tasks, :class:`BusyCores`); work w
# seconds long on the loop then takes START_SECONDS + w / speed-up on the cluster, which pays from
# w = START_SECONDS x speed-up / (speed-up - 1). Measured here (2 cores): a local cluster of 2 workers starts in
# 3.3-4.8 s on a quiet machine (processes and the engine's imports; 3.6-4.0 s on 2026-12-07's; 5-27 s at load 9-16);
# on the 24-scan campaign of 1.6-1.9k-point scans, whose loop keeps about one core busy, 2 workers ran the pairwise
# stage 1.65-1.72 x faster than the loop: efficiency 1.65 / 2, and it pays from 12 s of work, as before. The 10-scan
# campaign of 40k-point scans keeps 1.4-1.5 cores busy on the loop (Open3D's threads, the noise floors' thread,
# KISS-Matcher's child): its 2 workers, one thread each, took 1.6 x as long a pair, and the cluster started with
# 14 s of work left (the earlier rule: 12 s) ended the campaign 4.4 s later than the loop (41.0 s against 36.6).
START_SECONDS = 4.8
CLUSTER_EFFICIENCY = 1.65 / 2
# Under load a second worker finds no free core (2 workers were 0.42-1.06 x the loop at load 9-16): no
# cluster while the 1-minute load average is above the cores less this.
LOAD_MARGIN = 0.5


def default_workers() -> int:
    """As many workers as cores this process may use (core.threads.usable_cores; at least 1)."""
    return usable_cores()


def payback_seconds(cores: int, busy: float = 1.0, tasks: int | None = None) -> float:
    """The plain loop's work (seconds) from which a local cluster of one worker per core pays for its start, the loop
    keeping ``busy`` cores busy, ``tasks`` tasks left (None: as many as cores; no more workers than tasks can run at
    once); inf: a cluster cannot run faster. The start (START_SECONDS) was measured for 2 workers on 2 cores."""
    speedup = CLUSTER_EFFICIENCY * min(cores, cores if tasks is None else tasks) / max(1.0, busy)
    return START_SECONDS * speedup / (speedup - 1.0) if speedup > 1.0 else float("inf")


def cluster_pays(seconds_left: float, cores: int | None = None, load: float | None = None,
                 busy: float | None = None, tasks: int | None = None) -> tuple[bool, str]:
    """Whether ``seconds_left`` of work on the plain loop (``tasks`` tasks), which keeps ``busy`` cores busy (None:
    one), pays for starting a local cluster, and why."""
    cores = default_workers() if cores is None else cores
    if load is None:
        load = os.getloadavg()[0] if hasattr(os, "getloadavg") else 0.0  # (Windows has none: the busy cores say it)
    if cores < 2:
        return False, "one core: a cluster cannot run faster"
    if load > cores - LOAD_MARGIN:
        return False, f"the machine is busy (load {load:.1f} on {cores} cores): a second worker finds no free core"
    payback = payback_seconds(cores, 1.0 if busy is None else busy, tasks)
    kept = "" if busy is None else f"; the loop keeps {busy:.2f} of {cores} cores busy"
    if payback == float("inf"):
        few = tasks is not None and tasks < cores
        why = (f"{tasks} task(s) left" if few else
               f"the loop keeps {1.0 if busy is None else busy:.2f} of {cores} cores busy already")
        return False, f"{why}: a cluster cannot run faster"
    if seconds_left < payback:
        return False, f"about {seconds_left:.1f} s of work left, less than a local cluster's start pays back " \
                      f"({payback:.1f} s{kept})"
    return True, f"about {seconds_left:.1f} s of work left, more than a local cluster's start pays back " \
                 f"({payback:.1f} s{kept})"


class BusyCores:
    """The cores busy while the plain loop runs its tasks of one kind (all processes: the loop's threads, its child
    processes, anyone else's work, on the CPUs this process may use), from the system's CPU times between each task's
    start and end; the first 3 tasks of the kind left out, as ``app.distributed.Progress.rate`` leaves them."""

    def __init__(self) -> None:
        self.busy = self.wall = 0.0
        self.tasks = 0
        self._start: tuple[float, float] | None = None

    @staticmethod
    def _now() -> tuple[float, float]:
        import psutil  # a dependency of dask.distributed

        def busy(t) -> float:  # guest time is counted in user time already (Linux)
            return sum(t) - t.idle - getattr(t, "iowait", 0.0) - getattr(t, "guest", 0.0) - getattr(t, "guest_nice", 0.0)

        cpus, each = usable_cpus(), psutil.cpu_times(percpu=True)
        if cpus and max(cpus) < len(each):  # only the CPUs this process may use (a container's cpuset)
            return time.perf_counter(), sum(busy(each[k]) for k in cpus)
        return time.perf_counter(), busy(psutil.cpu_times())

    def start(self) -> None:
        self._start = self._now()

    def stop(self) -> None:
        if self._start is None:
            return
        (w0, b0), (w1, b1) = self._start, self._now()
        self._start = None
        self.tasks += 1
        if self.tasks > 3:
            self.wall += w1 - w0
            self.busy += b1 - b0

    @property
    def cores(self) -> float | None:
        """The mean cores busy over the steady tasks (None before one)."""
        return self.busy / self.wall if self.wall > 0 else None
