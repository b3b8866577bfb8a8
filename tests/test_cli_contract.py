"""The CLI's contract seen from outside, as real subprocesses (a traceback at exit or a broken pipe
only shows there): a fast subset of the bad-input table (benchmarks/bad_inputs.py) and a closed pipe."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import pytest

from tests.conftest import ASSETS, ROOT

_spec = importlib.util.spec_from_file_location("bad_inputs", ROOT / "benchmarks" / "bad_inputs.py")
bad_inputs = sys.modules.setdefault("bad_inputs", importlib.util.module_from_spec(_spec))
if not hasattr(bad_inputs, "CASES"):
    _spec.loader.exec_module(bad_inputs)


def test_the_table_holds_at_least_300_distinct_cases():
    names = [c.name for c in bad_inputs.CASES]
    assert len(set(names)) == len(names) >= 300
    assert len({(c.args, c.pipe, c.signal, c.stdout_closed) for c in bad_inputs.CASES}) == len(names)
    assert set(bad_inputs.FAST) <= set(names)


def test_a_fast_subset_of_the_bad_input_table_meets_the_contract():
    failures = []
    cases = [c for c in bad_inputs.CASES if c.name in bad_inputs.FAST]
    failed = bad_inputs.run_table(cases, jobs=2, timeout=120.0, say=failures.append)
    assert failed == 0, "\n".join(failures)


def test_a_closed_pipe_ends_quietly():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    p = subprocess.Popen([sys.executable, "-m", "rangereg.app.cli", "info", str(ASSETS / "corner" / "scan1.ply")], cwd=ROOT,
                         env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()  # as `| head` does once it has its lines: the command's writes meet a closed pipe
    err = p.stderr.read().decode()
    p.wait(timeout=120)
    assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err
    assert p.returncode == 1


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_the_entry_point_reports_a_full_disk_in_one_line():
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-m", "rangereg.app.cli", "info", str(ASSETS / "corner" / "scan1.ply"), "--json"],
                       cwd=ROOT, env=env, stdout=open("/dev/full", "w"), stderr=subprocess.PIPE, text=True, timeout=120)
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.returncode == 2


_ORDER = """
import sys
from rangereg.core import kiss_matcher_candidates
from rangereg.app.commands import register
kiss_matcher_candidates.kiss_available = lambda: True
kiss_matcher_candidates.start = lambda: print("kiss", "open3d" in sys.modules)
register.run = lambda a: print("run", "open3d" in sys.modules) or 0
from rangereg.app.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("flags, said", [((), "kiss False\nrun True\n"), (("--method", "hybrid"), "run True\n")])
def test_register_starts_kiss_matchers_process_before_open3d_is_imported_and_only_when_it_may_ask_it(flags, said):
    # its start-up (an interpreter, numpy, the library) then overlaps Open3D's import instead of the files' reading
    scans = [str(ASSETS / "corner" / f"scan{i}.ply") for i in (1, 2)]
    p = subprocess.run([sys.executable, "-c", _ORDER, "register", *scans, *flags], cwd=ROOT, capture_output=True,
                       text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert (p.returncode, p.stdout) == (0, said), p.stderr
