"""The HTTP calls, described once: each call's signature and documentation, its method,
path and body, and how to read its answer. ``Client`` and ``AsyncClient`` (client.py)
bind every call to their transport and only send it (httpx's own split: one request
model, two transports)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import httpx

from .encoding import json_body
from .errors import service_error
from .types import (
    BatchEntryResult,
    BatchFrame,
    BoneOutput,
    Chain,
    ClipResult,
    Conventions,
    FkResult,
    Frame,
    FrameResult,
    Pose,
    PoseIn,
    Session,
    SessionInfo,
    SolverOptionsPatch,
    Target,
)

T = TypeVar("T")


class SessionRef(Protocol):
    """What a call on a session needs: a ``Session`` or anything with ``id`` and ``token``."""

    @property
    def id(self) -> str: ...

    @property
    def token(self) -> str: ...


@dataclass(frozen=True, slots=True)
class Call(Generic[T]):
    """One HTTP request and the parser of its successful answer. ``repeatable``: a call
    a client may send again when it got no answer: a read, a pose or options set to given
    values, a stateless solve, a frame with an ``id`` (a server with a shared store
    answers a frame sent again from its stored answer; without one, a frame whose answer
    was lost after it was solved is solved again)."""

    method: str
    path: str
    parse: Callable[[httpx.Response], T]
    json: Any = None
    params: dict[str, str] = field(default_factory=dict)
    headers: dict[str, str] = field(default_factory=dict)
    repeatable: bool = False

    def request(self, http: httpx.Client | httpx.AsyncClient) -> httpx.Request:
        """The request, built by the client that sends it (its base URL and headers).

        Raises:
            EncodeError: The body cannot be written (NaN or infinity, named by field;
                a value JSON cannot hold), as a stream refuses it; nothing is sent.
        """
        if self.json is None:
            return http.build_request(
                self.method, self.path, params=self.params, headers=self.headers
            )
        return http.build_request(
            self.method,
            self.path,
            content=json_body(self.json),
            params=self.params,
            headers={**self.headers, "Content-Type": "application/json"},
        )

    def result(self, response: httpx.Response) -> T:
        raise_for_error(response)
        return self.parse(response)


def raise_for_error(response: httpx.Response) -> None:
    """Raise the ``ServiceError`` subclass of an error answer ``{"detail", "code", "field"}``."""
    if response.is_success:
        return
    try:
        body = response.json()
    except ValueError:
        body = None
    if not isinstance(body, dict):
        body = {"detail": response.text}
    detail = body.get("detail", "")
    # invalid_format's detail is pydantic's list of {loc, msg, type}: the first says most.
    if isinstance(detail, list) and detail and isinstance(detail[0], dict):
        message = str(detail[0].get("msg", ""))
    else:
        message = str(detail)
    retry_after = response.headers.get("Retry-After")
    raise service_error(
        body.get("code", f"http_{response.status_code}"),
        message,
        field=body.get("field"),
        retry_after_s=float(retry_after) if retry_after and retry_after.isdigit() else None,
        status_code=response.status_code,
        detail=detail,
    )


def _results(compact: bool) -> dict[str, str]:
    return {"results": "compact"} if compact else {}


def _without_none(**values: Any) -> dict[str, Any]:
    return {k: v for k, v in values.items() if v is not None}


def _on_session(
    session: SessionRef,
    method: str,
    subpath: str,
    parse: Callable[[httpx.Response], T],
    *,
    json: Any = None,
    params: dict[str, str] | None = None,
    repeatable: bool = False,
) -> Call[T]:
    """A call on ``/v1/sessions/{id}{subpath}``, with the session's token."""
    path = f"/v1/sessions/{session.id}{subpath}"
    headers = {"Authorization": f"Bearer {session.token}"}
    return Call(
        method,
        path,
        parse,
        json=json,
        params=params or {},
        headers=headers,
        repeatable=repeatable,
    )


def _post_frames(
    session: SessionRef,
    body: Any,
    compact: bool,
    parse: Callable[[httpx.Response], T],
    repeatable: bool = False,
) -> Call[T]:
    """``POST /v1/sessions/{id}/frames``: one frame or a clip."""
    return _on_session(
        session,
        "POST",
        "/frames",
        parse,
        json=body,
        params=_results(compact),
        repeatable=repeatable,
    )


def _session_info(response: httpx.Response) -> SessionInfo:
    return SessionInfo.from_json(response.json())


# --- the calls: the clients' methods (listed once in client.py's _BaseClient) --------------
def create_session(
    chain: Chain,
    *,
    options: SolverOptionsPatch | None = None,
    initial_pose: PoseIn | None = None,
    conventions: Conventions | None = None,
    bones: BoneOutput | None = None,
) -> Call[Session]:
    """A new session on ``chain`` (e.g. ``{"format": "example", "name": "panda_arm"}``),
    speaking ``conventions`` (e.g. ``{"preset": "unity"}``), answering with ``bones``."""
    body = _without_none(
        chain=chain,
        options=options,
        initial_pose=initial_pose,
        conventions=conventions,
        bones=bones,
    )
    return Call("POST", "/v1/sessions", lambda r: Session.from_json(r.json()), json=body)


def get_session(session: SessionRef) -> Call[SessionInfo]:
    """The session's chain summary, options, pose and counters."""
    return _on_session(session, "GET", "", _session_info, repeatable=True)


def patch_session(session: SessionRef, options: SolverOptionsPatch) -> Call[SessionInfo]:
    """Change solver options; the options left out keep their value."""
    return _on_session(session, "PATCH", "", _session_info, json=options, repeatable=True)


def set_pose(
    session: SessionRef,
    *,
    q: list[float] | None = None,
    joints: dict[str, float] | None = None,
) -> Call[Pose]:
    """Set the pose the next frame starts from: every DOF (``q``) or some by name."""
    pose = _pose_in(q, joints)
    return _on_session(
        session, "PUT", "/pose", lambda r: Pose.from_json(r.json()), json=pose, repeatable=True
    )


def delete_session(session: SessionRef) -> Call[None]:
    return _on_session(session, "DELETE", "", lambda r: None)


def frame(
    session: SessionRef,
    targets: list[Target],
    *,
    id: int | None = None,
    compact: bool = False,
    bones: BoneOutput | None = None,
    pose: PoseIn | None = None,
) -> Call[FrameResult]:
    """Solve one frame from the session's pose (``compact``: no joints by name and no
    per-effector errors; ``bones``: this frame's bone output, in place of the session's;
    ``pose``: this frame's animated pose, ``{"q": [...]}`` or ``{"joints": {...}}``, to
    start from, as ``set_pose`` then the frame in one step: IK on top of an animation).
    With an ``id`` the client sends the frame again, same id, when it got no answer (a
    failed or dropped connection, a 502 or 503: the client's ``reconnect``); behind a
    balancer with a shared store it is then answered once."""
    body = _without_none(id=id, targets=targets, bones=bones, pose=pose)
    return _post_frames(
        session,
        body,
        compact,
        lambda r: FrameResult.from_json(r.json()["results"][0]),
        repeatable=id is not None,
    )


def clip(
    session: SessionRef,
    frames: list[Frame],
    *,
    plan: bool = False,
    compact: bool = False,
) -> Call[ClipResult]:
    """Solve frames in order, each from the previous answer, or with ``plan`` as a
    whole (the smoothest joint path; the answer's ``plan`` says how smooth)."""
    body = {"frames": frames, "plan": plan}
    return _post_frames(session, body, compact, lambda r: ClipResult.from_json(r.json()))


def batch(frames: list[BatchFrame], *, compact: bool = False) -> Call[list[BatchEntryResult]]:
    """One frame for each of several sessions (a game server's characters) in one
    request; one answer per entry, in order, each a result or its own error (an
    entry's error is not raised: the other entries were solved)."""
    return Call(
        "POST",
        "/v1/batch",
        lambda r: [BatchEntryResult.from_json(e) for e in r.json()["results"]],
        json={"frames": frames},
        params=_results(compact),
    )


def solve(
    chain: Chain,
    targets: list[Target],
    *,
    seed: PoseIn | None = None,
    options: SolverOptionsPatch | None = None,
    id: int | None = None,
    conventions: Conventions | None = None,
    bones: BoneOutput | None = None,
) -> Call[FrameResult]:
    """A stateless one-shot solve (no session), speaking ``conventions`` (targets in,
    bones out), answering with ``bones``."""
    body = _without_none(
        chain=chain,
        targets=targets,
        seed=seed,
        options=options,
        id=id,
        conventions=conventions,
        bones=bones,
    )
    return Call(
        "POST", "/v1/solve", lambda r: FrameResult.from_json(r.json()), json=body, repeatable=True
    )


def fk(
    session: SessionRef,
    *,
    q: list[float] | None = None,
    joints: dict[str, float] | None = None,
    bones: BoneOutput | None = None,
) -> Call[FkResult]:
    """Forward kinematics of any chain: every effector's world pose for a pose (``q``,
    or some DOFs by name in ``joints``; neither: the session's current pose), in the
    session's conventions, and on skeleton chains its bone data (``bones``: what to
    return; the server's default is the local rotations; a chain without bones refuses
    any). The session's pose does not change."""
    body = _without_none(q=q, joints=joints, bones=bones)
    return _on_session(
        session, "POST", "/fk", lambda r: FkResult.from_json(r.json()), json=body, repeatable=True
    )


def _pose_in(q: list[float] | None, joints: dict[str, float] | None) -> PoseIn:
    """``PoseIn`` from exactly one of ``q`` and ``joints`` (the server also checks)."""
    if (q is None) == (joints is None):
        raise ValueError("give exactly one of q and joints")
    return {"q": q} if q is not None else {"joints": joints}  # type: ignore[typeddict-item]


def ws_url(base_url: str, session: SessionRef, compact: bool) -> str:
    """The session's WebSocket URL (``http`` -> ``ws``, ``https`` -> ``wss``)."""
    url = httpx.URL(base_url)
    scheme = "wss" if url.scheme == "https" else "ws"
    ws = url.copy_with(scheme=scheme, path=url.path.rstrip("/") + f"/v1/sessions/{session.id}/ws")
    return str(ws.copy_merge_params(_results(compact)))
