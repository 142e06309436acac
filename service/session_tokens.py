"""The sessions one connection has opened, with their tokens (``SessionTokens``): a
WebSocket's batches (and an HTTP batch request's entries) name many sessions, and
one opened before costs a constant-time comparison instead of a store lookup and a
hash."""

from __future__ import annotations

import secrets

from .auth import authenticate
from .sessions import Session, SessionStore

# A connection remembers at most this many sessions it has opened.
MAX_REMEMBERED_SESSIONS = 4096


class SessionTokens:
    """The sessions one connection has opened with their tokens (a WebSocket's, for
    its batches): an entry for one of them costs one constant-time comparison instead
    of a store lookup and a hash. A session deleted since, or idle past the store's
    TTL, is looked up again (404 once the store has expired it)."""

    def __init__(self, store: SessionStore) -> None:
        self._store = store
        self._opened: dict[str, tuple[str, Session]] = {}

    def known(self, session_id: str, token: str) -> Session | None:
        """The session if this connection opened it with ``token``, it still exists and
        it is not idle past the store's TTL: such a one is the store's to judge (the
        in-memory store expires it; another worker may have used a shared one), or a
        socket's batches would keep alive a session HTTP already answers 404 for."""
        known = self._opened.get(session_id)
        if known is None:
            return None
        token_sent, session = known
        if session.closed or not secrets.compare_digest(token_sent, token):
            return None
        store = self._store
        if session.websockets == 0 and store.clock() - session.last_seen > store.ttl_s:
            return None
        return session

    async def open(self, session_id: str, token: str) -> Session:
        """The session if ``token`` opens it.

        Raises:
            ServiceError: unauthorized, not_found, forbidden (as ``auth.authenticate``).
        """
        if (session := self.known(session_id, token)) is not None:
            return session
        session = await authenticate(self._store, session_id, token)
        if len(self._opened) >= MAX_REMEMBERED_SESSIONS:
            self._opened.pop(next(iter(self._opened)))
        self._opened[session_id] = (token, session)
        return session
