"""TestClient fixtures: apps built with create_app(Settings(...)), solver warmed once."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from starlette.exceptions import StarletteDeprecationWarning

# starlette 1.x asks for httpx2 and warns (an error here) when the TestClient falls back
# to httpx, which is what the [test] extras install; the warning is about that choice only.
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", category=StarletteDeprecationWarning)
    from fastapi.testclient import TestClient

from service.config import Settings
from service.main import create_app

from .helpers import Created, create

READY_TIMEOUT_S = 30.0


@pytest.fixture(scope="session")
def warm_solver() -> float:
    """Load (or compile: 30-60 s in a fresh checkout) the numba core once per run."""
    import solver

    return float(solver.warmup())


def _no_warmup(report: object) -> float:
    return 0.0


@pytest.fixture
def make_client(warm_solver: float) -> Iterator[Callable[..., TestClient]]:
    """Build apps with given settings; each is started (lifespan) and ready."""
    clients: list[TestClient] = []

    def make(settings: Settings | None = None, **kwargs: Any) -> TestClient:
        kwargs.setdefault("warmup", _no_warmup)
        app = create_app(settings or Settings(), **kwargs)
        client = TestClient(app)
        client.__enter__()
        clients.append(client)
        if kwargs["warmup"] is _no_warmup:
            assert app.state.ik.runner.warmup.ready.wait(READY_TIMEOUT_S)
        return client

    yield make
    for c in clients:
        c.__exit__(None, None, None)


@pytest.fixture
def client(make_client: Callable[..., TestClient]) -> TestClient:
    return make_client()


@pytest.fixture
def session(client: TestClient) -> Created:
    return create(client)
