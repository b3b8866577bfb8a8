"""core.threads: BLAS on one thread once the engine is imported, unless the environment says otherwise."""

from __future__ import annotations

import json
import os
import subprocess
import sys

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
