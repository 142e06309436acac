"""``python -m service``: uvicorn serving ``create_app`` on IK_HOST:IK_PORT."""

from __future__ import annotations

import os

# Before numpy is imported: one BLAS thread (solves are tiny; threads only contend).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import asyncio  # noqa: E402
import contextlib  # noqa: E402
import logging  # noqa: E402
import logging.config  # noqa: E402
import socket  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
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
from .listen_check import listen_problem  # noqa: E402
from .log_format import log_config  # noqa: E402
from .main import create_app  # noqa: E402
from .peer_limits import PeerLimits, protocols  # noqa: E402


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
    # Before the app starts (and a first start compiles): a port in use or a host name
    # that does not resolve, said naming the variable (service/listen_check.py).
    if (problem := listen_problem(settings.host, settings.port)) is not None:
        raise SystemExit("cannot start: " + problem)
    logging.config.dictConfig(log_config(settings.log_level))
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
        log_config=None,  # applied above, before the first line (once: see log_config)
    )
    DrainingServer(config, app).run()


if __name__ == "__main__":
    main()
