"""Every script in benchmarks/ runs at its smallest setting (``--smallest``: a few thousand points, one start,
one pair), so a change that breaks a benchmark fails here. The figures they print are not checked: they
are measurements for docs/benchmarks.md, taken on a quiet machine, never test outcomes."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tests.conftest import BUNNY, ROOT

BENCHMARKS = ROOT / "benchmarks"
BROWSER = {"workbench_frame", "workbench_rate"}  # headless Chromium: with the browser tests
SHARED = {"campaign_bunny"}  # campaigns of the shared scans themselves, even at their smallest


def scripts() -> list[str]:
    """The benchmarks/ modules that are scripts (run as ``python benchmarks/NAME.py``), by name."""
    return sorted(p.stem for p in BENCHMARKS.glob("*.py") if 'if __name__ == "__main__"' in p.read_text())


def test_every_script_is_found_and_helpers_are_not():
    found = scripts()
    assert {"large_pair", "closest_points", "bad_inputs", "campaign", "register_time"} <= set(found)
    assert "browser" not in found  # the page benchmarks' shared Chromium, not a script


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.browser) if n in BROWSER else n for n in scripts()])
def test_a_benchmark_runs_at_its_smallest(name):
    if name in BROWSER:
        from tests.test_workbench import CHROMIUM

        if not CHROMIUM.exists():
            pytest.skip("Debian's chromium is not installed (scripts/install --browser)")
    if name in SHARED and not BUNNY.is_dir():
        pytest.skip(f"{BUNNY}: the shared bunny scans are absent")
    r = subprocess.run([sys.executable, str(BENCHMARKS / f"{name}.py"), "--smallest"], cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0 and r.stdout.strip(), f"exit {r.returncode}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"
    assert "Traceback" not in r.stderr, r.stderr[-3000:]
