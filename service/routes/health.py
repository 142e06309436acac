"""/healthz (alive), /readyz (solver warm and the session store answering: 200, else 503
not_ready / store_unavailable), /metrics (Prometheus)."""

from __future__ import annotations

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST
from starlette import status

import schemas as S

from ..dependencies import ServicesDep
from ..errors import ServiceError
from ..responses import ORJSONResponse

router = APIRouter(tags=["operations"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """The process is alive and serving."""
    return {"status": "ok"}


@router.get(
    "/readyz",
    responses={
        503: {
            "model": S.NotReadyBody,
            "description": "`not_ready`: still warming up (`progress` says how far: a first "
            "start compiles the solver, minutes; later starts load it, about a second), "
            "or `warmup_failed`",
        }
    },
)
async def readyz(svc: ServicesDep) -> Response:
    """Ready once the compiled solver is loaded and warm (503 until then)."""
    warm = svc.runner.warmup
    if warm.ready.is_set():
        try:
            await svc.store.check()
        except ServiceError as e:  # Redis (IK_REDIS_URL) does not answer
            return ORJSONResponse(
                {"detail": e.detail, "code": e.code},
                status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
                headers={"Retry-After": "1"},
            )
        return ORJSONResponse({"status": "ready", "warmup_s": warm.seconds})
    if warm.error is not None:
        body = S.NotReadyBody(
            detail=f"solver warm-up failed: {warm.error}", code=S.ErrorCode.WARMUP_FAILED
        )
    else:
        progress = warm.progress
        body = S.NotReadyBody(
            detail=not_ready_detail(progress), code=S.ErrorCode.NOT_READY, progress=progress
        )
    return ORJSONResponse(
        body.model_dump(mode="json", exclude_none=True),
        status_code=status.HTTP_503_SERVICE_UNAVAILABLE,
        headers={"Retry-After": "1"},
    )


def not_ready_detail(progress: S.StartupProgress | None) -> str:
    """What a person reading /readyz should know about the warm-up."""
    if progress is None:
        return "the solver is warming up"
    if progress.phase is S.StartupPhase.COMPILING:
        return (
            "compiling the solver (first start of this checkout or image; the compiled code "
            f"is cached on disk, later starts take about a second): {progress.done}/"
            f"{progress.total} steps, {progress.compiled} functions, {progress.elapsed_s:.0f} s"
        )
    return (
        "loading the compiled solver from its on-disk cache: "
        f"{progress.done}/{progress.total} steps, {progress.elapsed_s:.1f} s"
    )


@router.get("/metrics", response_class=Response)
async def metrics(svc: ServicesDep) -> Response:
    """Prometheus text exposition."""
    return Response(svc.metrics.render(), media_type=CONTENT_TYPE_LATEST)
