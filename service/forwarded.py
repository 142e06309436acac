"""Which peers' ``X-Forwarded-For`` the service believes (IK_FORWARDED_ALLOW_IPS).

Behind a reverse proxy every connection comes from the proxy: without its header the
per-address session limit, the per-client work share and the logs all see one client.
uvicorn rewrites a request's client address from ``X-Forwarded-For`` when the TCP
peer is a trusted proxy (``uvicorn.Config(proxy_headers=..., forwarded_allow_ips=...)``,
its ProxyHeadersMiddleware; WebSocket handshakes included); ``python -m service``
turns that on only for the addresses listed here. Empty, no header is believed:
uvicorn's own default trusts 127.0.0.1 and ::1, so any program on the worker's machine
could pick its address per request.

The list is checked at start, stricter than uvicorn (which takes an entry it cannot
read as a literal that never matches, without a word), and ``*`` is refused: uvicorn
then takes the header's first entry, which the client writes (HAProxy's ``option
forwardfor`` and nginx's ``$proxy_add_x_forwarded_for`` append the address they saw
after whatever the client sent; deploy/haproxy.cfg drops the client's header first).
"""

from __future__ import annotations

import functools
import ipaddress
import logging

log = logging.getLogger("service")

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def trusted_networks(value: str) -> tuple[Network, ...]:
    """The comma-separated addresses and networks of ``value`` (``10.0.0.5``,
    ``10.244.0.0/16``, ``::1``); ValueError naming the first entry that is neither."""
    out = []
    for entry in (e.strip() for e in value.split(",")):
        if not entry:
            continue
        if entry == "*":
            raise ValueError(
                "'*' would believe the address a client writes itself: list the proxies' "
                "addresses or networks (10.0.0.5, 10.244.0.0/16)"
            )
        try:
            out.append(ipaddress.ip_network(entry))  # a lone address is a /32 or /128
        except ValueError:
            raise ValueError(
                f"{entry!r} is not an IP address or network (10.0.0.5, 10.244.0.0/16, "
                "::1; a network's host bits zero)"
            ) from None
    return tuple(out)


class TrustedProxies:
    """Membership of a peer's address in IK_FORWARDED_ALLOW_IPS."""

    def __init__(self, networks: tuple[Network, ...] = ()) -> None:
        self.networks = networks
        # Asked at every connection: the few addresses a worker sees, remembered.
        self._contains = functools.lru_cache(maxsize=4096)(self._compute)

    def __bool__(self) -> bool:
        return bool(self.networks)

    def __contains__(self, address: str) -> bool:
        return bool(self.networks) and self._contains(address)

    def as_list(self) -> list[str]:
        """The list as ``uvicorn.Config(forwarded_allow_ips=...)`` takes it."""
        return [str(net) for net in self.networks]

    def _compute(self, address: str) -> bool:
        try:
            ip = ipaddress.ip_address(address)
        except ValueError:  # a Unix socket's path, say
            return False
        return any(ip in net for net in self.networks)


class IgnoredForwards:
    """A peer outside IK_FORWARDED_ALLOW_IPS that sends ``X-Forwarded-For`` while the
    list is set: most likely a proxy the list misses (a Kubernetes ingress's pod
    network), whose clients then all count as one. Logged once per address, for the
    first ``most`` addresses."""

    def __init__(self, most: int = 64) -> None:
        self.most = most
        self.seen: set[str] = set()

    def note(self, address: str) -> None:
        if address in self.seen or len(self.seen) >= self.most:
            return
        self.seen.add(address)
        more = "" if len(self.seen) < self.most else " (no more such addresses are logged)"
        log.warning(
            "X-Forwarded-For from %s ignored: that address is not in IK_FORWARDED_ALLOW_IPS; "
            "if it is a proxy, add it (its clients count as one client until then)%s",
            address,
            more,
        )
