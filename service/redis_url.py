"""What makes an ``IK_REDIS_URL`` one the service cannot use, said at start.

redis-py's ``from_url`` reads a URL leniently: a path that is not a number is database
0 without a word, an unknown query option fails only at the first connection (then
every readiness probe errs), and ``?socket_timeout=`` silently replaces the timeout the
service sets from ``IK_REDIS_TIMEOUT_S``. So the URL is read here the way redis-py reads
it, and refused with a reason at start. No message quotes the URL or any part of it:
it may hold a password (one with an unencoded ``/``, ``?`` or ``#`` even ends up where
the port should be).
"""

from __future__ import annotations

from urllib.parse import parse_qs, unquote, urlsplit

SCHEMES = ("redis", "rediss", "unix")
# Set by the service from IK_REDIS_TIMEOUT_S (service/redis_commit.py ``connect``):
# a URL that sets them would quietly override it.
SET_BY_THE_SERVICE = frozenset(
    {"socket_timeout", "socket_connect_timeout", "timeout", "retry_on_timeout",
     "health_check_interval"}
)  # fmt: skip
# Options a URL may carry: redis-py's URL options, and the TLS files of rediss://.
OPTIONS = frozenset(
    {"db", "max_connections", "socket_keepalive", "socket_read_size", "protocol",
     "legacy_responses", "client_name", "ssl_check_hostname", "ssl_min_version",
     "ssl_include_verify_flags", "ssl_exclude_verify_flags", "ssl_cert_reqs",
     "ssl_ca_certs", "ssl_ca_path", "ssl_certfile", "ssl_keyfile"}
)  # fmt: skip


def redis_url_problem(url: str) -> str | None:
    """Why redis-py could not use ``url`` as the service would, else None."""
    try:
        from redis.asyncio.connection import URL_QUERY_ARGUMENT_PARSERS
    except ImportError:
        return "sessions in Redis need redis-py: pip install '.[redis]'"
    try:
        parts = urlsplit(url)
        parts.port  # noqa: B018  (ValueError when not a number in 0-65535)
    except ValueError:
        return (
            "not a URL with a port redis-py can read (percent-encode a password that holds "
            "/, ? or #)"
        )
    if parts.scheme not in SCHEMES:
        return "must start with redis://, rediss:// or unix://"
    query = parse_qs(parts.query)
    for key, values in query.items():
        if key in SET_BY_THE_SERVICE:
            return f"?{key} is set by the service: use IK_REDIS_TIMEOUT_S"
        if key not in OPTIONS:
            return f"?{key} is not a connection option redis-py knows"
        parser = URL_QUERY_ARGUMENT_PARSERS.get(key)
        if parser is not None and values:
            try:
                parser(values[0])
            except (TypeError, ValueError):
                return f"?{key} has a value redis-py cannot read"
    if parts.scheme == "unix":
        return None if parts.path else "unix:// needs the socket's path"
    db = unquote(parts.path).replace("/", "")  # redis-py's own reading of the path
    if db and "db" not in query:
        try:
            int(db)
        except ValueError:
            if "@" in parts.path:  # redis://:pa/ss@host: the password's '/' began the path
                return (
                    "the path is the database number (/0, /1, ...); percent-encode a "
                    "password that holds / (%2F), ? (%3F) or # (%23)"
                )
            return "the path is the database number (/0, /1, ...)"
    return None
