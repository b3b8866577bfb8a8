"""core.threads: BLAS on one thread once the engine is imported, unless the environment says otherwise; cached values
worked out without a lock across instances."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from tests.conftest import ROOT

PROBE = ("import json, rangereg.core, threadpoolctl; "
         "print(json.dumps([i['num_threads'] for i in threadpoolctl.threadpool_info() if i['user_api'] == 'blas']))")


def blas_threads(**env: str) -> list[int]:
    """The BLAS libraries' thread counts in a fresh process that imported rangereg.core, with ``env`` set."""
    clean = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS",
                                                              "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", PROBE], cwd=ROOT, env={**clean, **env}, capture_output=True,
                         text=True, timeout=120, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_the_engine_runs_blas_on_one_thread():
    threads = blas_threads()
    assert threads and all(n == 1 for n in threads), threads  # numpy's and scipy's OpenBLAS both


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: BLAS has one thread anyway")
def test_a_thread_count_the_user_set_stands():
    threads = blas_threads(OPENBLAS_NUM_THREADS="2")
    assert threads and all(n == 2 for n in threads), threads


def test_the_fpfh_hypotheses_are_the_same_run_after_run():
    # the turntable's crops 0: on Open3D's two threads, pairs among these gave other RANSAC hypotheses from run to
    # run (2 of 12 pairs, three runs each); on one thread none does (core.threads.open3d_one_thread)
    from rangereg.app.crops import crop
    from rangereg.core.candidates import fpfh_candidates
    from rangereg.core.turntable import make_campaign

    scans = [crop(s, 0) for s in make_campaign(0).scans]
    for i in range(0, 23, 2):
        s, t = scans[i + 1], scans[i]
        runs = [np.stack(fpfh_candidates(s, t, max(s.spacing, t.spacing), (5.0,), 2, 0)) for _ in range(4)]
        assert all(np.array_equal(r, runs[0]) for r in runs), i


def test_open3d_gets_its_thread_count_back():
    import open3d as o3d
    from rangereg.core.threads import open3d_one_thread

    before = o3d.utility.get_max_threads()
    with open3d_one_thread():
        assert o3d.utility.get_max_threads() == 1
    assert o3d.utility.get_max_threads() == before


def test_two_instances_work_out_their_cached_values_at_once_and_keep_them():
    # Python 3.11's functools.cached_property holds one lock per property across every instance: the second
    # thread here would wait at the barrier for a first that waits for it (a BrokenBarrierError after 5 s)
    from rangereg.core.threads import cached_property

    barrier, calls = threading.Barrier(2, timeout=5), []

    class Holder:
        @cached_property
        def value(self) -> int:
            calls.append(self)
            barrier.wait()
            return id(self)

    a, b = Holder(), Holder()
    with ThreadPoolExecutor(2) as pool:
        got = list(pool.map(lambda h: h.value, (a, b)))
    assert got == [id(a), id(b)] and len(calls) == 2
    barrier = threading.Barrier(1)
    assert (a.value, b.value) == (id(a), id(b)) and len(calls) == 2  # kept: not worked out again


def test_the_engines_cached_values_are_built_without_a_lock_across_instances():
    from rangereg.core.frustum import Frustum
    from rangereg.core.panorama import SphericalImage
    from rangereg.core.scan import Scan
    from rangereg.core.surface import Surface
    from rangereg.core.threads import cached_property
    from rangereg.core.unstructured import CloudView

    for cls in (Scan, Surface, CloudView, SphericalImage, Frustum):
        props = [v for v in vars(cls).values() if "cached_property" in type(v).__name__]
        assert props and all(isinstance(v, cached_property) for v in props), cls
