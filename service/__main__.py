"""``python -m service``: uvicorn serving ``create_app`` on IK_HOST:IK_PORT."""

from __future__ import annotations

import os

# Before numpy is imported: one BLAS thread (solves are tiny; threads only contend).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import asyncio  # noqa: E402
import contextlib  # noqa: E402
import logging  # noqa: E402
import re  # noqa: E402
import socket  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import uvicorn  # noqa: E402
from pydantic import ValidationError  # noqa: E402

from .config import (  # noqa: E402
    get_settings,
    misspelt_variables,
    service_link_hint,
    settings_errors,
    unknown_variables,
    usage,
)
from .main import create_app  # noqa: E402
from .peer_limits import PeerLimits, protocols  # noqa: E402

_TOKEN = re.compile(r"(token=)[^&\s\"]+")


class _RedactTokens(logging.Filter):
    """uvicorn's access log prints query strings; WebSocket clients may put ?token= there."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(
                _TOKEN.sub(r"\1<redacted>", a) if isinstance(a, str) else a for a in record.args
            )
        record.msg = _TOKEN.sub(r"\1<redacted>", str(record.msg))
        return True


# Health checks a balancer or a kubelet sends every 0.5-10 s per worker.
_PROBES = frozenset(("/healthz", "/readyz"))


class QuietProbes(logging.Filter):
    """Drops uvicorn's access-log line of a health check that passed: a balancer's
    probes were most of an idle worker's log (925 /readyz lines in a few minutes). A
    probe that fails (503 while compiling or without Redis) is logged when its status
    changes, and then once per ``repeat_s`` at most: a first start's compile of several
    minutes, probed every 0.5 s by two backends, once logged ~750 identical lines."""

    def __init__(self, repeat_s: float = 30.0, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.repeat_s = repeat_s
        self.clock = clock
        self._failed: dict[str, tuple[int, float]] = {}  # path -> (status, when logged)

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        # uvicorn.access: (client address, method, path, HTTP version, status code)
        if isinstance(args, tuple) and len(args) == 5:
            path, status_code = args[2], args[4]
            if path in _PROBES and isinstance(status_code, int):
                if status_code < 400:
                    self._failed.pop(path, None)
                    return False
                now = self.clock()
                last = self._failed.get(path)
                if last is not None and last[0] == status_code and now - last[1] < self.repeat_s:
                    return False
                self._failed[path] = (status_code, now)
        return True


class UtcTimestamps(logging.Formatter):
    """Each line's time in ISO-8601 UTC to the millisecond (2025-06-01T10:00:00.123Z):
    the lines had none, and an operator reads several workers' logs side by side, across
    machines and time zones."""

    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:
        when = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        return f"{when}.{int(record.msecs):03d}Z"


# The time, the worker's pid (which of several on a machine), then uvicorn's level style;
# uvicorn's own lines, its access log included, go through the same handler (log_config=None).
LOG_FORMAT = "%(asctime)s [%(process)d] %(levelname)s:     %(message)s"


def log_handler() -> logging.Handler:
    handler = logging.StreamHandler()  # stderr, as before
    handler.setFormatter(UtcTimestamps(LOG_FORMAT))
    return handler


class DrainingServer(uvicorn.Server):
    """uvicorn's server, with one step before its shutdown: stop accepting, then let the
    WebSocket messages in flight be answered (each such socket then closes 1012),
    within IK_GRACEFUL_SHUTDOWN_S; messages still being solved get their
    ``shutting_down`` error, all within one more second. uvicorn then closes the
    remaining (idle) WebSockets with 1012 and gives HTTP requests in flight up to
    IK_GRACEFUL_SHUTDOWN_S again: a stop takes at most twice that plus a second (the
    k8s manifest's terminationGracePeriodSeconds, 15, covers the default 5)."""

    def __init__(self, config: uvicorn.Config, app: Any) -> None:
        super().__init__(config)
        self.app = app

    async def shutdown(self, sockets: list[socket.socket] | None = None) -> None:
        for server in self.servers:  # refuse new connections from now on
            server.close()
        svc = getattr(self.app.state, "ik", None)
        if svc is not None:
            svc.draining = True
            deadline = time.monotonic() + float(self.config.timeout_graceful_shutdown or 0)
            while svc.ws_in_flight > 0 and time.monotonic() < deadline:
                await asyncio.sleep(0.005)
            # Messages still being solved get an error they can act on before 1012.
            replies = [reply() for reply in list(svc.shutdown_replies)]
            if replies:  # together, within one second (not one second each)
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(asyncio.gather(*replies, return_exceptions=True), 1.0)
        await super().shutdown(sockets)


def main() -> None:
    if len(sys.argv) > 1:  # an operator trial: --port was ignored, --help started it
        if sys.argv[1] in ("-h", "--help"):
            print(usage())
            raise SystemExit(0)
        raise SystemExit(
            f"python -m service takes no arguments (got {' '.join(sys.argv[1:])!r}): set "
            "IK_* variables instead, e.g. IK_PORT=8001 python -m service; the list: "
            "python -m service --help"
        )
    hint = service_link_hint(os.environ)
    also = "" if hint is None else f"\n  ({hint})"
    try:
        settings = get_settings()
    except ValidationError as e:  # said in the environment's names, not a traceback
        raise SystemExit(settings_errors(e) + also) from None
    if typos := misspelt_variables(os.environ):
        raise SystemExit("invalid configuration:\n  " + "\n  ".join(typos.values()) + also)
    logging.basicConfig(level=settings.log_level.upper(), handlers=[log_handler()])
    for name in ("uvicorn.access", "uvicorn.error"):
        logging.getLogger(name).addFilter(_RedactTokens())
    logging.getLogger("uvicorn.access").addFilter(QuietProbes())
    for warning in unknown_variables(os.environ):
        logging.getLogger("service").warning(warning)
    host = f"[{settings.host}]" if ":" in settings.host else settings.host
    logging.getLogger("service").info(
        "IK service on http://%s:%d (API docs: http://%s:%d/docs)",
        host,
        settings.port,
        host,
        settings.port,
    )
    app = create_app(settings)
    proxies = settings.trusted_proxies()
    http_protocol, ws_protocol = protocols(
        PeerLimits(
            max_header_bytes=settings.max_header_bytes,
            max_headers=settings.max_headers,
            header_timeout_s=settings.header_timeout_s,
            body_timeout_s=settings.body_timeout_s,
            max_connections_per_address=settings.max_connections_per_address or 2**62,
            ws_max_write_buffer_bytes=settings.ws_max_write_buffer_bytes,
            ws_max_pings_per_s=settings.ws_max_pings_per_s,
            trusted_proxies=proxies,
        )
    )
    config = uvicorn.Config(
        app,
        host=settings.host,
        port=settings.port,
        http=http_protocol,  # httptools, with limits on headers and slow peers
        ws=ws_protocol,  # websockets-sansio, with a bound on unread pongs
        # X-Forwarded-For believed from IK_FORWARDED_ALLOW_IPS only (service/forwarded.py):
        # uvicorn's default believes any local program's.
        proxy_headers=bool(proxies),
        forwarded_allow_ips=proxies.as_list(),
        ws_max_size=settings.ws_max_message_bytes,
        ws_per_message_deflate=settings.ws_compression,
        ws_ping_interval=settings.ws_ping_interval_s,
        ws_ping_timeout=settings.ws_ping_timeout_s,
        timeout_keep_alive=settings.keep_alive_s,
        timeout_graceful_shutdown=settings.graceful_shutdown_s,
        log_level=settings.log_level,
        log_config=None,
    )
    DrainingServer(config, app).run()


if __name__ == "__main__":
    main()
