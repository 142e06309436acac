"""Whether ``python -m service`` can listen on IK_HOST:IK_PORT, checked before the app
starts, and said in one line that names the variable to change.

Left to uvicorn, an operator trial read ``[Errno -2] Name or service not known`` (which
name?) for a host name that does not resolve, and ``[Errno 98] error while attempting to
bind on address ('127.0.0.1', 18101): address already in use`` for a port in use, both
after "Application startup complete" and the start of the solver's warm-up (on a first
start, its compile), with exit code 3. The check binds a probe socket the way asyncio's
``create_server`` will (every address the host resolves to, ``SO_REUSEADDR``, IPv6 only
on IPv6 sockets) and closes it; a port taken between the check and uvicorn's bind still
gets uvicorn's own message.
"""

from __future__ import annotations

import errno
import socket

# What to do about the bind errors an operator meets, by errno.
_ADVICE = {
    errno.EADDRINUSE: "another process listens there: stop it, or set IK_PORT to a free port",
    errno.EADDRNOTAVAIL: "no interface of this machine has that address: set IK_HOST to one "
    "that does (0.0.0.0: every interface; 127.0.0.1: this machine only)",
    errno.EACCES: "a port below 1024 needs privileges this process lacks: set IK_PORT to "
    "1024 or above",
}


def listen_problem(host: str, port: int) -> str | None:
    """Why the service could not listen on ``host:port``, in one line naming IK_HOST or
    IK_PORT; None when a probe socket binds there."""
    try:
        addresses = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as e:
        return (
            f"IK_HOST: {host!r} does not resolve to an address ({e.strerror}): give an IP "
            "address (127.0.0.1, 0.0.0.0, ::) or a name this machine resolves"
        )
    for family, kind, proto, _, address in addresses:
        try:
            probe = socket.socket(family, kind, proto)
        except OSError:  # a family this kernel lacks (IPv6 off): asyncio skips it too
            continue
        with probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:  # as asyncio: IPv4 is a socket of its own
                probe.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            try:
                probe.bind(address)
            except OSError as e:
                where = f"[{address[0]}]" if family == socket.AF_INET6 else address[0]
                advice = _ADVICE.get(e.errno or 0)
                said = f": {advice}" if advice else ""
                return f"IK_HOST:IK_PORT: cannot listen on {where}:{port} ({e.strerror or e}){said}"
    return None
