"""/readyz's bodies: how far the solver's warm-up is while the service is not ready."""

from __future__ import annotations

import enum

from pydantic import ConfigDict, Field

from .common import ErrorBody, StrictModel


class StartupPhase(enum.StrEnum):
    COMPILING = "compiling"  # no compiled solver on disk yet: numba compiles it (once)
    LOADING = "loading"  # loading the compiled solver from numba's on-disk cache


class StartupProgress(StrictModel):
    """The solver's warm-up so far. A first start of a checkout or image compiles
    (minutes; the result is cached on disk), every later start only loads (about a
    second). While compiling, ``done`` and ``compiled`` grow."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {"phase": "compiling", "done": 1, "total": 5, "elapsed_s": 61.2, "compiled": 35}
            ]
        }
    )

    phase: StartupPhase = Field(description="compiling (first start) or loading (from cache)")
    done: int = Field(ge=0, description="Warm-up steps finished in this phase")
    total: int = Field(ge=0, description="Warm-up steps in this phase")
    elapsed_s: float = Field(ge=0, description="Seconds since the warm-up began")
    compiled: int = Field(ge=0, description="Functions compiled so far in this phase")


class NotReadyBody(ErrorBody):
    """503 from /readyz: ``not_ready`` (warming up; ``progress`` says how far) or
    ``warmup_failed`` (``detail`` says why)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "detail": "compiling the solver (first start of this checkout or image; "
                    "the compiled code is cached on disk): 1/5 steps, 35 functions, 61 s",
                    "code": "not_ready",
                    "progress": {
                        "phase": "compiling",
                        "done": 1,
                        "total": 5,
                        "elapsed_s": 61.2,
                        "compiled": 35,
                    },
                }
            ]
        }
    )

    progress: StartupProgress | None = Field(
        default=None, description="How far the warm-up is (absent before it starts and on failure)"
    )
