"""/v1 HTTP resources: sessions, their frames, pose and options, and one-shot solves.

Codes: 201/200/204 on success; 401 unauthorized, 403 forbidden, 404 not_found,
413 payload_too_large, 422 invalid_format / invalid_problem, 429 rate_limited /
too_many_plans (+ Retry-After), 503 too_many_sessions / plans_busy / not_ready
(+ Retry-After).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import APIRouter, Body, Query, Request, Response
from starlette import status

import schemas as S
from schemas import ErrorCode
from schemas.chain import EXAMPLE_ARM, EXAMPLE_BVH_LEG, EXAMPLE_GLTF_LEG

from .. import batch, convert
from ..dependencies import OwnerDep, ServicesDep, SessionDep
from ..errors import ServiceError, not_found
from ..middleware import received_at
from ..responses import ORJSONResponse
from ..session_tokens import SessionTokens
from ..sessions import (
    OwnerFull,
    Session,
    SessionStore,
    StoreFull,
    chain_definition,
    new_session,
)
from ..solving import make_solver, session_client, solve_once
from ..work import WorkClass

router = APIRouter(prefix="/v1")

_E = {"model": S.ErrorBody}
_AUTH_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {**_E, "description": "No token (`unauthorized`)"},
    403: {**_E, "description": "Wrong token (`forbidden`)"},
    404: {**_E, "description": "No such session, or it expired (`not_found`)"},
}
_422: dict[int | str, dict[str, Any]] = {
    422: {**_E, "description": "`invalid_format` (schema) or `invalid_problem` (field named)"}
}
_503: dict[int | str, dict[str, Any]] = {
    503: {
        **_E,
        "description": "`not_ready` (warming up), `too_many_sessions` or, for a planned "
        "clip, `plans_busy`; see Retry-After",
    }
}
_KEY_ERRORS: dict[int | str, dict[str, Any]] = {
    401: {**_E, "description": "No API key while the server requires one (`unauthorized`)"},
    403: {**_E, "description": "Unknown API key (`forbidden`)"},
}
_429_KEY: dict[int | str, dict[str, Any]] = {
    429: {
        **_E,
        "description": "This API key holds its maximum of sessions (`key_session_limit`), "
        "or, without API keys, this address created IK_SESSIONS_PER_ADDRESS_PER_MIN in "
        "the last minute (`rate_limited`, Retry-After)",
    }
}
_429_RATE: dict[int | str, dict[str, Any]] = {
    429: {
        **_E,
        "description": "Over IK_MAX_FRAMES_PER_S for this session (`rate_limited`), or a "
        "planned clip while this client holds its share of the plan queue "
        "(`too_many_plans`); Retry-After says when to try again",
    }
}
_413: dict[int | str, dict[str, Any]] = {
    413: {**_E, "description": "Body over IK_MAX_BODY_BYTES (`payload_too_large`)"}
}

_CREATE_EXAMPLES = {
    "hierarchy": {
        "summary": "A 3-DOF arm given as joints (position effector 'hand')",
        "value": {"chain": EXAMPLE_ARM, "options": {"time_budget_us": 1000}},
    },
    "example": {
        "summary": "The built-in Franka Panda example (pose effector 'tool')",
        "value": {"chain": {"format": "example", "name": "panda_arm"}},
    },
    "urdf": {
        "summary": "URDF text with base and tip links",
        "value": {
            "chain": {
                "format": "urdf",
                "urdf": (
                    '<robot name="r"><link name="base"/><link name="l1"/><link name="tip"/>'
                    '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
                    '<axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/>'
                    '</joint><joint name="j2" type="revolute"><parent link="l1"/>'
                    '<child link="tip"/><origin xyz="0.5 0 0"/><axis xyz="0 0 1"/>'
                    '<limit lower="-3" upper="3" effort="1" velocity="1"/></joint></robot>'
                ),
                "base_link": "base",
                "tip_links": ["tip"],
                "mode": "position",
            }
        },
    },
}
_CREATE_EXAMPLES["gltf"] = {
    "summary": "A glTF skin (the .gltf JSON) for a Unity client, with bone rotations",
    "value": {
        "chain": EXAMPLE_GLTF_LEG,
        "conventions": {"preset": "unity"},
        "bones": {"local_rotations": True, "world": ["ankle"]},
    },
}
_CREATE_EXAMPLES["bvh"] = {
    "summary": "A BVH skeleton in centimetres for an Unreal client",
    "value": {"chain": EXAMPLE_BVH_LEG, "conventions": {"preset": "unreal"}},
}
_FRAMES_EXAMPLES = {
    "frame": {
        "summary": "One frame (for the 3-DOF arm example)",
        "value": {
            "id": 1,
            "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
        },
    },
    "clip": {
        "summary": "A clip: frames solved in order, each from the previous answer",
        "value": {
            "frames": [
                {
                    "id": 1,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
                },
                {
                    "id": 2,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.12, "z": 0.59}}],
                },
                {
                    "id": 3,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.14, "z": 0.58}}],
                },
            ]
        },
    },
    "planned clip": {
        "summary": "A clip solved as a whole: the smoothest joint path through all frames",
        "value": {
            "plan": True,
            "frames": [
                {
                    "id": 1,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
                },
                {
                    "id": 2,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.12, "z": 0.59}}],
                },
            ],
        },
    },
    "panda": {
        "summary": "One pose frame for the panda_arm example (effector 'tool')",
        "value": {
            "id": 7,
            "targets": [
                {
                    "effector": "tool",
                    "position": {"x": 0.4, "y": 0.1, "z": 0.5},
                    "orientation": {"w": 0.0, "x": 1.0, "y": 0.0, "z": 0.0},
                }
            ],
        },
    },
}


def _session_info(session: Session, store: SessionStore) -> dict[str, Any]:
    view = session.view
    return {
        "id": session.id,
        **view.summary,
        "options": convert.options_dict(session.options),
        "pose": convert.pose_dict(view, session.solver.q),
        "counters": {
            "frames": session.frames,
            "solved": session.solved,
            "not_solved": session.frames - session.solved,
        },
        "created_at": session.created_at,
        "idle_s": store.idle_s(session),
        "idle_ttl_s": store.ttl_s,
        "websockets": session.websockets,
    }


@router.post(
    "/sessions",
    status_code=status.HTTP_201_CREATED,
    response_model=S.SessionCreated,
    responses={**_KEY_ERRORS, **_413, **_422, **_429_KEY, **_503},
    tags=["sessions"],
)
async def create_session(
    body: Annotated[S.SessionCreate, Body(openapi_examples=_CREATE_EXAMPLES)],
    request: Request,
    svc: ServicesDep,
    owner: OwnerDep,
) -> Response:
    """Create a session: a chain, solver options and an optional initial pose."""
    svc.runner.check_ready()
    if owner is None and svc.session_starts is not None:  # no API keys: per address
        address = request.client.host if request.client else ""
        wait_s = svc.session_starts.take(address)
        if wait_s > 0:
            raise ServiceError(
                ErrorCode.RATE_LIMITED,
                f"this address created {svc.settings.sessions_per_address_per_min:g} sessions "
                "in the last minute (IK_SESSIONS_PER_ADDRESS_PER_MIN); reuse one, or wait",
                status_code=status.HTTP_429_TOO_MANY_REQUESTS,
                retry_after_s=wait_s,
            )
    settings = svc.settings
    view = await svc.runner.run(
        WorkClass.BUILD, convert.chain_from_spec, body.chain, settings, body.conventions, body.bones
    )
    defaults = convert.session_defaults(settings, skeleton=view.skeleton is not None)
    options = convert.apply_options(body.options, defaults, settings)
    solver = await svc.runner.run(WorkClass.BUILD, make_solver, view, options)
    session, token = new_session(view, solver, options, now=svc.store.clock(), owner=owner)
    clipped: list[str] = []
    if body.initial_pose is not None:
        session.set_pose(convert.pose_vector(body.initial_pose, view, solver.q, "initial_pose"))
        clipped = convert.clipped_dofs(body.initial_pose, view)
    session.definition = chain_definition(body)
    try:
        await svc.store.add(session)
    except OwnerFull as e:
        raise ServiceError(
            ErrorCode.KEY_SESSION_LIMIT,
            f"this API key holds its maximum of {e.limit} sessions (IK_MAX_SESSIONS_PER_KEY); "
            "delete one first",
            status_code=status.HTTP_429_TOO_MANY_REQUESTS,
        ) from None
    except StoreFull as e:
        raise ServiceError(
            ErrorCode.TOO_MANY_SESSIONS,
            f"the server holds its maximum of {settings.max_sessions} sessions",
            status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
            retry_after_s=e.retry_after_s,
        ) from None
    svc.metrics.sessions_created.inc()
    body_out = {
        "id": session.id,
        "token": token,
        **view.summary,
        "options": convert.options_dict(options),
        "pose": convert.pose_dict(view, solver.q, clipped),
        "idle_ttl_s": svc.store.ttl_s,
    }
    return ORJSONResponse(
        body_out,
        status_code=status.HTTP_201_CREATED,
        headers={"Location": f"/v1/sessions/{session.id}"},
    )


async def _change(session: Session, store: SessionStore, apply: Callable[[], None]) -> None:
    """Run ``apply`` on the session under its lock and save the change through the
    store (a session deleted meanwhile answers 404), then count the request as a use."""
    async with session.lock:
        if session.closed:
            raise not_found()
        await store.change(session, apply)
    store.touch(session)


@router.get(
    "/sessions/{session_id}",
    response_model=S.SessionInfo,
    responses=_AUTH_ERRORS,
    tags=["sessions"],
)
async def get_session(session: SessionDep, svc: ServicesDep) -> dict[str, Any]:
    """The session's chain summary, options, current pose and counters."""
    await svc.store.latest(session)
    svc.store.touch(session)
    return _session_info(session, svc.store)


@router.patch(
    "/sessions/{session_id}",
    response_model=S.SessionInfo,
    responses={**_AUTH_ERRORS, **_422},
    tags=["sessions"],
)
async def patch_session(
    body: Annotated[S.OptionsPatch, Body()], session: SessionDep, svc: ServicesDep
) -> dict[str, Any]:
    """Change solver options; fields left out keep their value. Applies to later frames."""

    def apply() -> None:
        session.options = convert.apply_options(body, session.options, svc.settings, field="")

    await _change(session, svc.store, apply)
    return _session_info(session, svc.store)


@router.put(
    "/sessions/{session_id}/pose",
    response_model=S.Pose,
    responses={**_AUTH_ERRORS, **_422},
    tags=["sessions"],
)
async def put_pose(
    body: Annotated[S.PoseIn, Body()], session: SessionDep, svc: ServicesDep
) -> dict[str, Any]:
    """Set the current pose (the next frame starts from it). Values outside the limits
    are set to the nearest limit, and the answer's ``clipped`` names those DOFs."""

    def apply() -> None:
        session.set_pose(convert.pose_vector(body, session.view, session.solver.q))

    await _change(session, svc.store, apply)
    clipped = convert.clipped_dofs(body, session.view)
    return convert.pose_dict(session.view, session.solver.q, clipped)


@router.delete(
    "/sessions/{session_id}",
    status_code=status.HTTP_204_NO_CONTENT,
    responses=_AUTH_ERRORS,
    tags=["sessions"],
)
async def delete_session(session: SessionDep, svc: ServicesDep) -> Response:
    """Delete the session; open WebSockets on it close with 4404 at their next message."""
    await svc.store.remove(session.id)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.post(
    "/sessions/{session_id}/frames",
    response_model=S.FrameResults | S.CompactFrameResults,
    responses={**_AUTH_ERRORS, **_413, **_422, **_429_RATE, **_503},
    tags=["sessions"],
)
async def post_frames(
    body: Annotated[S.FramesBody, Body(openapi_examples=_FRAMES_EXAMPLES)],
    request: Request,
    session: SessionDep,
    svc: ServicesDep,
    query: Annotated[S.FramesQuery, Query()],
) -> Response:
    """Solve one frame, or a clip of frames in order (with `"plan": true`, as a whole);
    one result per frame."""
    t0 = received_at(request)
    plan = isinstance(body, S.ClipRequest) and body.plan
    view = session.view
    if isinstance(body, S.ClipRequest):
        limit = svc.settings.max_frames_per_request
        jobs = convert.clip_jobs(body.frames, view, limit, plan=body.plan)
        outputs = [f.bones for f in body.frames]
        fields = [f"frames[{i}].bones" for i in range(len(body.frames))]
    else:
        targets = convert.targets(body.targets, view, "targets")
        jobs = [(body.id, targets, convert.frame_pose(body.pose, view, "pose"))]
        outputs, fields = [body.bones], ["bones"]
    for output, where in zip(outputs, fields, strict=True):
        if output is not None:
            convert.check_bone_output(output, view.skeleton, where)
    build = convert.result_builder(query.results)
    if plan:
        solved, planned = await svc.runner.session_plan(session, svc.store, jobs, t0, "http")
        results = convert.add_bones(convert.render_frames(solved, build), solved, view, outputs)
        return ORJSONResponse({"results": results, "plan": convert.plan_summary(planned)})
    peer = request.client.host if request.client else None
    client = session_client(session, peer)
    solved = await svc.runner.session_frames(session, svc.store, jobs, t0, "http", client)
    results = convert.add_bones(convert.render_frames(solved, build), solved, view, outputs)
    return ORJSONResponse({"results": results})


_BATCH_EXAMPLES = {
    "two characters": {
        "summary": "One frame for each of two sessions (3-DOF arm example)",
        "value": {
            "frames": [
                {
                    "session": "<session id>",
                    "token": "<its token>",
                    "id": 1,
                    "targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}],
                },
                {
                    "session": "<another session id>",
                    "token": "<its token>",
                    "id": 1,
                    "targets": [{"effector": "hand", "position": {"x": 0.2, "y": 0.3, "z": 0.5}}],
                },
            ]
        },
    },
}


@router.post(
    "/batch",
    response_model=S.BatchResults,
    responses={
        **_413,
        **_422,
        429: {**_E, "description": "This client holds its share of the frame threads"},
        503: {**_E, "description": "`not_ready` (warming up) or `server_busy`; see Retry-After"},
    },
    tags=["sessions"],
)
async def post_batch(
    body: Annotated[S.BatchRequest, Body(openapi_examples=_BATCH_EXAMPLES)],
    request: Request,
    svc: ServicesDep,
    query: Annotated[S.FramesQuery, Query()],
) -> Response:
    """One frame for each of several sessions (a game server's characters), each entry
    with its session's token; one answer per entry, in order: its result, or its own
    error (the other entries are still solved)."""
    t0 = received_at(request)
    batch.check_length(len(body.frames), svc.settings.max_frames_per_request)
    tokens = SessionTokens(svc.store)
    entries = [
        await batch.prepare(i, frame, svc.store, tokens) for i, frame in enumerate(body.frames)
    ]
    peer = request.client.host if request.client else None
    first = next((e.session for e in entries if isinstance(e, batch.Entry)), None)
    client = f"peer:{peer}" if first is None else session_client(first, peer)
    outcomes = await batch.solve(svc.runner, svc.store, entries, t0, "http", client)
    build = convert.result_builder(query.results)
    results = batch.render(
        entries, body.frames, outcomes, build, lambda code: svc.metrics.error(code, "http")
    )
    return ORJSONResponse({"results": results})


@router.post(
    "/sessions/{session_id}/fk",
    response_model=S.FkResult,
    responses={**_AUTH_ERRORS, **_422},
    tags=["sessions"],
)
async def post_fk(
    body: Annotated[S.FkRequest, Body()], session: SessionDep, svc: ServicesDep
) -> Response:
    """Forward kinematics of any chain: a pose in (``q`` or ``joints``; neither: the
    current pose), every effector's world pose out and, on skeleton chains (gltf, bvh),
    bone local rotations and world transforms, in the session's conventions. The
    session's pose does not change."""
    if body.q is None:  # the current pose is read (all of it, or under ``joints``)
        await svc.store.latest(session)
    svc.store.touch(session)
    out = convert.fk_dict(session.view, session.solver.q, body.q, body.joints, body.bones)
    return ORJSONResponse(out)


@router.post(
    "/solve",
    response_model=S.FrameResult,
    responses={**_KEY_ERRORS, **_413, **_422, **_503},
    tags=["one-shot"],
)
async def solve(
    body: S.SolveRequest, request: Request, svc: ServicesDep, owner: OwnerDep
) -> Response:
    """Stateless one-shot solve: a chain, one frame of targets, an optional seed."""
    t0 = received_at(request)
    svc.runner.check_ready()
    settings = svc.settings
    view = await svc.runner.run(
        WorkClass.BUILD, convert.chain_from_spec, body.chain, settings, body.conventions, body.bones
    )
    options = convert.apply_options(body.options, convert.oneshot_defaults(settings), settings)
    targets = convert.targets(body.targets, view, "targets")
    seed = None
    if body.seed is not None:
        seed = convert.pose_vector(body.seed, view, view.mid_limits, "seed")
    solved = await svc.runner.run(
        WorkClass.SOLVE, solve_once, view, targets, seed, options, body.id, t0
    )
    svc.metrics.frame(solved.result, solved.server_us * 1e-6, "http")
    result = convert.result_dict(solved.result, solved.frame_id, solved.server_us)
    (result,) = convert.add_bones([result], [solved], view, [None])
    return ORJSONResponse(result)
