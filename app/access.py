"""Who may talk to the workbench: its own page only.

A page on any other site could otherwise open a WebSocket to the workbench (browsers let it) and
drive it, and a DNS-rebinding page could reach it under a foreign host name. So every request must
name one of our hosts in its ``Host`` header (loopback names, plus the host the server was told to
listen on), and a WebSocket opened by a browser must come from a page served under that same host
(``Origin``). A client that sends no ``Origin`` is not a web page (browsers always send it on a
WebSocket) and is let through.

viser 1.1.1 has no hook for this; it hands its own ``process_request`` (the static files) to
``websockets.asyncio.server.serve`` on its server thread. :func:`guarded_viser` wraps that one call
while the server starts, and fails closed if viser no longer makes it.
"""

from __future__ import annotations

import asyncio
import http
import logging
import socket
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from urllib.parse import urlsplit

LOOPBACK = ("localhost", "127.0.0.1", "::1")
WILDCARDS = ("0.0.0.0", "::", "")


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now (for a server started next: tests, benchmarks,
    the recording's static page)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _host_of(netloc: str) -> str | None:
    """Lower-case host name of ``host[:port]`` (IPv6 without brackets), None when malformed."""
    try:
        parts = urlsplit("//" + netloc.strip())
        parts.port  # noqa: B018 (raises ValueError on a bad port)
    except ValueError:
        return None
    return parts.hostname


def reachable_addresses(host: str) -> list[str]:
    """Addresses a browser can use to reach a server bound to ``host`` (each of this machine's for a wildcard)."""
    if host not in WILDCARDS:
        return [host]
    found = {"127.0.0.1"}
    try:
        for *_, addr in socket.getaddrinfo(socket.gethostname(), None, type=socket.SOCK_STREAM):
            if host == "::" or ":" not in addr[0]:
                found.add(addr[0])
    except OSError:
        pass
    return sorted(found, key=lambda a: (a.startswith("127."), a))


def allowed_hosts(host: str) -> frozenset[str]:
    """Host names a request may carry: loopback names, the listening host, and for a wildcard this machine's names."""
    names = set(LOOPBACK)
    if host in WILDCARDS:
        names |= set(reachable_addresses(host)) | {socket.gethostname(), socket.getfqdn()}
    else:
        names.add(host)
    return frozenset(n.strip("[]").lower() for n in names)


_TWICE = object()


def _single(headers, name: str):
    """The header's value, None when absent, ``_TWICE`` when given more than once."""
    values = headers.get_all(name) if hasattr(headers, "get_all") else [v for v in [headers.get(name)] if v is not None]
    return _TWICE if len(values) > 1 else (values[0] if values else None)


class Guard:
    """Decides, from a request's headers, whether it comes from the workbench's own page."""

    def __init__(self, host: str):
        self.hosts = allowed_hosts(host)

    def refusal(self, headers, websocket: bool) -> str | None:
        """Why a request is refused, or None to serve it. ``headers``: websockets ``Headers`` (or a dict)."""
        host, origin = _single(headers, "Host"), _single(headers, "Origin")
        if host is _TWICE or origin is _TWICE:
            return "a repeated Host or Origin header"
        if not host or _host_of(host) not in self.hosts:
            return f"Host {host!r} is not this workbench"
        if websocket and origin is not None:
            o = urlsplit(origin)
            if o.scheme not in ("http", "https") or o.netloc.lower() != host.strip().lower():
                return f"Origin {origin!r} is not this workbench's page"
        return None

    def wrap(self, inner: Callable | None) -> Callable:
        """A websockets ``process_request`` that refuses foreign requests (403) and hands the rest to ``inner``."""

        def process_request(connection, request):
            websocket = request.headers.get("Upgrade", "").lower() == "websocket"
            reason = self.refusal(request.headers, websocket)
            if reason is not None:
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"Forbidden: {reason}\n")
            return inner(connection, request) if inner is not None else None

        return process_request


# The largest WebSocket message the workbench accepts from a page. viser's page sends uploads in parts of
# 512 KiB and this workbench asks it for no renders (viser allows 50 MiB for those); the rest are small GUI
# updates. websockets buffers a message whole before anyone sees it, so this bounds what one frame can cost.
MAX_FRAME = 4 << 20

log = logging.getLogger("rangereg.workbench")


def _one_line(what: str, exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{what} ({type(exc).__name__}{': ' + text[:160] if text else ''})"


def quiet_handler(inner: Callable) -> Callable:
    """A websockets connection handler that logs a page's malformed frame (one viser cannot decode, or a
    message its handlers choke on) as one line instead of a traceback; the connection is closed either way."""

    async def handler(connection):
        loop = asyncio.get_running_loop()
        if not getattr(loop, "_rangereg_quiet", False):
            loop.set_exception_handler(_loop_errors)
            loop._rangereg_quiet = True
        try:
            await inner(connection)
        except Exception as exc:  # noqa: BLE001 - whatever a page sends, the server keeps serving
            log.warning(_one_line("closed a page connection after a malformed frame", exc))

    return handler


def _loop_errors(loop, context: dict) -> None:
    """The server loop's handler of errors nobody awaited (a message handler that failed on a page's frame)."""
    exc = context.get("exception")
    log.warning(_one_line(f"ignored a page message: {context.get('message', 'error')}", exc) if exc is not None
                else f"ignored a page message: {context.get('message', 'error')}")


_PATCH_LOCK = threading.Lock()


@contextmanager
def guarded_viser(guard: Guard) -> Iterator[None]:
    """While this is open, a websockets server that viser starts checks every request with ``guard``.

    Raises RuntimeError on exit when no server was started through the hook (a viser that no longer
    calls ``websockets.asyncio.server.serve``): better no workbench than an unguarded one.
    """
    import websockets.asyncio.server as ws

    calls = []
    with _PATCH_LOCK:
        original = ws.serve

        def serve(handler, *args, process_request=None, **kwargs):
            calls.append(1)
            kwargs["max_size"] = min(kwargs.get("max_size") or MAX_FRAME, MAX_FRAME)
            return original(quiet_handler(handler), *args, process_request=guard.wrap(process_request), **kwargs)

        ws.serve = serve
        try:
            yield
        finally:
            ws.serve = original
    if not calls:
        raise RuntimeError("could not install the Origin/Host check in viser's server: refusing to serve")


class UploadGuard:
    """Holds a page's uploads to a cap while their bytes arrive, not after: an upload that announces more
    than the cap is dropped at its first message, and one that sends more than it announced (or fewer, once
    every part is in) is dropped at the part that shows it, before viser keeps that part. So at most the cap
    is ever buffered, and viser never has to warn about a transfer that lies about its length.

    viser keeps an upload's parts in the client's GUI state (``GuiApi._current_file_upload_states``,
    private) until the last arrives. The guard's handlers go first in the client's dispatch (``install``)
    and drop the transfer there. ``refuse(client_id, text)`` tells the page why.
    """

    def __init__(self, cap: int, refuse: Callable[[int, str], None]):
        self.cap, self.refuse = int(cap), refuse
        self.transfers: dict[str, dict] = {}  # uuid -> name, announced bytes, parts expected, seen, received
        self.refused: set[str] = set()
        self._lock = threading.Lock()
        self.states: dict | None = None

    def install(self, gui) -> bool:
        """Hook into a client's viser ``GuiApi``; False when its upload state is not where this expects it."""
        from viser import _messages

        self.states = getattr(gui, "_current_file_upload_states", None)
        iface = getattr(gui, "_websock_interface", None)
        if not isinstance(self.states, dict) or iface is None:
            self.states = None
            return False
        handlers = getattr(iface, "_incoming_handlers", None)
        for cls, cb in ((_messages.FileTransferStartUpload, self.started), (_messages.FileTransferPart, self.part)):
            if isinstance(handlers, dict):  # before viser's own: a part is judged before it is kept
                handlers.setdefault(cls, []).insert(0, cb)
            else:
                iface.register_handler(cls, cb)
        return True

    def started(self, client_id: int, message) -> None:
        size, name, parts = message.size_bytes, message.filename, message.part_count
        if not isinstance(size, int) or not isinstance(parts, int) or size < 0 or parts < 0 or size > self.cap:
            shown = f"{size / 1e6:.3g} MB" if isinstance(size, (int, float)) else repr(size)
            self._drop(message.transfer_uuid, client_id, f"{name}: {shown} is over the upload cap "
                                                         f"({self.cap / 1e6:.3g} MB)")
            return
        with self._lock:
            self.transfers[message.transfer_uuid] = {"name": name, "size": size, "parts": parts, "seen": set(),
                                                     "received": 0}

    def part(self, client_id: int, message) -> None:
        uid = message.transfer_uuid
        with self._lock:
            t = self.transfers.get(uid)
            if t is None:
                if uid in self.refused and self.states is not None:  # before viser can keep this part
                    self.states.pop(uid, None)
                return
            if message.part_index in t["seen"] or not (isinstance(message.part_index, int)
                                                       and 0 <= message.part_index < t["parts"]):
                return  # viser drops it too
            t["seen"].add(message.part_index)
            n = len(message.content) if isinstance(message.content, (bytes, bytearray, memoryview)) else 0
            t["received"] += n
            last = len(t["seen"]) == t["parts"]
            why = None
            if t["received"] > min(t["size"], self.cap):
                why = f"sent more than the {t['size'] / 1e6:.3g} MB it announced ({t['received'] / 1e6:.3g} MB so far)"
            elif last and t["received"] != t["size"]:
                why = f"sent {t['received']} bytes where it announced {t['size']}"
            if why is None and not last:
                return
            self.transfers.pop(uid, None)
        if why is not None:
            self._drop(uid, client_id, f"{t['name']}: {why}; refused")

    def _drop(self, uid: str, client_id: int, text: str) -> None:
        with self._lock:
            self.transfers.pop(uid, None)
            self.refused.add(uid)  # viser may make its state after this: each later part drops it first
            if self.states is not None:
                self.states.pop(uid, None)
        log.warning(f"refused an upload: {text}")
        try:
            self.refuse(client_id, text)
        except Exception:  # noqa: BLE001 - a closed tab cannot be told
            pass
