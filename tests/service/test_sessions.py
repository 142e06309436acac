"""The in-memory store: cap, expiry (injected clock), open sockets keep sessions alive."""

from __future__ import annotations

import asyncio

import pytest

import schemas as S
from service import convert
from service.config import Settings
from service.sessions import InMemorySessionStore, Session, StoreFull, new_session, token_digest
from solver.ik import IKSolver

from .helpers import ARM


@pytest.fixture
def view(warm_solver: float) -> convert.ChainView:
    return convert.chain_from_spec(S.HierarchyChain.model_validate(ARM), Settings())


def _session(view: convert.ChainView, now: float) -> tuple[Session, str]:
    options = convert.session_defaults(Settings())
    return new_session(view, IKSolver(view.chain, options), options, now=now)


def test_ids_and_tokens_are_random_and_tokens_stored_hashed(view: convert.ChainView) -> None:
    pairs = [_session(view, 0.0) for _ in range(20)]
    assert len({s.id for s, _ in pairs}) == 20 and len({t for _, t in pairs}) == 20
    s, token = pairs[0]
    assert s.token_digest == token_digest(token) and token.encode() not in s.token_digest
    assert s.token_ok(token) and not s.token_ok(token + "x") and not s.token_ok("")


def test_cap_expiry_and_retry_after(view: convert.ChainView) -> None:
    now = [0.0]
    store = InMemorySessionStore(max_sessions=2, ttl_s=10.0, clock=lambda: now[0])

    async def scenario() -> None:
        a, _ = _session(view, now[0])
        await store.add(a)
        now[0] = 4.0
        b, _ = _session(view, now[0])
        await store.add(b)
        with pytest.raises(StoreFull) as info:
            await store.add(_session(view, now[0])[0])
        assert info.value.retry_after_s == pytest.approx(6.0)  # a expires at t = 10
        a.websockets = 1  # an open socket keeps a alive past its ttl
        now[0] = 30.0
        assert [s.id for s in await store.expire()] == [b.id]
        assert b.closed and await store.get(b.id) is None
        assert await store.get(a.id) is a
        a.websockets = 0
        assert await store.get(a.id) is None and a.closed
        assert len(store) == 0

    asyncio.run(scenario())


def test_remove_marks_closed(view: convert.ChainView) -> None:
    store = InMemorySessionStore(max_sessions=2, ttl_s=10.0)

    async def scenario() -> None:
        s, _ = _session(view, store.clock())
        await store.add(s)
        assert await store.remove(s.id) is s and s.closed
        assert await store.remove(s.id) is None

    asyncio.run(scenario())
