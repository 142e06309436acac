"""The service's error codes and termination codes (generated: do not edit).

Written by ``python -m tests.clients.client_codes`` from ``schemas/errors.py`` and
``solver/optim/termination.py``; tests/clients/test_error_codes_agree.py fails when it
is stale.
"""

from __future__ import annotations

import enum


class ErrorCode(enum.StrEnum):
    """The service's stable error codes (docs/api.md and docs/websocket.md, Errors)."""

    INVALID_FORMAT = "invalid_format"
    """422 / WebSocket error message: the body or message fails the schema, or is not JSON
    (MessagePack); `field` is the first error's location"""
    INVALID_PROBLEM = "invalid_problem"
    """422 / WebSocket error message: valid JSON the chain or solver rejects; `field` names it
    (`chain.joints[1].lower`)"""
    ID_REUSE = "id_reuse"
    """WebSocket error message: the message `id` is not greater than the previous one"""
    UNAUTHORIZED = "unauthorized"
    """401 / close 4401: no session token (or no API key when the server has keys)"""
    FORBIDDEN = "forbidden"
    """403 / close 4403: the token is not this session's, or the API key is unknown"""
    FORBIDDEN_ORIGIN = "forbidden_origin"
    """close 4403: a browser Origin not in IK_CORS_ORIGINS"""
    NOT_FOUND = "not_found"
    """404 / close 4404: no such session (never created, expired or deleted), or no such route"""
    METHOD_NOT_ALLOWED = "method_not_allowed"
    """405: the path has no such method (`Allow` lists them)"""
    HTTP_ERROR = "http_error"
    """any other HTTP error status the framework raises (no route raises one today)"""
    PAYLOAD_TOO_LARGE = "payload_too_large"
    """413 / 431 / close 1009: body over IK_MAX_BODY_BYTES, headers over IK_MAX_HEADER_BYTES or
    IK_MAX_HEADERS, message over IK_WS_MAX_MESSAGE_BYTES"""
    TOO_MANY_SESSIONS = "too_many_sessions"
    """503 + Retry-After: the session cap is reached"""
    KEY_SESSION_LIMIT = "key_session_limit"
    """429: this API key holds IK_MAX_SESSIONS_PER_KEY sessions"""
    RATE_LIMITED = "rate_limited"
    """429 + Retry-After / WebSocket error message: more than IK_MAX_FRAMES_PER_S frames per
    second on this session; or, without API keys, IK_SESSIONS_PER_ADDRESS_PER_MIN sessions
    created from one address"""
    NOT_READY = "not_ready"
    """503 + Retry-After / WebSocket error message: the solver is still warming up"""
    WARMUP_FAILED = "warmup_failed"
    """503 from /readyz: the solver's warm-up failed (the detail says why)"""
    PLANS_BUSY = "plans_busy"
    """503 + Retry-After / WebSocket error message: IK_MAX_QUEUED_PLANS planned clips are already
    queued or running"""
    TOO_MANY_PLANS = "too_many_plans"
    """429 + Retry-After / WebSocket error message: this client holds half of IK_MAX_QUEUED_PLANS"""
    SERVER_BUSY = "server_busy"
    """503 + Retry-After / WebSocket error message: IK_MAX_QUEUED_JOBS jobs of this kind (chain
    builds, one-shot solves or pooled frames) are already queued or running"""
    STORE_UNAVAILABLE = "store_unavailable"
    """503 + Retry-After / WebSocket error message: the shared session store (Redis, IK_REDIS_URL)
    failed the request; send it again (a write that timed out may have been stored: over HTTP a
    frame sent again with its id gets its stored answer; a stream sends its next frame)"""
    TOO_MUCH_WORK = "too_much_work"
    """429 + Retry-After / WebSocket error message: this client (API key, else address) already
    has IK_MAX_CLIENT_WORK_S of pooled solving in flight"""
    TOO_MANY_WEBSOCKETS = "too_many_websockets"
    """close 1013: IK_MAX_WEBSOCKETS are open; retry later"""
    SLOW_READER = "slow_reader"
    """close 1008: the client did not read an answer for IK_WS_SEND_TIMEOUT_S"""
    SHUTTING_DOWN = "shutting_down"
    """503 + Retry-After / WebSocket error message, then close 1012: the server is shutting down
    before it answered; retry, or reconnect"""
    INTERNAL_ERROR = "internal_error"
    """500 / WebSocket error message then close 1011: a bug (logged once with its traceback)"""


class Termination(enum.StrEnum):
    """How the optimizer's last pass ended (docs/api.md, Termination codes)."""

    GOAL_REACHED = "goal_reached"
    """f fell to or below the goal value f_goal"""
    GTOL = "gtol"
    """projected gradient inf-norm fell to or below gtol (a stationary point)"""
    STEP_SMALL = "step_small"
    """the accepted step was below xtol relative to x (no further progress)"""
    STALLED = "stalled"
    """f improved by less than ftol over stall_window consecutive iterations (the multi-pass
    trigger: the analyzer normally resets H and continues)"""
    LINE_SEARCH_FAILED = "line_search_failed"
    """the backtracking line search reached its minimum step length without sufficient decrease"""
    MAX_ITER = "max_iter"
    """the iteration budget (shared by all passes) is spent"""
    MAX_FEV = "max_fev"
    """the function-evaluation budget is spent"""
    DEADLINE = "deadline"
    """the time budget ran out; the best point so far is returned"""
    NONFINITE = "nonfinite"
    """the objective or its gradient returned NaN or infinity"""
