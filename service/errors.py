"""Service errors with stable codes, their HTTP mapping and the WebSocket close codes.

Codes owned here (HTTP status / WebSocket behaviour):

==================== ====== =====================================================
code                 HTTP   WebSocket
==================== ====== =====================================================
invalid_format       422    error message, socket stays open
invalid_problem      422    error message, socket stays open
id_reuse             --     error message (id not greater than the previous one)
unauthorized         401    close 4401 (no token)
forbidden            403    close 4403 (wrong token)
forbidden_origin     --     close 4403 (a browser Origin not in IK_CORS_ORIGINS)
not_found            404    close 4404 (no such session, or it expired / was deleted)
method_not_allowed   405    --
http_error           other  -- (any other status the framework raises; none today)
payload_too_large    413    close 1009 (message larger than IK_WS_MAX_MESSAGE_BYTES); 431 headers
too_many_sessions    503    -- (+ Retry-After)
key_session_limit    429    --
rate_limited         429    error message (+ Retry-After / retry_after_s)
not_ready            503    error message (solver still warming up) (+ Retry-After)
warmup_failed        503    -- (/readyz only)
plans_busy           503    error message (IK_MAX_QUEUED_PLANS planned clips already queued)
too_many_plans       429    error message (this client holds half of IK_MAX_QUEUED_PLANS)
server_busy          503    error message (IK_MAX_QUEUED_JOBS of one kind of work queued)
store_unavailable    503    error message, close 1013 at connect (Redis does not answer)
too_much_work        429    error message (this client's IK_MAX_CLIENT_WORK_S in flight)
too_many_websockets  --     close 1013 (try again later)
slow_reader          --     close 1008 (the client stopped reading its answers)
shutting_down        503    error message, then close 1012 (the server is shutting down)
internal_error       500    error message, then close 1011
==================== ====== =====================================================

The codes are ``schemas.ErrorCode`` (tests/service/test_error_codes.py keeps this table,
the enum and docs/api.md in step).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from starlette import status
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.responses import Response
from starlette.routing import compile_path

from schemas import ErrorCode
from schemas.chain import CHAIN_FORMATS
from schemas.solve import MAX_FRAME_ID
from solver.errors import IKError

from .hints import JSON_INVALID, hint
from .responses import ORJSONResponse

log = logging.getLogger("service")

# Application close codes mirror the HTTP statuses (4000-4999 is the private range).
WS_UNAUTHORIZED = 4401
WS_FORBIDDEN = 4403
WS_NOT_FOUND = 4404
WS_CLOSE_CODES: dict[int, str] = {
    status.WS_1000_NORMAL_CLOSURE: "normal closure",
    status.WS_1008_POLICY_VIOLATION: (
        "the client did not read its answers (IK_WS_SEND_TIMEOUT_S), or a results query "
        "value other than full or compact (at connect)"
    ),
    status.WS_1009_MESSAGE_TOO_BIG: "message larger than IK_WS_MAX_MESSAGE_BYTES",
    status.WS_1011_INTERNAL_ERROR: "unexpected server error (logged)",
    status.WS_1012_SERVICE_RESTART: "the server is shutting down; reconnect",
    status.WS_1013_TRY_AGAIN_LATER: (
        "too many open WebSockets, or the session store (Redis) did not answer at connect; "
        "retry later"
    ),
    WS_UNAUTHORIZED: "no token (Authorization: Bearer or ?token=)",
    WS_FORBIDDEN: "wrong token for this session",
    WS_NOT_FOUND: "no such session (never existed, expired or deleted)",
}


# An error echoes what the client sent (a joint name, a key, a field path): bounded, so
# that a 1 MB key costs a 1 MB request, not also a 1 MB answer and a 1 MB log line.
MAX_DETAIL_CHARS = 2000
MAX_FIELD_CHARS = 500
MAX_LOC_PART_CHARS = 200
# A 422 lists at most this many validation errors (pydantic reports each of 20,000
# unknown keys: a 250 KB body answered 2.9 MB); the last entry says how many are left.
MAX_LISTED_ERRORS = 50


def clip(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters, saying how many were cut."""
    if len(text) <= limit:
        return text
    cut = len(text) - limit
    return f"{text[:limit]}... ({cut} more characters)"


class ServiceError(Exception):
    """An error a client caused or must handle; carries its stable code.

    Args:
        code: Stable error code.
        detail: Human-readable message.
        status_code: HTTP status.
        field: Path of the offending field, if any (``frame.targets[0].position.x``).
        retry_after_s: Adds ``Retry-After`` (seconds, rounded up).
    """

    def __init__(
        self,
        code: ErrorCode,
        detail: str,
        *,
        status_code: int,
        field: str | None = None,
        retry_after_s: float | None = None,
    ) -> None:
        detail = clip(detail, MAX_DETAIL_CHARS)
        super().__init__(detail)
        self.code = code
        self.detail = detail
        self.status_code = status_code
        self.field = None if field is None else clip(field, MAX_FIELD_CHARS)
        self.retry_after_s = retry_after_s

    def body(self) -> dict[str, Any]:
        out: dict[str, Any] = {"detail": self.detail, "code": self.code.value}
        if self.field is not None:
            out["field"] = self.field
        return out

    def headers(self) -> dict[str, str]:
        h: dict[str, str] = {}
        if self.retry_after_s is not None:
            h["Retry-After"] = str(max(1, math.ceil(self.retry_after_s)))
        if self.status_code == status.HTTP_401_UNAUTHORIZED:
            h["WWW-Authenticate"] = "Bearer"
        return h


def invalid_problem(detail: str, field: str | None) -> ServiceError:
    where = f"{field}: " if field and not detail.startswith(field) else ""
    return ServiceError(
        ErrorCode.INVALID_PROBLEM,
        f"{where}{detail}",
        status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
        field=field,
    )


def not_found(detail: str = "no such session") -> ServiceError:
    return ServiceError(ErrorCode.NOT_FOUND, detail, status_code=status.HTTP_404_NOT_FOUND)


def not_ready() -> ServiceError:
    return ServiceError(
        ErrorCode.NOT_READY,
        "the solver is still warming up (see /readyz)",
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        retry_after_s=1.0,
    )


def too_many_plans(limit: int) -> ServiceError:
    return ServiceError(
        ErrorCode.TOO_MANY_PLANS,
        f"this client already has {limit} planned clip(s) queued or running (half of "
        "IK_MAX_QUEUED_PLANS, per API key, or per session when the server has no keys)",
        status_code=status.HTTP_429_TOO_MANY_REQUESTS,
        retry_after_s=1.0,
    )


def store_unavailable(retry_after_s: float = 1.0, *, detail: str | None = None) -> ServiceError:
    """Redis failed a call; ``detail`` replaces the clients' words (``/readyz`` says the
    operator's cause there). Not "nothing was stored": a write that timed out may still
    be applied by a Redis that was only slow (an operator trial: SIGSTOP for 1.2 s)."""
    return ServiceError(
        ErrorCode.STORE_UNAVAILABLE,
        detail
        or "the session store (Redis) failed the request (no answer in time, or a "
        "refusal): send it again after Retry-After; over HTTP a frame sent again with its "
        "id gets its stored answer if Redis stored it after all (a stream sends its next "
        "frame instead)",
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        retry_after_s=retry_after_s,
    )


def plans_busy(limit: int) -> ServiceError:
    return ServiceError(
        ErrorCode.PLANS_BUSY,
        f"{limit} planned clips are already queued or running (IK_MAX_QUEUED_PLANS)",
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        retry_after_s=1.0,
    )


def validation_errors(errors: Any) -> list[dict[str, Any]]:
    """pydantic errors without the echoed input (it can be a whole URDF) or URLs; the
    message says the expected form where service.hints knows it. At most
    ``MAX_LISTED_ERRORS``, then one entry counting the rest."""
    errors = list(errors)
    out = []
    for e in errors[:MAX_LISTED_ERRORS]:
        msg = hint(e) or str(e.get("msg", ""))
        loc = [
            p if isinstance(p, int) else clip(str(p), MAX_LOC_PART_CHARS) for p in e.get("loc", ())
        ]
        out.append({"loc": loc, "msg": clip(msg, MAX_DETAIL_CHARS), "type": e.get("type", "")})
    if len(errors) > MAX_LISTED_ERRORS:
        left = len(errors) - MAX_LISTED_ERRORS
        msg = f"{left} more errors not listed (the first {MAX_LISTED_ERRORS} are above)"
        out.append({"loc": [], "msg": msg, "type": "too_many_errors"})
    return out


def echoable_id(value: Any) -> int | None:
    """A frame or message id as sent, if an error may echo it: an int (not a bool) in
    the schema's range. Read leniently (the stdlib's json, a NaN beside it) an id can be
    any integer, and one over 64 bits cannot be written by orjson (a 500, a 1011)."""
    return value if type(value) is int and 0 <= value <= MAX_FRAME_ID else None


def most_helpful(errors: Any) -> dict[str, Any]:
    """The one error of a WebSocket message or a batch entry (an HTTP 422 lists them
    all), as ``validation_errors`` renders it: the first that service.hints has a
    better message for (a field name one typo away, an array where an object belongs),
    else the first. A misspelt ``target`` then says "did you mean 'targets'?" where the
    first error would only say that ``targets`` is missing."""
    errors = list(errors)
    if not errors:
        return {"loc": [], "msg": "invalid message", "type": ""}
    chosen = next((e for e in errors if hint(e) is not None), errors[0])
    return validation_errors([chosen])[0]


def field_path(loc: Sequence[Any]) -> str | None:
    """The path of a validation error's ``loc`` as every error names a field: object
    keys dotted, list indices in brackets (``frame.targets[0].orientation``, as the
    chain's and the solver's errors write ``frames[3].targets[0].effector``), without
    FastAPI's leading ``body`` and without the chain's ``format`` that pydantic puts
    after ``chain`` (``chain.unit_m``, not ``chain.bvh.unit_m``: ``chain.bvh`` is the
    BVH text). A map key that looks like a number (a joint named "0") stays dotted:
    pydantic gives it as a string, an index as an int."""
    parts = list(loc[1:] if loc and loc[0] == "body" else loc)
    if len(parts) > 1 and parts[0] == "chain" and parts[1] in CHAIN_FORMATS:
        del parts[1]  # only there: a bone may be named "chain", a key "urdf"
    path = ""
    for part in parts:
        if type(part) is int:
            path += f"[{part}]"
        else:
            path += f".{part}" if path else str(part)
    return path or None


def _field_of(error: Mapping[str, Any]) -> str | None:
    """The field a validation error names: the whole ``body`` when it is not JSON at
    all (its ``loc`` then ends in a character offset, not a field)."""
    if error.get("type") == JSON_INVALID:
        return "body"
    loc = error["loc"]
    # The body as a whole (an array where an object belongs): named as unreadable JSON is.
    return field_path(loc) or ("body" if list(loc) == ["body"] else None)


_HTTP_CODES = {
    status.HTTP_404_NOT_FOUND: ErrorCode.NOT_FOUND,
    status.HTTP_405_METHOD_NOT_ALLOWED: ErrorCode.METHOD_NOT_ALLOWED,
    status.HTTP_413_CONTENT_TOO_LARGE: ErrorCode.PAYLOAD_TOO_LARGE,
}


def _count(request: Request, code: ErrorCode) -> None:
    """Count an HTTP error answer in ``ik_errors_total`` (transport ``http``), as the
    WebSocket's errors and batch entries are counted where they are answered. Read
    from the app's state: this module sits below the one that defines it."""
    services = getattr(request.app.state, "ik", None)
    if services is not None:
        services.metrics.error(code, "http")


async def _service_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, ServiceError)
    _count(request, exc.code)
    return ORJSONResponse(exc.body(), status_code=exc.status_code, headers=exc.headers())


async def _validation_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, RequestValidationError)
    _count(request, ErrorCode.INVALID_FORMAT)
    detail = validation_errors(exc.errors())
    body: dict[str, Any] = {"detail": detail, "code": ErrorCode.INVALID_FORMAT}
    if detail and (field := _field_of(detail[0])) is not None:
        body["field"] = field  # the first error's, as the WebSocket's error names it
    return ORJSONResponse(body, status_code=status.HTTP_422_UNPROCESSABLE_CONTENT)


def solver_error(exc: IKError) -> ServiceError:
    """A solver error that got past convert.py (which names the field first), as the
    ``invalid_problem`` it is: the safety net of HTTP and WebSocket alike."""
    return invalid_problem(str(exc), getattr(exc, "field", None))


async def _solver_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, IKError)
    err = solver_error(exc)
    _count(request, err.code)
    return ORJSONResponse(err.body(), status_code=err.status_code)


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, StarletteHTTPException)
    if exc.status_code == status.HTTP_400_BAD_REQUEST:
        # FastAPI answers 400 when the body cannot be decoded at all (invalid UTF-8,
        # nesting deeper than the parser's recursion limit, an integer literal of
        # thousands of digits); to a client that is the same as malformed JSON.
        # FastAPI's own text ("There was an error parsing the body") says neither.
        _count(request, ErrorCode.INVALID_FORMAT)
        msg = (
            "the body cannot be read as JSON: not UTF-8, nested deeper than the parser "
            "allows, or a number literal too long to read"
        )
        return ORJSONResponse(
            {
                "detail": [{"loc": ["body"], "msg": msg, "type": "json_invalid"}],
                "code": ErrorCode.INVALID_FORMAT,
                "field": "body",
            },
            status_code=status.HTTP_422_UNPROCESSABLE_CONTENT,
        )
    code = _HTTP_CODES.get(exc.status_code, ErrorCode.HTTP_ERROR)
    _count(request, code)
    headers = dict(exc.headers or {})
    if exc.status_code == status.HTTP_405_METHOD_NOT_ALLOWED:
        headers["Allow"] = _allowed_methods(request)
    return ORJSONResponse(
        {"detail": exc.detail, "code": code}, status_code=exc.status_code, headers=headers
    )


def _allowed_methods(request: Request) -> str:
    """Every method of every route on this path (found by schemathesis: starlette's
    405 names only the first route's methods, here GET of GET/PATCH/DELETE). Read
    from the app's own OpenAPI paths, compiled once."""
    table = getattr(request.app.state, "allow_table", None)
    if table is None:
        table = [
            (compile_path(path)[0], {m.upper() for m in ops if m.upper() in _METHODS})
            for path, ops in request.app.openapi().get("paths", {}).items()
        ]
        request.app.state.allow_table = table
    methods: set[str] = set()
    for regex, ms in table:
        if regex.match(request.url.path):
            methods |= ms
    if "GET" in methods:
        methods.add("HEAD")
    return ", ".join(sorted(methods))


_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"})


async def _internal_error(request: Request, exc: Exception) -> Response:
    # Starlette's ServerErrorMiddleware logs the traceback once and re-raises.
    _count(request, ErrorCode.INTERNAL_ERROR)
    return ORJSONResponse(
        {"detail": "internal server error", "code": ErrorCode.INTERNAL_ERROR},
        status_code=status.HTTP_500_INTERNAL_SERVER_ERROR,
    )


def install_handlers(app: FastAPI) -> None:
    """The one central mapper from exceptions to ``{"detail", "code"}`` bodies."""
    app.add_exception_handler(ServiceError, _service_error)
    app.add_exception_handler(RequestValidationError, _validation_error)
    app.add_exception_handler(IKError, _solver_error)
    app.add_exception_handler(StarletteHTTPException, _http_error)
    app.add_exception_handler(Exception, _internal_error)
