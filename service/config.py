"""Settings from environment variables with the ``IK_`` prefix (pydantic-settings).

Every field is one row of the configuration table in docs/operations.md (a test checks
names and defaults); units are in the names.
"""

from __future__ import annotations

import difflib
import ipaddress
import re
import socket
from collections.abc import Mapping
from functools import lru_cache
from typing import Literal

from pydantic import Field, SecretStr, ValidationError, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from .forwarded import TrustedProxies, trusted_networks
from .redis_url import redis_url_problem

# Digits and dots only: an IPv4 address, in the forms the resolver takes (127.1, 0).
_LOOKS_NUMERIC = re.compile(r"[0-9.]+")


class Settings(BaseSettings):
    """Server configuration; build one per app (tests pass their own)."""

    # hide_input_in_errors: a ValidationError's text never holds a value (IK_REDIS_URL and
    # IK_API_KEYS are secrets); settings_errors shows the others' from errors().
    # env_ignore_empty: a variable set to nothing (compose's `IK_X=` or `IK_X: ""` for
    # "unset") keeps the default, where a number was refused as "not a valid integer"
    # (API keys, CORS and Redis: empty was their default anyway). IK_HOST excepted: an
    # empty one is refused at start (``misspelt_variables``).
    # allow_inf_nan=False: no setting means "no limit" by inf (0 does, where one can), and
    # an operator trial's IK_SESSION_TTL_S=inf started, then answered every new session
    # with a 500 (Redis keys' TTL in ms); inf also turned off IK_REDIS_TIMEOUT_S's bound
    # and IK_REDIS_WRITE_BEHIND_MS's writes, without a word.
    model_config = SettingsConfigDict(
        env_prefix="IK_",
        frozen=True,
        extra="ignore",
        hide_input_in_errors=True,
        env_ignore_empty=True,
        allow_inf_nan=False,
    )

    # Network (used by ``python -m service``).
    host: str = Field(default="127.0.0.1", description="Address to bind")
    port: int = Field(default=8000, ge=0, le=65535, description="Port to bind")
    log_level: Literal["critical", "error", "warning", "info", "debug"] = "info"

    @field_validator("host")
    @classmethod
    def _host_form(cls, value: str) -> str:
        """A value that looks like an address must be one, as the resolver reads it:
        256.1.1.1 would otherwise fail at bind with uvicorn's "Name or service not
        known", which does not name IK_HOST. Host names are left to the resolver."""
        try:
            if _LOOKS_NUMERIC.fullmatch(value):
                socket.inet_aton(value)  # 127.1 and 0 as getaddrinfo takes them
            elif ":" in value:
                ipaddress.ip_address(value)  # IPv6, with a zone id or not
            else:  # a name: as the resolver will encode it (a..b, a label over 63)
                value.encode("idna")
        except (OSError, ValueError):  # UnicodeError is a ValueError
            raise ValueError("not an IP address (127.0.0.1, 0.0.0.0, ::) nor a host name") from None
        return value

    @field_validator("log_level", mode="before")
    @classmethod
    def _any_case(cls, value: object) -> object:
        """IK_LOG_LEVEL=INFO as well as info (Python's logging names are upper case)."""
        return value.lower() if isinstance(value, str) else value

    graceful_shutdown_s: int = Field(
        default=5, ge=0, description="Time in-flight requests get on SIGTERM [s]"
    )

    # What a peer controls (service/peer_limits.py; docs/operations.md "Limits on peers").
    max_header_bytes: int = Field(
        default=32_768, ge=1024, description="Request line and headers [bytes] (431 above)"
    )
    max_headers: int = Field(default=100, ge=1, description="Header fields per request (431)")
    header_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="Time a connection gets to send a request's headers, from connect or "
        "from the previous response; then it is closed [s]",
    )
    body_timeout_s: float = Field(
        default=30.0, gt=0, description="Time a request gets to send its body; then closed [s]"
    )
    keep_alive_s: int = Field(
        default=5, ge=1, description="Idle keep-alive connection closed after [s]"
    )
    max_connections_per_address: int = Field(
        default=256,
        ge=0,
        description="Open connections (HTTP and WebSocket) per client address (the TCP "
        "peer: a proxy in IK_FORWARDED_ALLOW_IPS is not limited); more are closed at once; "
        "0 = no limit",
    )
    sessions_per_address_per_min: float = Field(
        default=60.0,
        ge=0,
        description="Sessions one client address may create per minute when the server has "
        "no API keys (429 rate_limited); 0 = no limit",
    )
    forwarded_allow_ips: str = Field(
        default="",
        description="Comma-separated addresses or networks of reverse proxies whose "
        "X-Forwarded-For names the client (sessions per address, work shares, logs); "
        "empty = no proxy header is believed",
    )

    @field_validator("forwarded_allow_ips")
    @classmethod
    def _forwarded_form(cls, value: str) -> str:
        trusted_networks(value)  # said at start, naming the entry
        return value

    ws_ping_interval_s: float = Field(
        default=20.0, gt=0, description="WebSocket keep-alive ping period [s]"
    )
    ws_ping_timeout_s: float = Field(
        default=20.0, gt=0, description="A WebSocket whose pong is this late is closed [s]"
    )
    ws_max_pings_per_s: int = Field(
        default=50,
        ge=1,
        description="WebSocket ping frames a client may send per second; more drops the connection",
    )
    ws_compression: bool = Field(
        default=True,
        description="Accept permessage-deflate when a WebSocket client offers it (browsers "
        "always do): answers about 4x smaller on the wire for about a third more server CPU "
        "per message (bench/RESULTS.md); false: messages go uncompressed",
    )
    ws_max_write_buffer_bytes: int = Field(
        default=1_048_576,
        ge=65_536,
        description="Unsent bytes a WebSocket may hold when the client sends a ping; more "
        "(a client that pings and never reads) drops it [bytes]",
    )

    # Access control.
    api_keys: SecretStr = Field(
        default=SecretStr(""),
        description="Comma-separated API keys for POST /v1/sessions and /v1/solve "
        "(X-API-Key header); empty = no key needed. Never logged.",
    )
    cors_origins: str = Field(
        default="",
        description="Comma-separated origins allowed by CORS and for browser WebSockets "
        "(Origin header); empty = none (closed)",
    )

    # Sessions.
    # At most a year: Redis refuses a key expiry near 1e300 s ("value is not an integer
    # or out of range"), which every new session then met as a 503 blaming the URL.
    session_ttl_s: float = Field(
        default=300.0, gt=0, le=31_536_000, description="Idle time before expiry [s]"
    )
    max_sessions: int = Field(default=1000, ge=1, description="Session cap (503 when full)")
    max_sessions_per_key: int = Field(
        default=100, ge=1, description="Sessions per API key (429 when reached)"
    )
    sweep_interval_s: float = Field(default=10.0, gt=0, description="Expiry sweep period [s]")
    redis_url: SecretStr = Field(
        default=SecretStr(""),
        description="redis:// URL of a Redis that holds the sessions, shared by every "
        "worker (docs/operations.md, 'Several workers'); empty = sessions in this process's "
        "memory. Never logged (it may hold a password).",
    )

    @field_validator("redis_url")
    @classmethod
    def _redis_url_form(cls, value: SecretStr) -> SecretStr:
        """A URL redis-py can open, checked at start: a typo is a clear configuration
        error naming IK_REDIS_URL, not a traceback from the first connection."""
        url = value.get_secret_value()
        if url and (problem := redis_url_problem(url)) is not None:
            raise ValueError(problem)
        return value

    redis_write_behind_ms: float = Field(
        default=0.0,
        ge=0,
        description="0: each frame's pose and answer are in Redis before the answer is sent "
        "(write-through, grouped); > 0: written behind, every this many ms, one write per "
        "session (less CPU; a worker's death loses at most this long of poses) [ms]",
    )
    redis_timeout_s: float = Field(
        default=0.5,
        gt=0,
        description="Longest wait for Redis on any call; then 503 store_unavailable [s]",
    )

    # Limits.
    max_joints: int = Field(default=256, ge=1, description="Joints per chain")
    max_dof: int = Field(default=256, ge=1, description="Degrees of freedom per chain")
    max_effectors: int = Field(default=32, ge=1, description="Effectors per chain")
    max_urdf_bytes: int = Field(default=2_000_000, ge=1, description="URDF text size [bytes]")
    max_frames_per_request: int = Field(default=600, ge=1, description="Frames in one clip")
    max_body_bytes: int = Field(default=4_194_304, ge=1024, description="HTTP body [bytes]")
    ws_max_message_bytes: int = Field(
        default=1_048_576, ge=1024, description="WebSocket message size [bytes] (close 1009)"
    )
    max_websockets: int = Field(default=1000, ge=1, description="Open WebSockets (close 1013)")
    max_frames_per_s: float = Field(
        default=1000.0,
        ge=0,
        description="Frames per second per session, HTTP and WebSocket together "
        "(token bucket; burst: one second's worth or a full clip); 0 = unlimited",
    )
    ws_send_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="A WebSocket whose client does not read an answer for this long is dropped [s]",
    )
    max_time_budget_us: float = Field(
        default=50_000.0, gt=0, description="Largest per-frame time budget a client may ask [us]"
    )

    # Where solves run (see docs/operations.md: "Inline or off the event loop").
    inline_budget_us: float = Field(
        default=1_000.0,
        ge=0,
        description="Solve inline on the event loop when frames x time_budget_us <= this [us]; "
        "otherwise in the solver thread pool",
    )
    solver_threads: int = Field(
        default=2, ge=1, description="Threads for a session's frames too long to solve inline"
    )
    build_threads: int = Field(
        default=1, ge=1, description="Threads for chain builds (POST /v1/sessions, /v1/solve)"
    )
    oneshot_threads: int = Field(default=1, ge=1, description="Threads for one-shot solves")
    max_queued_jobs: int = Field(
        default=64,
        ge=1,
        description="Jobs of one kind (chain builds, one-shot solves, pooled frames) queued "
        "or running at once; more get 503 server_busy",
    )
    max_request_work_s: float = Field(
        default=2.0,
        gt=0,
        description="Largest worst case of one request, frames x time_budget_us, "
        "solved in order (422 invalid_problem, field frames) [s]",
    )
    max_client_work_s: float = Field(
        default=4.0,
        gt=0,
        description="Worst case of pooled frames one client (API key, else address) may "
        "have queued or running (429 too_much_work) [s]",
    )
    compile_processes: int = Field(
        default=2,
        ge=1,
        le=2,
        description="Processes that compile the solver when its on-disk cache is empty "
        "(first start of a checkout or image): 2 is faster on two or more cores (two "
        "compiles at once peak at ~2.4 GB together), 1 compiles one share at a time",
    )
    max_queued_plans: int = Field(
        default=4,
        ge=1,
        description="Planned clips queued or running at once (one plans at a time); "
        "more get 503 plans_busy; one API key (a session when keys are off) holds at most "
        "half of them, at least 1 (429 too_many_plans)",
    )

    # Default solver options (a session or request may override each).
    default_time_budget_us: float = Field(default=1_000.0, gt=0, description="[us] per frame")
    default_position_tolerance_m: float = Field(default=1e-4, gt=0, description="[m]")
    default_rotation_tolerance_rad: float = Field(default=1e-3, gt=0, description="[rad]")
    default_max_iter: int = Field(default=1000, ge=1, description="Iterations per frame")
    # None: the solver's own defaults, 126 for one-shot solves (enough that the time
    # budget, not the count, ends a solve that keeps missing: solver.ik.IKOptions) and
    # 50 for a session's frames (local restarts near the previous pose: STREAM_DEFAULTS).
    default_max_restarts: int | None = Field(
        default=None,
        ge=0,
        description="Restarts per frame; unset: 126 for one-shot solves, 50 for sessions",
    )

    def api_key_list(self) -> tuple[bytes, ...]:
        """The configured API keys (UTF-8), empty when keys are off."""
        raw = self.api_keys.get_secret_value()
        return tuple(k.strip().encode() for k in raw.split(",") if k.strip())

    def trusted_proxies(self) -> TrustedProxies:
        return TrustedProxies(trusted_networks(self.forwarded_allow_ips))

    def cors_origin_list(self) -> list[str]:
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]


@lru_cache
def usage() -> str:
    """``python -m service --help``: the service takes no arguments, only IK_*
    variables; each with its default and description."""
    lines = [
        "usage: [IK_VARIABLE=value ...] python -m service",
        "",
        "The IK service (uvicorn) on IK_HOST:IK_PORT. It takes no arguments: it is",
        "configured with these environment variables (docs/operations.md says more):",
        "",
    ]
    for name, f in Settings.model_fields.items():
        default = f.default
        shown = "empty" if default in ("", None) or default == SecretStr("") else default
        lines.append(f"  IK_{name.upper()} (default {shown})")
        if f.description:
            lines.append(f"      {f.description}")
    return "\n".join(lines)


def get_settings() -> Settings:
    """The process's settings, read from the environment once."""
    return Settings()


ENV_PREFIX = "IK_"


# An unknown IK_ variable this close to a setting's name (difflib's ratio) that is not
# set itself is a typo: IK_REDIS_UR (0.96), IK_PORTS (0.93), IK_API_KEY (0.95),
# IK_LOGLEVEL (0.96). IK_LB_BIND (HAProxy's, docs/operations.md) is nothing like one.
TYPO_RATIO = 0.85


def _closest(key: str, known: list[str], cutoff: float) -> str | None:
    close = difflib.get_close_matches(key, known, n=1, cutoff=cutoff)
    return close[0] if close else None


def misspelt_variables(environ: Mapping[str, str]) -> dict[str, str]:
    """The ``IK_`` variables the service refuses to start with, each with its reason:
    one that no setting reads but one nearly does, when that setting is not set
    itself; and any other ``IK_REDIS_*`` while IK_REDIS_URL is not set.

    pydantic-settings ignores unknown variables (``extra="ignore"``: the environment
    holds other programs' variables too), so a misspelt ``IK_REDIS_UR``, or an
    ``IK_REDIS_HOST`` meant to configure Redis, would start a worker with its sessions
    in memory behind a balancer that expects Redis: it passes /readyz, takes traffic,
    and its sessions are 404 on every other worker.
    """
    known = [ENV_PREFIX + name.upper() for name in Settings.model_fields]
    redis_url = ENV_PREFIX + "REDIS_URL"
    out = {}
    for key in sorted(environ):
        if not key.startswith(ENV_PREFIX) or key in known:
            continue
        meant = _closest(key, known, TYPO_RATIO)
        if meant is not None and not environ.get(meant):  # empty: as good as unset
            out[key] = f"{key} is not a setting of this service: did you mean {meant}?"
        elif key.startswith(ENV_PREFIX + "REDIS_") and not environ.get(redis_url):
            out[key] = (
                f"{key} is not a setting of this service: sessions in Redis are set with "
                f"{redis_url} alone (redis://[:password@]host:port/db)"
            )
    host = ENV_PREFIX + "HOST"
    if environ.get(host) == "":
        # Every other empty variable keeps its default (env_ignore_empty); an empty host
        # bound every interface before that, and the default (127.0.0.1) would now
        # hide a container from its network: say which, do not guess.
        out[host] = (
            f"{host} is empty: give the address to bind (0.0.0.0: every interface, as the "
            "image's default; 127.0.0.1: this machine only)"
        )
    return out


def service_link_hint(environ: Mapping[str, str]) -> str | None:
    """Why a pod's environment holds ``IK_*=tcp://...``: Kubernetes' service links (a
    Service named ``ik`` gives IK_PORT, ``ik-redis`` IK_REDIS_PORT, ...), said beside
    the start's refusal, which names only the variable."""
    if "KUBERNETES_SERVICE_HOST" not in environ:
        return None
    linked = sorted(
        k for k, v in environ.items() if k.startswith(ENV_PREFIX) and v.startswith("tcp://")
    )
    if not linked:
        return None
    return (
        f"{', '.join(linked)} come from Kubernetes' service links (a Service whose name "
        "starts with ik): set enableServiceLinks: false in the pod spec, as "
        "deploy/k8s/ik.yaml does"
    )


def unknown_variables(environ: Mapping[str, str]) -> list[str]:
    """A warning for each other ``IK_`` variable that no setting reads (those that
    ``misspelt_variables`` refuses excepted), with the closest name if any."""
    known = [ENV_PREFIX + name.upper() for name in Settings.model_fields]
    refused = misspelt_variables(environ)
    out = []
    for key in sorted(environ):
        if key.startswith(ENV_PREFIX) and key not in known and key not in refused:
            meant = _closest(key, known, 0.6)
            guess = f" (did you mean {meant}?)" if meant else ""
            out.append(f"{key} is not a setting of this service and is ignored{guess}")
    return out


# Settings whose value is never echoed in an error (passwords, keys).
_SECRET_FIELDS = frozenset(
    name for name, field in Settings.model_fields.items() if field.annotation is SecretStr
)


def settings_errors(exc: ValidationError) -> str:
    """A bad setting's error in the environment's words: ``IK_MAX_SESSIONS: Input
    should be a valid integer, got 'abc'`` rather than pydantic's field names. A
    secret's value is not shown."""
    lines = []
    for e in exc.errors():
        loc = e.get("loc") or ()
        name = ENV_PREFIX + str(loc[0]).upper() if loc else "settings"
        got = e.get("input")
        secret = bool(loc) and loc[0] in _SECRET_FIELDS
        shown = f", got {got!r}" if isinstance(got, str | int | float) and not secret else ""
        lines.append(f"{name}: {e.get('msg', 'invalid')}{shown}")
    return "invalid configuration:\n  " + "\n  ".join(lines)
