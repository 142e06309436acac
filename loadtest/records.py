"""What one simulated client measured: plain arrays and counters, picklable across processes."""

from __future__ import annotations

from array import array
from collections import Counter
from dataclasses import dataclass, field


@dataclass
class ClientResult:
    """One client's session: per-frame samples (parallel arrays) and what went wrong.

    ``t_s`` is each answered frame's scheduled send time, relative to the client's first
    frame [s]; ``rtt_us`` runs from that scheduled time to the answer's arrival, so a
    client that could not send on time does not hide the delay (coordinated omission).
    """

    index: int
    chain: str
    transport: str
    worker: str | None = None  # x-worker header of the session's process, if the server sends one
    opened: bool = False  # the session was created (and, for WebSocket, connected)
    lost: bool = False  # the session or its connection went away before the client finished
    lost_reason: str | None = None
    sent: int = 0
    answered: int = 0
    t_s: array[float] = field(default_factory=lambda: array("d"))
    rtt_us: array[float] = field(default_factory=lambda: array("d"))
    solve_us: array[float] = field(default_factory=lambda: array("d"))
    server_us: array[float] = field(default_factory=lambda: array("d"))
    send_lag_us: array[float] = field(default_factory=lambda: array("d"))
    terminations: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)


@dataclass
class Progress:
    """Running totals the progress line reads (one per process)."""

    sent: int = 0
    answered: int = 0
    errors: int = 0
    late: int = 0
