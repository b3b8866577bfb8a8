"""The workbench serves its own page only: Host and Origin checks (app/access.py), unit level."""

from __future__ import annotations

import pytest
from rangereg.app.access import Guard, allowed_hosts, reachable_addresses
from websockets.datastructures import Headers


@pytest.mark.parametrize("host", ["127.0.0.1:8080", "localhost:8080", "LOCALHOST", "[::1]:8080"])
def test_loopback_page_is_served(host):
    g = Guard("127.0.0.1")
    assert g.refusal({"Host": host}, websocket=False) is None
    assert g.refusal({"Host": host, "Origin": f"http://{host}"}, websocket=True) is None


@pytest.mark.parametrize("headers", [
    {"Host": "127.0.0.1:8080", "Origin": "http://evil.example"},
    {"Host": "127.0.0.1:8080", "Origin": "http://127.0.0.1:9999"},  # another local server's page
    {"Host": "127.0.0.1:8080", "Origin": "null"},  # a sandboxed frame or a file:// page
    {"Host": "evil.example:8080", "Origin": "http://evil.example:8080"},  # DNS rebinding
    {"Host": "evil.example"},
    {"Host": "127.0.0.1:notaport"},
    {},
])
def test_foreign_pages_and_hosts_are_refused(headers):
    assert Guard("127.0.0.1").refusal(headers, websocket=True) is not None


def test_a_foreign_host_is_refused_for_plain_page_requests_too():
    assert Guard("127.0.0.1").refusal({"Host": "evil.example"}, websocket=False) is not None


def test_repeated_headers_are_refused():
    h = Headers()
    h["Host"] = "127.0.0.1:8080"
    h["Host"] = "evil.example"
    assert Guard("127.0.0.1").refusal(h, websocket=True) is not None


def test_a_client_without_origin_is_not_a_web_page_and_is_served():
    assert Guard("127.0.0.1").refusal({"Host": "127.0.0.1:8080"}, websocket=True) is None


def test_the_listening_host_is_allowed_besides_loopback():
    assert "scanbox.lab" in allowed_hosts("scanbox.lab") and "localhost" in allowed_hosts("scanbox.lab")
    g = Guard("10.1.2.3")
    assert g.refusal({"Host": "10.1.2.3:8080", "Origin": "http://10.1.2.3:8080"}, websocket=True) is None
    assert g.refusal({"Host": "10.1.2.4:8080"}, websocket=True) is not None


def test_every_interface_allows_this_machines_addresses_and_names():
    addrs = reachable_addresses("0.0.0.0")
    assert "127.0.0.1" in addrs
    assert set(addrs) <= allowed_hosts("0.0.0.0")
    assert reachable_addresses("127.0.0.1") == ["127.0.0.1"]
