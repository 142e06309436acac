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
    of a store lookup and a hash. A session deleted since is looked up again (404)."""

    def __init__(self) -> None:
        self._opened: dict[str, tuple[str, Session]] = {}

    def known(self, session_id: str, token: str) -> Session | None:
        """The session if this connection opened it with ``token`` and it still exists."""
        known = self._opened.get(session_id)
        if known is not None and not known[1].closed and secrets.compare_digest(known[0], token):
            return known[1]
        return None

    async def open(self, store: SessionStore, session_id: str, token: str) -> Session:
        """The session if ``token`` opens it.

        Raises:
            ServiceError: unauthorized, not_found, forbidden (as ``auth.authenticate``).
        """
        if (session := self.known(session_id, token)) is not None:
            return session
        session = await authenticate(store, session_id, token)
        if len(self._opened) >= MAX_REMEMBERED_SESSIONS:
            self._opened.pop(next(iter(self._opened)))
        self._opened[session_id] = (token, session)
        return session
