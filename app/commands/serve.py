"""``rangereg serve``: start the viser workbench with typed options (app.workbench). A ``--trace`` is read
here and checked against the first pair (its header's scans, app.tab.replay.read_checked) before the
server listens."""

from __future__ import annotations

from argparse import Namespace

from rangereg.app.options import read_text_file
from rangereg.core.errors import InputError
from rangereg.core.files import check_folder, stat_regular
from rangereg.core.trace import read_trace


def run(a: Namespace) -> int:
    from rangereg.app.workbench import ServeOptions, serve

    if (a.source is None) != (a.target is None):
        raise InputError("serve takes two scans (SOURCE TARGET) or none")
    for p in (a.source, a.target):
        if p is not None:
            stat_regular(p, p, "a scan file")  # missing, a folder, a FIFO, a device, a link loop: one line now
    if a.trace is not None:  # missing, a folder, unreadable, binary, not a trace: one line now (its scans: below)
        read_trace(read_text_file(a.trace, "--trace"), f"--trace {a.trace}")
    if a.data_dir is not None:
        check_folder(a.data_dir, f"--data-dir {a.data_dir}")
    if not a.host.strip():
        raise InputError("--host: expected a host name or address, got nothing")
    return serve(ServeOptions(source=a.source, target=a.target, scene=a.scene, host=a.host, port=a.port,
                              data_dir=a.data_dir, upload_cap_mb=a.upload_cap_mb, trace=a.trace,
                              scan_kind=getattr(a, "scan_kind", None)))
