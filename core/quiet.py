"""Libraries' own console messages kept off the console.

Open3D writes its warnings straight to standard output from C++ ("[Open3D WARNING] Too few correspondences
..." from a feature match with few mutual matches, dozens of times in a merge); they say nothing the result
does not, and they break the one-line-per-event output of the CLI. :func:`quiet_open3d` lowers Open3D's
level to errors once per process (the CLI's, and each Dask worker's before its first task), and notes it
on the ``rangereg`` logger. Set ``RANGEREG_OPEN3D_WARNINGS=1`` to see them again (the variable reaches the
local cluster's workers too).
"""

from __future__ import annotations

import logging
import os

ENV = "RANGEREG_OPEN3D_WARNINGS"
_done = False


def quiet_open3d() -> None:
    """Open3D at error level in this process, unless :data:`ENV` is set; idempotent and cheap after the first call."""
    global _done
    if _done:
        return
    _done = True
    if os.environ.get(ENV, "").strip() not in ("", "0"):
        return
    import open3d as o3d

    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    logging.getLogger("rangereg").debug("Open3D's warnings are off (set %s=1 to see them)", ENV)
