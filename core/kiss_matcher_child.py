"""KISS-Matcher in a process of its own: the child side of core.kiss_matcher_candidates.

Run by path (``python core/kiss_matcher_child.py``), so it imports neither the ``core`` package nor Open3D:
numpy and kiss_matcher only (~0.15 s). Its directory, core/, is then first on sys.path: no module there may be
named ``kiss_matcher`` (it would hide the library). KISS-Matcher's first use is made on one CPU, so its TBB runs
one thread from then on and the same clouds give the same bits (core.kiss_matcher_candidates explains why).

Protocol, little-endian, on stdin/stdout (stdout is moved off fd 1 first, so that anything the
library prints goes to stderr instead of into the replies):
    request: int64 n_source, int64 n_target, float64 voxel, then n_source x 3 and n_target x 3 float32
    reply:   uint8 valid, then 16 float64 (the 4x4 T_target_source, row-major, in the clouds' units)
End of input ends the process.
"""

from __future__ import annotations

import os
import struct
import sys

HEAD = struct.Struct("<qqd")


def _read(stream, n: int) -> bytes:
    """Exactly ``n`` bytes from ``stream`` (EOFError when it ends first)."""
    buf = bytearray()
    while len(buf) < n:
        chunk = stream.read(n - len(buf))
        if not chunk:
            raise EOFError
        buf += chunk
    return bytes(buf)


def main() -> int:
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)  # the library's prints go to stderr, never into a reply
    import kiss_matcher
    import numpy as np

    if hasattr(os, "sched_setaffinity"):
        # its TBB takes its thread count from this mask at its first use, once: one CPU for a tiny
        # estimate, then the whole mask again (one thread, free to run on any core)
        mask = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {max(mask)})
        pts = np.random.default_rng(0).random((200, 3)).astype(np.float32)
        kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(0.3)).estimate(pts, pts)
        os.sched_setaffinity(0, mask)

    inp = sys.stdin.buffer
    while True:
        try:
            n_s, n_t, voxel = HEAD.unpack(_read(inp, HEAD.size))
            a = np.frombuffer(_read(inp, 12 * n_s), dtype=np.float32).reshape(n_s, 3)
            b = np.frombuffer(_read(inp, 12 * n_t), dtype=np.float32).reshape(n_t, 3)
        except EOFError:
            return 0
        sol = kiss_matcher.KISSMatcher(kiss_matcher.KISSMatcherConfig(voxel)).estimate(a, b)
        T = np.eye(4)
        if sol.valid:
            T[:3, :3] = np.asarray(sol.rotation)
            T[:3, 3] = np.asarray(sol.translation).ravel()
        out.write(bytes([1 if sol.valid else 0]) + T.astype("<f8").tobytes())
        out.flush()


if __name__ == "__main__":
    sys.exit(main())
