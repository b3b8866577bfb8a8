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

import http
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
            return original(handler, *args, process_request=guard.wrap(process_request), **kwargs)

        ws.serve = serve
        try:
            yield
        finally:
            ws.serve = original
    if not calls:
        raise RuntimeError("could not install the Origin/Host check in viser's server: refusing to serve")
