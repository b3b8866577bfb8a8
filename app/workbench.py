"""``rangereg serve``: the viser workbench. One server, one :class:`app.tab.page.Tab` per browser tab.

It listens on 127.0.0.1 unless told otherwise (viser's own default is every interface), serves
only its own page (Host and Origin checked, app/access.py), refuses a taken port instead of moving
to another, fetches nothing from the internet and hides viser's share button (the share link would
go through a public relay).
"""

from __future__ import annotations

import errno
import socket
import sys
import threading
import time
from dataclasses import dataclass
from functools import cache
from pathlib import Path

from rangereg.core.e57 import split_selection
from rangereg.core.errors import InputError
from rangereg.core.files import TRACE_LIMIT, read_bytes, stat_regular
from rangereg.core.io import FORMATS, load_scan
from rangereg.core.scan import Scan
from rangereg.core.scenes import scene_paths
from rangereg.core.simulate import SCENES

ASSETS = Path(__file__).resolve().parent.parent / "assets"
SCAN_SUFFIXES = FORMATS  # every format core.io reads
MAX_LISTED_FILES = 500
PANEL_WIDTH = 480  # pixels of the page the docked panel takes: room for the E chart and the contour (the floating
# "large" panel was ~400; at 480 the contour's axes and colour bar fit, docs/landscape.png)


@dataclass(frozen=True)
class ServeOptions:
    """What ``rangereg serve`` was asked for: a pair of scan paths (or a bundled scene), where to listen."""

    source: str | None = None
    target: str | None = None
    scene: str = "corner"
    host: str = "127.0.0.1"
    port: int = 8080
    data_dir: str | None = None
    upload_cap_mb: float = 200.0
    trace: str | None = None  # a register --trace file of SOURCE -> TARGET, opened on the Replay timeline
    scan_kind: str | None = None  # --scan-kind: every scan the page opens is of this kind (None: from each file)

    def __post_init__(self) -> None:
        if not self.upload_cap_mb > 0:
            raise InputError(f"--upload-cap-mb must be positive, got {self.upload_cap_mb}")


@cache
def _load_cached(path: str, mtime: float, kind: str | None = None) -> Scan:
    return load_scan(path, kind=kind)


def _load(path: Path, kind: str | None = None) -> Scan:
    path, selector = split_selection(path)  # one scan of an E57: site.e57#K or site.e57#NAME
    st = stat_regular(path, str(path), "a scan file")  # a FIFO, a device, a link loop: refused unread
    return _load_cached(str(path.resolve()) + ("" if selector is None else f"#{selector}"), st.st_mtime, kind)


def check_port(host: str, port: int) -> None:
    """Raise InputError when ``host:port`` cannot be bound (taken, or not an address of this machine)."""
    if not 0 < port < 65536:
        raise InputError(f"--port must be between 1 and 65535, got {port}")
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as exc:
        raise InputError(f"--host {host!r} is not a usable address ({exc.strerror})") from None
    family, _, _, _, addr = infos[0]
    with socket.socket(family, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise InputError(f"port {port} on {host} is taken; choose another with --port") from None
            raise InputError(f"cannot listen on {host}:{port} ({exc.strerror})") from None


class Workbench:
    def __init__(self, options: ServeOptions):
        import viser
        from rangereg.app.access import Guard, guarded_viser

        self.options = options
        self.scene_names = list(SCENES)
        self.upload_cap_mb = float(options.upload_cap_mb)
        self.upload_cap = int(self.upload_cap_mb * 1e6)
        self.data_dir = Path(options.data_dir).resolve() if options.data_dir else None
        if self.data_dir is not None and not self.data_dir.is_dir():
            raise InputError(f"--data-dir {options.data_dir}: no such folder")
        # Check the first pair before the server starts: a bad file is one clear line, not a page error.
        if options.source or options.target:
            if not (options.source and options.target):
                raise InputError("give both SOURCE and TARGET, or neither (the default scene opens)")
            kind = options.scan_kind
            self.first_pair = (_load(Path(options.source), kind), _load(Path(options.target), kind))
        else:
            self.first_pair = self.scene_pair(options.scene)
        self.trace = self._check_trace(options.trace) if options.trace else None
        check_port(options.host, options.port)
        with guarded_viser(Guard(options.host)):
            self.server = viser.ViserServer(host=options.host, port=options.port, label="rangereg", verbose=False)
        self.server.gui.configure_theme(show_share_button=False, control_width="large", dark_mode=False)
        # beside the scene, not over it: nothing is hidden under the panel, and a software-rendered page draws
        # 35 % fewer canvas pixels a frame (bunny pair, 1400 x 900 page, no run: 15-16 frames a second docked,
        # 11-14 floating)
        self.server.gui.main_panel.dock_right()
        self.server.gui.main_panel.set_width(PANEL_WIDTH)
        self.tabs: dict = {}
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)

    def _check_trace(self, path: str) -> tuple[str, bytes]:
        """(name, bytes) of a trace that parses and is of the first pair; else one InputError, before serving."""
        from rangereg.app.tab.replay import read_checked
        from rangereg.core.problem import prepare, relative_guess
        from rangereg.core.register import estimate_threshold

        content = read_bytes(path, f"--trace {path}", TRACE_LIMIT, "a text file")
        source, target = self.first_pair
        problem = prepare(source, target, relative_guess(source, target), seed=0)
        read_checked(content.decode("utf-8", errors="replace"), f"--trace {path}", source, target, problem,
                     estimate_threshold(problem, 0))
        return Path(path).name, content

    @property
    def urls(self) -> list[str]:
        """Where a browser finds the page: each address of this machine when listening on every interface."""
        from rangereg.app.access import reachable_addresses

        return [f"http://{f'[{a}]' if ':' in a else a}:{self.options.port}"
                for a in reachable_addresses(self.options.host)]

    @property
    def url(self) -> str:
        return self.urls[0]

    def scene_pair(self, name: str) -> tuple[Scan, Scan]:
        if name not in SCENES:
            raise InputError(f"unknown scene {name!r}; choose one of {', '.join(SCENES)}")
        src, tgt = scene_paths(ASSETS, name)
        if not src.exists():
            raise InputError(f"the bundled scene {name} is missing from {ASSETS}; run 'rangereg scenes'")
        return _load(src), _load(tgt)

    def data_files(self) -> list[str]:
        """Scan files under --data-dir, relative to it."""
        if self.data_dir is None:
            return []
        files = sorted(p for p in self.data_dir.rglob("*") if p.suffix.lower() in SCAN_SUFFIXES and p.is_file())
        return [str(p.relative_to(self.data_dir)) for p in files[:MAX_LISTED_FILES]]

    def load_data_file(self, relative: str) -> Scan:
        """A file under --data-dir; nothing outside it is ever read."""
        if self.data_dir is None:
            raise InputError("the workbench was started without --data-dir")
        path = (self.data_dir / relative).resolve()
        if not path.is_relative_to(self.data_dir):
            raise InputError(f"{relative}: outside the data folder")
        return _load(path, self.options.scan_kind)

    def _guard_uploads(self, client) -> None:
        """The client's uploads held to the cap while they arrive (app.access.UploadGuard): viser buffers them
        in the client's own GUI state. The tab checks the size again when one completes."""
        from rangereg.app.access import UploadGuard

        def refuse(client_id, text: str) -> None:
            tab = self.tabs.get(client_id)
            if tab is not None:
                tab.notify("Upload refused", text)

        UploadGuard(self.upload_cap, refuse).install(client.gui)

    def _connect(self, client) -> None:
        from rangereg.app.tab.page import Tab

        self._guard_uploads(client)
        tab = Tab(self, client)
        self.tabs[client.client_id] = tab

        def first() -> None:
            try:
                tab.load_pair(*self.first_pair, scene="-" if self.options.source else self.options.scene)
                if self.trace is not None:
                    tab.replay.load_trace(*self.trace)
            except InputError as exc:
                tab.notify("Could not open the scans", str(exc))

        tab.actions.submit(first)  # the tab's first action: a click meanwhile waits for the pair, not beside its load

    def _disconnect(self, client) -> None:
        tab = self.tabs.pop(client.client_id, None)
        if tab is not None:
            tab.close()


def serve(options: ServeOptions, stop: threading.Event | None = None) -> int:
    """Entry point of ``rangereg serve``; blocks until interrupted or ``stop`` is set."""
    from rangereg.app.access import WILDCARDS

    # The optimiser's worker thread is busy Python; a short switch interval lets the server's threads
    # (events, page pushes) take the GIL within milliseconds, so Pause and the 10 Hz path stay live.
    sys.setswitchinterval(0.001)
    wb = Workbench(options)
    if options.host in WILDCARDS:
        print(f"warning: --host {options.host or '(empty)'} listens on every network interface: anyone who can reach "
              "this machine can open the workbench and read the scans. Use 127.0.0.1 unless you mean it.",
              file=sys.stderr, flush=True)
    print(f"rangereg workbench: {'  '.join(wb.urls)}  (Ctrl+C to stop)", flush=True)
    stop = stop or threading.Event()
    try:
        while not stop.is_set():
            time.sleep(0.5)
    except KeyboardInterrupt:
        pass
    finally:
        wb.server.stop()
    return 0
