"""Every error code the service sends: HTTP bodies' ``code``, WebSocket error messages'
``error.code`` and WebSocket close reasons (Home Assistant's ``const.py`` ERR_* style).

The string values are the stable contract; ``ERROR_CODE_DESCRIPTIONS`` says when each
is sent and feeds the OpenAPI schema. docs/api.md lists exactly these codes
(tests/service/test_error_codes.py checks it).
"""

from __future__ import annotations

import enum

from pydantic import GetJsonSchemaHandler
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema


class ErrorCode(enum.StrEnum):
    """A stable error code; the HTTP status and WebSocket behaviour are in the
    descriptions (and in the table of service/errors.py)."""

    INVALID_FORMAT = "invalid_format"
    INVALID_PROBLEM = "invalid_problem"
    ID_REUSE = "id_reuse"
    UNAUTHORIZED = "unauthorized"
    FORBIDDEN = "forbidden"
    FORBIDDEN_ORIGIN = "forbidden_origin"
    NOT_FOUND = "not_found"
    METHOD_NOT_ALLOWED = "method_not_allowed"
    HTTP_ERROR = "http_error"
    PAYLOAD_TOO_LARGE = "payload_too_large"
    TOO_MANY_SESSIONS = "too_many_sessions"
    KEY_SESSION_LIMIT = "key_session_limit"
    RATE_LIMITED = "rate_limited"
    NOT_READY = "not_ready"
    WARMUP_FAILED = "warmup_failed"
    PLANS_BUSY = "plans_busy"
    TOO_MANY_PLANS = "too_many_plans"
    SERVER_BUSY = "server_busy"
    STORE_UNAVAILABLE = "store_unavailable"
    TOO_MUCH_WORK = "too_much_work"
    TOO_MANY_WEBSOCKETS = "too_many_websockets"
    SLOW_READER = "slow_reader"
    SHUTTING_DOWN = "shutting_down"
    INTERNAL_ERROR = "internal_error"

    @classmethod
    def __get_pydantic_json_schema__(
        cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        """The enum's schema with a description per code: as a list in the description
        (Swagger UI shows it) and as ``x-enumDescriptions`` (Redoc, openapi-generator)."""
        json_schema = handler(core_schema)
        target = handler.resolve_ref_schema(json_schema)
        codes = ERROR_CODE_DESCRIPTIONS.items()
        target["description"] = "A stable error code:\n\n" + "\n".join(
            f"- `{code.value}`: {text}" for code, text in codes
        )
        target["x-enumDescriptions"] = {code.value: text for code, text in codes}
        return json_schema


ERROR_CODE_DESCRIPTIONS: dict[ErrorCode, str] = {
    ErrorCode.INVALID_FORMAT: "422 / WebSocket error message: the body or message fails the "
    "schema, or is not JSON (MessagePack); `field` is the first error's location",
    ErrorCode.INVALID_PROBLEM: "422 / WebSocket error message: valid JSON the chain or solver "
    "rejects; `field` names it (`chain.joints[1].lower`)",
    ErrorCode.ID_REUSE: "WebSocket error message: the message `id` is not greater than the "
    "previous one",
    ErrorCode.UNAUTHORIZED: "401 / close 4401: no session token (or no API key when the "
    "server has keys)",
    ErrorCode.FORBIDDEN: "403 / close 4403: the token is not this session's, or the API key "
    "is unknown",
    ErrorCode.FORBIDDEN_ORIGIN: "close 4403: a browser Origin not in IK_CORS_ORIGINS",
    ErrorCode.NOT_FOUND: "404 / close 4404: no such session (never created, expired or "
    "deleted), or no such route",
    ErrorCode.METHOD_NOT_ALLOWED: "405: the path has no such method (`Allow` lists them)",
    ErrorCode.HTTP_ERROR: "any other HTTP error status the framework raises (no route "
    "raises one today)",
    ErrorCode.PAYLOAD_TOO_LARGE: "413 / 431 / close 1009: body over IK_MAX_BODY_BYTES, "
    "headers over IK_MAX_HEADER_BYTES or IK_MAX_HEADERS, message over "
    "IK_WS_MAX_MESSAGE_BYTES",
    ErrorCode.TOO_MANY_SESSIONS: "503 + Retry-After: the session cap is reached",
    ErrorCode.KEY_SESSION_LIMIT: "429: this API key holds IK_MAX_SESSIONS_PER_KEY sessions",
    ErrorCode.RATE_LIMITED: "429 + Retry-After / WebSocket error message: more than "
    "IK_MAX_FRAMES_PER_S frames per second on this session; or, without API keys, "
    "IK_SESSIONS_PER_ADDRESS_PER_MIN sessions created from one address",
    ErrorCode.NOT_READY: "503 + Retry-After / WebSocket error message: the solver is still "
    "warming up",
    ErrorCode.WARMUP_FAILED: "503 from /readyz: the solver's warm-up failed (the detail says why)",
    ErrorCode.PLANS_BUSY: "503 + Retry-After / WebSocket error message: IK_MAX_QUEUED_PLANS "
    "planned clips are already queued or running",
    ErrorCode.TOO_MANY_PLANS: "429 + Retry-After / WebSocket error message: this client holds "
    "half of IK_MAX_QUEUED_PLANS",
    ErrorCode.SERVER_BUSY: "503 + Retry-After / WebSocket error message: IK_MAX_QUEUED_JOBS "
    "jobs of this kind (chain builds, one-shot solves or pooled frames) are already queued "
    "or running",
    ErrorCode.STORE_UNAVAILABLE: "503 + Retry-After / WebSocket error message: the shared "
    "session store (Redis, IK_REDIS_URL) failed the request; send it again (a write that timed "
    "out may have been stored: over HTTP a frame sent again with its id gets its stored answer; "
    "a stream sends its next frame)",
    ErrorCode.TOO_MUCH_WORK: "429 + Retry-After / WebSocket error message: this client "
    "(API key, else address) already has IK_MAX_CLIENT_WORK_S of pooled solving in flight",
    ErrorCode.TOO_MANY_WEBSOCKETS: "close 1013: IK_MAX_WEBSOCKETS are open; retry later",
    ErrorCode.SLOW_READER: "close 1008: the client did not read an answer for IK_WS_SEND_TIMEOUT_S",
    ErrorCode.SHUTTING_DOWN: "503 + Retry-After / WebSocket error message, then close 1012: "
    "the server is shutting down before it answered; retry, or reconnect",
    ErrorCode.INTERNAL_ERROR: "500 / WebSocket error message then close 1011: a bug (logged "
    "once with its traceback)",
}
