"""IK_HOST:IK_PORT that cannot be listened on stops ``python -m service`` at once, in one
line naming the variable (an operator trial: uvicorn said "[Errno -2] Name or service
not known" for an unresolvable host, and a port in use only after the app had started)."""

from __future__ import annotations

import socket
from collections.abc import Iterator

import pytest

from service.listen_check import listen_problem

from .helpers import python_m_service


@pytest.fixture
def taken_port() -> Iterator[int]:
    """A port another program listens on (127.0.0.1)."""
    with socket.socket() as other:
        other.bind(("127.0.0.1", 0))
        other.listen()
        yield other.getsockname()[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
    return port


def test_a_port_in_use_is_named_with_what_to_do(taken_port: int) -> None:
    said = listen_problem("127.0.0.1", taken_port)
    assert said is not None
    assert said.startswith(f"IK_HOST:IK_PORT: cannot listen on 127.0.0.1:{taken_port} (")
    assert "another process listens there" in said and "set IK_PORT" in said
    # Every interface includes the loopback one that is taken.
    assert listen_problem("0.0.0.0", taken_port) is not None


def test_a_host_that_does_not_resolve_names_ik_host() -> None:
    said = listen_problem("no-such-host.invalid", _free_port())  # .invalid: RFC 2606
    assert said is not None
    assert said.startswith("IK_HOST: 'no-such-host.invalid' does not resolve to an address (")


def test_an_address_this_machine_does_not_have_names_ik_host() -> None:
    said = listen_problem("192.0.2.1", _free_port())  # TEST-NET-1: on no interface here
    assert said is not None
    assert "cannot listen on 192.0.2.1:" in said and "set IK_HOST" in said


def test_a_free_address_is_no_problem_and_stays_free() -> None:
    port = _free_port()
    assert listen_problem("127.0.0.1", port) is None
    assert listen_problem("localhost", port) is None
    with socket.socket() as again:  # the probe let go of it
        again.bind(("127.0.0.1", port))


def test_python_m_service_stops_before_the_app_starts(taken_port: int) -> None:
    """Exit 1 with the one line, and nothing of uvicorn's or the app's start before it."""
    done = python_m_service(IK_HOST="127.0.0.1", IK_PORT=str(taken_port))
    assert done.returncode == 1, done
    assert done.stderr.strip().splitlines() == [
        f"cannot start: IK_HOST:IK_PORT: cannot listen on 127.0.0.1:{taken_port} "
        "(Address already in use): another process listens there: stop it, or set "
        "IK_PORT to a free port"
    ], done.stderr


def test_an_address_family_the_kernel_lacks_is_skipped_as_asyncio_does(
    monkeypatch: pytest.MonkeyPatch, taken_port: int
) -> None:
    """A kernel with IPv6 off and a host name that resolves to ::1 and 127.0.0.1 (as
    Debian's localhost does): uvicorn listens on 127.0.0.1; the check raised OSError
    from the IPv6 socket it could not create (a review). The kernel's refusal is
    stood in for by a socket class that refuses AF_INET6."""
    real_socket = socket.socket

    def no_ipv6(family: int = socket.AF_INET, *args: object, **kwargs: object) -> socket.socket:
        if family == socket.AF_INET6:
            raise OSError(97, "Address family not supported by protocol")
        return real_socket(family, *args, **kwargs)  # type: ignore[arg-type]

    def both(host: str, port: int, **_: object) -> list[tuple[object, ...]]:
        return [
            (socket.AF_INET6, socket.SOCK_STREAM, 6, "", ("::1", port, 0, 0)),
            (socket.AF_INET, socket.SOCK_STREAM, 6, "", ("127.0.0.1", port)),
        ]

    monkeypatch.setattr(socket, "socket", no_ipv6)
    monkeypatch.setattr(socket, "getaddrinfo", both)
    assert listen_problem("dual-stack-name", _free_port()) is None
    # The IPv4 address is still checked.
    assert listen_problem("dual-stack-name", taken_port) is not None
