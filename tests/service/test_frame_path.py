"""The per-frame path stays cheap (issue #5): no thread hop per HTTP request."""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any

from fastapi.dependencies.models import Dependant
from fastapi.routing import APIRoute, APIWebSocketRoute

from service.routes import health, http, ws


def _calls(dependant: Dependant) -> Iterator[Any]:
    for d in dependant.dependencies:
        if d.call is not None:
            yield d.call
        yield from _calls(d)


def _is_async(call: Any) -> bool:
    return inspect.iscoroutinefunction(call) or inspect.iscoroutinefunction(
        getattr(call, "__call__", None)  # noqa: B004 (security schemes are callables)
    )


def test_no_route_runs_a_dependency_in_the_thread_pool() -> None:
    """FastAPI runs a plain ``def`` dependency (or endpoint) in its thread pool: a
    hand-off and a wake-up per request."""
    seen = 0
    for route in (*http.router.routes, *ws.router.routes, *health.router.routes):
        assert isinstance(route, APIRoute | APIWebSocketRoute)
        assert _is_async(route.endpoint), route.path
        for call in _calls(route.dependant):
            seen += 1
            assert _is_async(call), (route.path, call)
    assert seen > 10  # the walk did reach the dependencies
