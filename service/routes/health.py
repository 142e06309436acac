"""/healthz (alive), /readyz (solver warm: 200, else 503 not_ready), /metrics (Prometheus)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST
from starlette import status

import schemas as S

from ..dependencies import ServicesDep
from ..responses import ORJSONResponse

router = APIRouter(tags=["operations"])


@router.get("/healthz")
async def healthz() -> dict[str, str]:
    """The process is alive and serving."""
    return {"status": "ok"}


@router.get(
    "/readyz",
    responses={503: {"model": S.ErrorBody, "description": "`not_ready`: still warming up"}},
)
async def readyz(svc: ServicesDep) -> Response:
    """Ready once the compiled solver is loaded and warm (503 until then)."""
    warm = svc.runner.warmup
    if warm.ready.is_set():
        return ORJSONResponse({"status": "ready", "warmup_s": warm.seconds})
    body: dict[str, Any] = {"detail": "the solver is warming up", "code": "not_ready"}
    if warm.error is not None:
        body = {"detail": f"solver warm-up failed: {warm.error}", "code": "warmup_failed"}
    return ORJSONResponse(
        body, status_code=status.HTTP_503_SERVICE_UNAVAILABLE, headers={"Retry-After": "1"}
    )


@router.get("/metrics", response_class=Response)
async def metrics(svc: ServicesDep) -> Response:
    """Prometheus text exposition."""
    return Response(svc.metrics.render(), media_type=CONTENT_TYPE_LATEST)
