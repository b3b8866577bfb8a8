"""KISS-Matcher's hypothesis (Lim et al. 2025; pip ``kiss-matcher``, an optional extra), computed in a
process of its own.

Two facts about the library, measured here, shape this module:

- Its Python binding holds the GIL for the whole estimate (0.15-0.25 s on a bunny pair): on a thread
  of ours it stalls the cut, the noise floor and the basis it was meant to overlap. In a child
  process (core/kiss_matcher_child.py, started once and kept) it runs on the other core while they run here.
- Its parallel feature matching gives a slightly different hypothesis from run to run (ten runs on
  bun045->bun000: up to 0.12 deg and 0.2 mm apart; upstream MIT-SPARK/KISS-Matcher issue 89, open),
  and a global run refined from them ended up to 0.08 deg apart. On one thread every run gives the
  same bits (four bunny pairs, ten runs each). Its TBB takes its thread count once, from the CPU
  mask at its first use: so the child makes that first use on one CPU, and so does the fallback in
  this process when the child cannot start (``_serial_in_process``).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import selectors
import subprocess
import sys
import threading
from functools import cache
from pathlib import Path

import numpy as np

from .kiss_matcher_child import HEAD, _read
from .scan import Scan

KISS_VOXEL = 0.3  # KISS-Matcher's default voxel size; it refuses small ones (it is made for metres)
# KISS-Matcher (1.0, the wheel here) crashes the process on small clouds: random clouds of 3-80 points
# segfault, 100 do not; it asks for >= 50 final inliers anyway. Fewer voxels than this: no hypothesis.
# It skips the 8-stop simulated turntable's scans (115-138 cells at 5 spacings; 8 of 8 placed from
# identity poses without it, tests/test_campaign.py) and none of the bunny's (4.0-4.6k) or its crops'
# (1.1-2.3k) or the 24-stop turntable's (246-277). A crash on a larger cloud is contained (ChildDied).
KISS_MIN_POINTS = 200
CHILD = Path(__file__).with_name("kiss_matcher_child.py")
# A guard against a stuck estimate, not a bound on the search (that counts work: core.search.budget). Its maximum-clique
# step can run for minutes on some inputs (upstream MIT-SPARK/KISS-Matcher issue 8, "Occasionally, pmc stuck", on
# submaps); measured here an estimate takes 0.1-0.5 s (bunny pairs, the shared LiDAR and Kinect frames, 300k-point
# TSDF fragments at every grid of CandidateConfig.kiss_grids), so a process silent this long is stuck: it is killed
# and the search goes on without its hypothesis.
ANSWER_SECONDS = 120.0


@cache
def kiss_available() -> bool:
    """Whether kiss-matcher is installed and imports (~0.1 s, once)."""
    try:
        import kiss_matcher  # noqa: F401
    except ImportError:
        return False
    return True


def voxel_clouds(source: Scan, target: Scan, spacing: float, voxel: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Both scans on Open3D's voxel grid, in units where the voxel (``voxel`` point spacings) is
    KISS_VOXEL: (source (S, 3) float32, target (T, 3) float32, the scale k applied)."""
    import open3d as o3d

    k = KISS_VOXEL / (voxel * spacing)

    def cloud(scan: Scan) -> np.ndarray:
        # Open3D's grid first: KISS-Matcher then builds its features on ~1/10 of the points (its own grid of
        # the same size finds the same cells). Measured on three bunny pairs from 180 deg: 0.17-0.27 s of
        # CPU instead of 0.33-0.44 s, hypotheses 0.7-4.1 deg off instead of 0.8-5.2.
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(scan.points * k)).voxel_down_sample(KISS_VOXEL)
        return np.ascontiguousarray(np.asarray(pcd.points), dtype=np.float32)

    return cloud(source), cloud(target), k


def start() -> None:
    """Start KISS-Matcher's process now, when it is installed, so that its start-up (~0.15-0.3 s: an
    interpreter, numpy, the library) overlaps other work (the CLI's imports and file reading); else
    it starts on first use. Where the process is busy with a request (another run of this process) it returns
    at once: the process is started already."""
    if kiss_available() and _CHILD._lock.acquire(blocking=False):
        try:
            _CHILD._started()
        except OSError:
            pass  # first use says it again and falls back to this process
        finally:
            _CHILD._lock.release()


def kiss_candidates(source: Scan, target: Scan, spacing: float, voxel: float) -> list[np.ndarray]:
    """KISS-Matcher's one hypothesis T_target_source (voxel size in point spacings), or none when it is
    not installed or finds none."""
    if not kiss_available():
        return []
    a, b, k = voxel_clouds(source, target, spacing, voxel)
    if min(len(a), len(b)) < KISS_MIN_POINTS:
        return []
    key = _digest(a, b)
    if key in _FAILED:  # it died or stuck on this input before: not asked again (a merge's later round, a rerun)
        return []
    try:
        found = _CHILD.estimate(a, b)
    except ChildDied:  # it died or stuck on this input: never repeated in this process, where it would end or hang the run
        _FAILED.add(key)
        return []
    except OSError:  # the child could not start: the same serial estimate here (the same bits)
        found = _estimate_here(a, b)
    if found is None:
        return []
    found[:3, 3] /= k
    return [found]


class ChildDied(OSError):
    """KISS-Matcher's process ended while it worked on a request (a crash on that input), or was killed after
    ANSWER_SECONDS without an answer (stuck on it)."""


class _Child:
    """The one child process of this process (started on first use, kept, ended at exit); one request
    at a time. A process forked from this one starts a child of its own (the pipes are not shared)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._proc: subprocess.Popen | None = None
        self._pid = 0
        self._asked = False  # a request was sent to this child

    def estimate(self, a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """T (4x4) for float32 clouds ``a`` (source) and ``b`` (target), or None when none is valid.
        Raises ChildDied when a signal ended the child on this input (a crash) or it gave no answer within
        ANSWER_SECONDS (killed), OSError when it cannot start or answer otherwise (it is then dropped)."""
        with self._lock:
            proc = self._started()
            self._asked = True
            try:
                proc.stdin.write(HEAD.pack(len(a), len(b), KISS_VOXEL) + a.tobytes() + b.tobytes())
                proc.stdin.flush()
                answered = _answers_within(proc, ANSWER_SECONDS)
                reply = _read(proc.stdout, 1 + 16 * 8) if answered else b""
            except (EOFError, OSError, ValueError) as exc:
                try:
                    code = proc.wait(timeout=1)
                except subprocess.TimeoutExpired:
                    code = None
                self._drop()
                if code is not None and code < 0:  # ended by a signal while on this input: a crash
                    raise ChildDied(f"KISS-Matcher's process ended by signal {-code}") from exc
                raise OSError(f"KISS-Matcher's process did not answer: {exc}") from exc
            if not answered:
                self._drop()
                raise ChildDied(f"KISS-Matcher's process gave no answer in {ANSWER_SECONDS:g} s: killed")
        return np.frombuffer(reply[1:], dtype="<f8").reshape(4, 4).astype(np.float64) if reply[0] else None

    def _started(self) -> subprocess.Popen:
        if self._proc is None or self._pid != os.getpid() or self._proc.poll() is not None:
            self._proc = subprocess.Popen([sys.executable, str(CHILD)], stdin=subprocess.PIPE,
                                          stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
            self._pid = os.getpid()
            self._asked = False
        return self._proc

    def _drop(self) -> None:
        if self._proc is not None and self._pid == os.getpid():
            self._proc.kill()
            self._proc.wait()
        self._proc = None

    def close(self) -> None:
        """End the child (at exit): end of its input ends it; one never asked (a run that ended on bad input)
        is killed, not waited for while it starts (0.15-0.3 s), and an interrupt while waiting kills it."""
        with self._lock:
            if self._proc is not None and self._pid == os.getpid():
                try:
                    if not self._asked:
                        raise OSError
                    self._proc.stdin.close()
                    self._proc.wait(timeout=2)
                except (OSError, subprocess.TimeoutExpired, KeyboardInterrupt):
                    self._proc.kill()
            self._proc = None


def _answers_within(proc: subprocess.Popen, seconds: float) -> bool:
    """Whether ``proc`` has written to its output (its reply, or the end of it) within ``seconds``. Where a pipe
    cannot be waited on with a timeout (not POSIX) it is read as before, with no guard. (A selector, not
    select.select, which refuses file numbers from 1024 on: a long-lived workbench or worker can reach them.)"""
    if os.name != "posix":
        return True
    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        return bool(sel.select(seconds))


def _digest(a: np.ndarray, b: np.ndarray) -> bytes:
    """A request's identity: the two clouds' bytes, hashed."""
    h = hashlib.sha1(a.tobytes())
    h.update(b"|")
    h.update(b.tobytes())
    return h.digest()


_FAILED: set[bytes] = set()  # the requests the process died or stuck on (kiss_candidates)


_CHILD = _Child()
atexit.register(_CHILD.close)

_serial_lock = threading.Lock()
_serial_done = False


def _estimate_here(a: np.ndarray, b: np.ndarray) -> np.ndarray | None:
    import kiss_matcher

    _serial_in_process()
    sol = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(KISS_VOXEL)).estimate(a, b)
    if not sol.valid:
        return None
    T = np.eye(4)
    T[:3, :3] = np.asarray(sol.rotation)
    T[:3, 3] = np.asarray(sol.translation).ravel()
    return T


def _serial_in_process() -> None:
    """KISS-Matcher's bundled TBB reads its thread count once, from the main thread's CPU mask, when
    first used: so its first use here is a tiny estimate with that mask narrowed to one CPU for its
    ~10 ms, then restored. Where the mask cannot be set (not Linux) it keeps its threads and its spread."""
    global _serial_done
    with _serial_lock:
        if _serial_done:
            return
        _serial_done = True
        if not hasattr(os, "sched_setaffinity"):
            return
        import kiss_matcher

        pid = os.getpid()  # the main thread's mask (Linux keeps one per thread)
        mask = os.sched_getaffinity(pid)
        os.sched_setaffinity(pid, {max(mask)})
        try:
            pts = np.random.default_rng(0).random((200, 3)).astype(np.float32)
            kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(KISS_VOXEL)).estimate(pts, pts)
        finally:
            os.sched_setaffinity(pid, mask)
