"""X-Forwarded-For against a real server (IK_FORWARDED_ALLOW_IPS, service/forwarded.py):
believed from a listed proxy only, so that the per-address session limit and the logs
see each real client, directly and through the real HAProxy with deploy/haproxy.cfg.

Clients take distinct loopback addresses (127.0.0.2, ...: all of 127/8 is this
machine on Linux) so that each test has buckets of its own in the shared server.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Iterator

import httpx
import pytest
from websockets.sync.client import connect

from loadtest.cluster import Balancer, missing_programs

from .conftest import Server
from .test_server import PANDA, TIMEOUT_S

pytestmark = pytest.mark.live

LIMIT = 2  # sessions per address per minute: the third is 429
MAX_CONNECTIONS = 4


@pytest.fixture(scope="module")
def proxied(start_server: Callable[..., Server]) -> Server:
    return start_server(
        IK_FORWARDED_ALLOW_IPS="127.0.0.1",
        IK_SESSIONS_PER_ADDRESS_PER_MIN=str(LIMIT),
        IK_MAX_CONNECTIONS_PER_ADDRESS=str(MAX_CONNECTIONS),
    )


def _from(address: str) -> httpx.Client:
    """An HTTP client whose connections come from ``address``."""
    return httpx.Client(transport=httpx.HTTPTransport(local_address=address), timeout=TIMEOUT_S)


def _creates(client: httpx.Client, base: str, forwarded_for: str | None, n: int) -> list[int]:
    headers = {} if forwarded_for is None else {"X-Forwarded-For": forwarded_for}
    return [
        client.post(f"{base}/v1/sessions", json={"chain": PANDA}, headers=headers).status_code
        for _ in range(n)
    ]


def _logged(server: Server, text: str) -> bool:
    """Whether the server's log holds ``text`` (within a second: the log is a pipe)."""
    deadline = time.monotonic() + 5
    while text not in server.log():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


def test_by_default_no_forwarded_for_is_believed(start_server: Callable[..., Server]) -> None:
    """Not even from this machine: uvicorn's own default believes 127.0.0.1's, which let
    any local program pick a new address per request."""
    plain = start_server(IK_SESSIONS_PER_ADDRESS_PER_MIN=str(LIMIT))
    with _from("127.0.0.1") as client:
        codes = [_creates(client, plain.base, f"198.51.100.{i}", 1)[0] for i in range(3)]
    assert codes == [201] * LIMIT + [429]
    assert "198.51.100." not in plain.log()
    plain.stop()


def test_an_untrusted_peer_s_forwarded_for_is_not_believed(proxied: Server) -> None:
    with _from("127.0.0.2") as client:
        # A new address in each header: believed, every one would have a bucket of its own.
        codes = [_creates(client, proxied.base, f"198.51.100.{i}", 1)[0] for i in range(3)]
    assert codes == [201] * LIMIT + [429]
    assert _logged(proxied, "127.0.0.2:")
    assert "198.51.100." not in proxied.log()
    assert _logged(proxied, "X-Forwarded-For from 127.0.0.2 ignored")


def test_a_trusted_proxy_s_forwarded_for_names_the_client(proxied: Server) -> None:
    with _from("127.0.0.1") as proxy:
        first = _creates(proxy, proxied.base, "203.0.113.7", LIMIT + 1)
        second = _creates(proxy, proxied.base, "203.0.113.8", 1)
    assert first == [201] * LIMIT + [429]  # one client's limit, not the proxy's
    assert second == [201]
    assert _logged(proxied, '203.0.113.8:0 - "POST /v1/sessions HTTP/1.1" 201')


def _served(address: str, port: int, opened: list[socket.socket]) -> bool:
    """Whether a connection from ``address``, kept open in ``opened``, gets an answer."""
    s = socket.socket()
    opened.append(s)
    s.settimeout(TIMEOUT_S)
    s.bind((address, 0))
    s.connect(("127.0.0.1", port))
    try:
        s.sendall(b"GET /healthz HTTP/1.1\r\nhost: x\r\n\r\n")
        return s.recv(12).startswith(b"HTTP/1.1 200")
    except ConnectionError:  # closed at accept (a reset)
        return False


def test_a_trusted_proxy_is_not_held_to_the_connection_cap(proxied: Server) -> None:
    """The count is taken at accept, before any header, on the TCP peer: a proxy
    carries every client's connections."""
    opened: list[socket.socket] = []
    try:
        proxy = [_served("127.0.0.1", proxied.port, opened) for _ in range(MAX_CONNECTIONS + 2)]
        other = [_served("127.0.0.6", proxied.port, opened) for _ in range(MAX_CONNECTIONS + 1)]
    finally:
        for s in opened:
            s.close()
    assert all(proxy)
    assert other == [True] * MAX_CONNECTIONS + [False]


@pytest.fixture(scope="module")
def balancer(proxied: Server) -> Iterator[Balancer]:
    lb = _ready_balancer(proxied)
    try:
        yield lb
    finally:
        lb.stop()


def _ready_balancer(worker: Server) -> Balancer:
    """HAProxy with deploy/haproxy.cfg in front of ``worker``, once it sees it ready."""
    missing = missing_programs()
    if "haproxy" in missing:
        if os.environ.get("CI") == "true":
            pytest.fail("haproxy not installed; CI=true, so this is a failure", pytrace=False)
        pytest.skip("haproxy not installed (.ci/run installs it)")
    lb = Balancer([worker.port])
    deadline = time.monotonic() + 10  # its first health check marks the worker up
    while httpx.get(f"{lb.base}/readyz", timeout=TIMEOUT_S).status_code != 200:
        if time.monotonic() > deadline:
            lb.stop()
            raise AssertionError("the balancer never saw the worker ready")
        time.sleep(0.1)
    return lb


def test_through_haproxy_each_client_has_its_own_limit(proxied: Server, balancer: Balancer) -> None:
    # Both clients write the same address in a header of their own: HAProxy drops it
    # and writes the address it saw, and the worker takes that one.
    for address in ("127.0.0.3", "127.0.0.4"):
        with _from(address) as client:
            assert _creates(client, balancer.base, "192.0.2.1", LIMIT + 1) == [201] * LIMIT + [429]
        assert _logged(proxied, f'{address}:0 - "POST /v1/sessions HTTP/1.1" 201')
    assert "192.0.2.1" not in proxied.log()


def test_through_haproxy_a_websocket_sees_its_client(proxied: Server, balancer: Balancer) -> None:
    with _from("127.0.0.5") as client:
        r = client.post(f"{balancer.base}/v1/sessions", json={"chain": PANDA})
    assert r.status_code == 201, r.text
    sid, token = r.json()["id"], r.json()["token"]
    sock = socket.socket()
    sock.settimeout(TIMEOUT_S)
    sock.bind(("127.0.0.5", 0))
    sock.connect(("127.0.0.1", balancer.port))
    url = balancer.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws"
    with connect(url, sock=sock, additional_headers={"Authorization": f"Bearer {token}"}):
        pass
    assert _logged(proxied, f'127.0.0.5:0 - "WebSocket /v1/sessions/{sid}/ws" [accepted]')


@pytest.fixture(scope="module")
def wide_list_balancer(start_server: Callable[..., Server]) -> Iterator[tuple[Server, Balancer]]:
    """A list wider than the proxy, as docker-compose.yml's private networks are: the
    clients (127.0.0.7, 127.0.0.8) are inside it too, as a LAN client or Docker's
    gateway is inside 10/8, 172.16/12, 192.168/16."""
    wide = start_server(
        IK_FORWARDED_ALLOW_IPS="127.0.0.0/8", IK_SESSIONS_PER_ADDRESS_PER_MIN=str(LIMIT)
    )
    lb = _ready_balancer(wide)
    try:
        yield wide, lb
    finally:
        lb.stop()
        wide.stop()


def test_through_haproxy_a_client_in_the_list_cannot_pick_its_address(
    wide_list_balancer: tuple[Server, Balancer],
) -> None:
    """uvicorn takes the rightmost entry not in the list: had HAProxy appended its
    entry after the client's, a client inside the list would be passed over and the
    address it wrote believed, a new one per request."""
    wide, lb = wide_list_balancer
    for address in ("127.0.0.7", "127.0.0.8"):
        with _from(address) as client:
            codes = [_creates(client, lb.base, f"198.51.100.{i}", 1)[0] for i in range(LIMIT + 1)]
        assert codes == [201] * LIMIT + [429]
        assert _logged(wide, f'{address}:0 - "POST /v1/sessions HTTP/1.1" 201')
    assert "198.51.100." not in wide.log()
