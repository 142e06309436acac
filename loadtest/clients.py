"""Simulated game clients: open a session, stream a path at a fixed rate, record answers.

Sends are open-loop on a fixed schedule (frame k at start + k / rate): a slow answer
does not delay the next frame over WebSocket (the server answers in order, so a client
may pipeline), and over HTTP the next request goes out as soon as the previous answer
is in (one request in flight per client, which is what keeps HTTP frames in order).
Latency is measured from the scheduled time either way (over WebSocket, to the answer
as ik_client returns it, decoded).

WebSocket frames go through ik_client (``AsyncStream``: ids, pipelining, answers and
error answers typed), opened on the keep-alive connection that created the session
(``create_session_sticky``), so they reach the worker process that holds it.
Reconnecting is off: a drop is an error to count, not something to hide. Session
creation and HTTP frames stay on plain HTTP (httpx), because the floors
(loadtest.floors), which the same generator drives, answer them with bare bodies (an
id and a token; ``{"id", "termination": "echo"}``) that are not the service's schema a
typed client reads; making them full answers would change the floor being measured.

Error kinds (``ClientResult.errors``): ``setup_<why>`` (the session could not be opened),
``ws_<code>`` / ``http_<status>`` (the server answered with an error), ``closed_<code>``
(the socket closed under us), ``out_of_order``, ``unknown_id`` (an answer to nothing in
flight), ``unanswered`` (still in flight at the end of the drain), ``<ExceptionName>``.
"""

from __future__ import annotations

import asyncio
import socket
import time
from collections import deque
from dataclasses import dataclass
from typing import Any
from urllib.parse import urlsplit

import httpx
import orjson
from ik_client import (
    AsyncStream,
    Encoding,
    FrameAnswer,
    FrameResult,
    Reconnect,
    ServiceError,
    StreamClosed,
    Target,
    UnexpectedAnswer,
)
from ik_client.calls import ws_url
from websockets.exceptions import ConnectionClosed, InvalidHandshake

from .paths import Path
from .records import ClientResult, Progress

WORKER_HEADER = "x-worker"  # set by loadtest.serve; tells which process owns the session
# A load tool counts a dropped connection (closed_<code>); it never reconnects past it.
NO_RECONNECT = Reconnect(attempts=0)


class SetupError(Exception):
    """The session could not be opened; ``kind`` is the error kind to count."""

    def __init__(self, kind: str) -> None:
        super().__init__(kind)
        self.kind = kind


@dataclass(frozen=True, slots=True)
class ClientSpec:
    """What one client does; ``offset`` staggers clients along the path and in time."""

    index: int
    url: str  # http://host:port
    transport: str  # "ws" or "http"
    path: Path
    rate_hz: float
    duration_s: float
    drain_s: float
    timeout_s: float
    phase_s: float  # first frame this long after the common start (spreads the ticks)
    options: dict[str, Any]
    results: str = "full"  # ?results= of the service: "full" or "compact"
    deflate: bool = False  # offer permessage-deflate (browsers do; the floors accept it too)


@dataclass(frozen=True, slots=True)
class StickySession:
    """The id and token of a session made by ``create_session_sticky`` (an
    ``ik_client.SessionRef``; the floors answer with no more than these two)."""

    id: str
    token: str


def session_body(spec: ClientSpec) -> bytes:
    body: dict[str, Any] = {"chain": {"format": "example", "name": spec.path.chain}}
    if spec.options:
        body["options"] = spec.options
    return orjson.dumps(body)


def _read_http_response(sock: socket.socket) -> tuple[int, dict[str, str], bytes]:
    """One HTTP/1.1 response with a Content-Length body, read from a blocking socket."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            raise SetupError("setup_connection_closed")
        buf += chunk
    head, _, rest = buf.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    status = int(lines[0].split(" ", 2)[1])
    headers = {k.strip().lower(): v.strip() for k, _, v in (ln.partition(":") for ln in lines[1:])}
    length = int(headers.get("content-length", "0"))
    while len(rest) < length:
        chunk = sock.recv(65536)
        if not chunk:
            raise SetupError("setup_connection_closed")
        rest += chunk
    return status, headers, rest[:length]


def create_session_sticky(
    host: str, port: int, body: bytes, timeout_s: float
) -> tuple[socket.socket, dict[str, Any], str | None]:
    """POST /v1/sessions on a fresh TCP connection and return that connection.

    The WebSocket is then opened on the same connection (HTTP/1.1 keep-alive, then
    Upgrade), so it lands on the worker process that holds the session: with several
    workers behind one port, a second connection may be accepted by another process,
    whose in-memory store does not know the session (close 4404).
    """
    sock = socket.create_connection((host, port), timeout=timeout_s)
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.sendall(
            b"POST /v1/sessions HTTP/1.1\r\nHost: %s:%d\r\ncontent-type: application/json\r\n"
            b"content-length: %d\r\n\r\n%s" % (host.encode(), port, len(body), body)
        )
        status, headers, payload = _read_http_response(sock)
        if status != 201:
            raise SetupError(f"setup_http_{status}")
        return sock, orjson.loads(payload), headers.get(WORKER_HEADER)
    except BaseException:
        sock.close()
        raise


def _query(spec: ClientSpec) -> str:
    """``?results=compact`` when asked for; nothing for the default (the floors, which
    ignore query strings, get the same URL either way)."""
    return "" if spec.results == "full" else f"?results={spec.results}"


def _first_frame_at(start: float, spec: ClientSpec) -> float:
    """The common start plus this client's phase; a client whose session took longer to
    open than the setup allowance starts when it is ready instead of bursting to catch up."""
    return max(start + spec.phase_s, time.perf_counter())


async def _sleep_until(t: float) -> None:
    delay = t - time.perf_counter()
    if delay > 0:
        await asyncio.sleep(delay)


async def ws_client(spec: ClientSpec, start: float, progress: Progress) -> ClientResult:
    """One WebSocket client: sticky session, paced sends, in-order answers checked.

    Frames go through ik_client's ``AsyncStream`` on the connection that created the
    session, with reconnecting off (a drop is counted as ``closed_<code>``, not mended),
    permessage-deflate only when ``spec.deflate`` (browsers offer it; the figures without
    it are the service's own cost, not zlib's) and no keepalive pings (as the raw
    clients before ik_client: they add traffic to a short run, and a reconnect-less
    client learns of a drop from its reads)."""
    res = ClientResult(spec.index, spec.path.chain, "ws")
    parts = urlsplit(spec.url)
    host, port = parts.hostname or "127.0.0.1", parts.port or 80
    try:
        sock, created, res.worker = await asyncio.to_thread(
            create_session_sticky, host, port, session_body(spec), spec.timeout_s
        )
        session = StickySession(created["id"], created["token"])
        # The stream alone, not an AsyncClient's: each httpx client loads the CA
        # certificates (tens of ms of CPU), which would stall the clients already sending.
        stream = AsyncStream(
            ws_url(spec.url, session, spec.results == "compact"),
            session.token,
            encoding=Encoding.JSON,
            reconnect=NO_RECONNECT,
            timeout_s=None,  # the drain below bounds the wait for the last answers
            deflate=spec.deflate,
            sock=sock,
            ping_interval_s=None,  # the run is short; pings would only add traffic
        )
        await asyncio.wait_for(stream.__aenter__(), spec.timeout_s)
    except SetupError as e:
        res.errors[e.kind] += 1
        progress.errors += 1
        return res
    except (OSError, TimeoutError, ConnectionClosed, InvalidHandshake) as e:
        res.errors[f"setup_{type(e).__name__}"] += 1
        progress.errors += 1
        return res
    res.opened = True
    try:
        await _stream_frames(spec, start, progress, res, stream)
    finally:
        try:
            await asyncio.wait_for(stream.close(), spec.timeout_s)
        except (TimeoutError, ConnectionClosed, OSError):
            pass
    return res


async def _stream_frames(
    spec: ClientSpec, start: float, progress: Progress, res: ClientResult, stream: AsyncStream
) -> None:
    """Send the path on schedule (a sender task) and check each answer against the
    oldest frame in flight (a receiver task); drain, then count what is left."""
    period = 1.0 / spec.rate_hz
    targets: list[list[Target]] = [orjson.loads(t) for t in spec.path.targets]
    n_path = len(targets)
    offset = spec.index * 37  # clients on the same chain start at different points
    in_flight: deque[tuple[int, float]] = deque()  # (the stream's id, scheduled time)
    first = _first_frame_at(start, spec)
    all_answered = asyncio.Event()

    async def sender() -> None:
        k = 0  # the stream numbers its messages 0, 1, 2, ...: k is the id it gives
        try:
            while True:
                t_sched = first + k * period
                if t_sched - first >= spec.duration_s:
                    break
                await _sleep_until(t_sched)
                now = time.perf_counter()
                in_flight.append((k, t_sched))  # before the send: its answer may come first
                all_answered.clear()
                res.send_lag_us.append((now - t_sched) * 1e6)
                res.sent += 1  # counted before the send: a frame lost in it is unanswered
                progress.sent += 1
                await stream.send_frame(targets[(offset + k) % n_path])
                k += 1
        except StreamClosed:
            pass  # the receiver records why

    async def receiver() -> None:
        while True:
            result: FrameResult | None = None
            error: str | None = None
            try:
                answer = await stream.receive()
                rid = answer.id
                if isinstance(answer, FrameAnswer):
                    result = answer.result
            except ServiceError as e:  # an error answer
                rid, error = e.id, f"ws_{e.code}"
            except UnexpectedAnswer as e:
                if e.id is None:
                    res.errors["unknown_id"] += 1
                    progress.errors += 1
                    continue
                rid = e.id  # not a result: the bare echo (loadtest.floors) sends the frame back
            now = time.perf_counter()
            if in_flight and in_flight[0][0] == rid:
                _, t_sched = in_flight.popleft()
            else:
                match = [x for x in in_flight if x[0] == rid]
                if not match:
                    res.errors["unknown_id"] += 1
                    progress.errors += 1
                    continue
                res.errors["out_of_order"] += 1
                progress.errors += 1
                in_flight.remove(match[0])
                t_sched = match[0][1]
            res.answered += 1
            progress.answered += 1
            rtt = now - t_sched
            if rtt > period:
                progress.late += 1
            if error is not None:
                res.errors[error] += 1
                progress.errors += 1
            else:
                res.t_s.append(t_sched - first)
                res.rtt_us.append(rtt * 1e6)
                if result is None:
                    res.solve_us.append(0.0)
                    res.server_us.append(0.0)
                    res.terminations["echo"] += 1
                else:
                    res.solve_us.append(result.solve_us)
                    res.server_us.append(result.server_us)
                    res.terminations[result.termination.value] += 1
            if not in_flight:
                all_answered.set()

    recv_task = asyncio.create_task(receiver())
    send_task = asyncio.create_task(sender())
    try:
        await send_task
        if in_flight and not recv_task.done():
            waiter = asyncio.create_task(all_answered.wait())
            await asyncio.wait(
                {waiter, recv_task}, timeout=spec.drain_s, return_when=asyncio.FIRST_COMPLETED
            )
            waiter.cancel()
        if recv_task.done():
            # The socket closed (or the receiver failed) before the client was done.
            exc = recv_task.exception()
            if isinstance(exc, StreamClosed):
                kind = f"closed_{exc.close_code}"
            else:
                kind = type(exc).__name__
            res.lost = True
            res.lost_reason = kind
            res.errors[kind] += 1
            progress.errors += 1
    finally:
        if in_flight:
            res.errors["unanswered"] += len(in_flight)
            progress.errors += len(in_flight)
        recv_task.cancel()
        send_task.cancel()
        await asyncio.gather(recv_task, send_task, return_exceptions=True)


async def http_client(spec: ClientSpec, start: float, progress: Progress) -> ClientResult:
    """One HTTP client: POST a frame per tick, one request in flight, answers checked."""
    res = ClientResult(spec.index, spec.path.chain, "http")
    limits = httpx.Limits(max_connections=1, max_keepalive_connections=1)
    async with httpx.AsyncClient(base_url=spec.url, limits=limits, timeout=spec.timeout_s) as http:
        try:
            r = await http.post(
                "/v1/sessions",
                content=session_body(spec),
                headers={"content-type": "application/json"},
            )
        except httpx.HTTPError as e:
            res.errors[f"setup_{type(e).__name__}"] += 1
            progress.errors += 1
            return res
        if r.status_code != 201:
            res.errors[f"setup_http_{r.status_code}"] += 1
            progress.errors += 1
            return res
        res.opened = True
        res.worker = r.headers.get(WORKER_HEADER)
        created = r.json()
        frames_url = f"/v1/sessions/{created['id']}/frames{_query(spec)}"
        headers = {
            "Authorization": f"Bearer {created['token']}",
            "content-type": "application/json",
        }
        period = 1.0 / spec.rate_hz
        targets = spec.path.targets
        n_path = len(targets)
        offset = spec.index * 37
        first = _first_frame_at(start, spec)
        deadline = first + spec.duration_s + spec.drain_s  # bounds a run that falls behind
        k = 0
        while True:
            t_sched = first + k * period
            if t_sched - first >= spec.duration_s or time.perf_counter() > deadline:
                break
            await _sleep_until(t_sched)
            res.send_lag_us.append((time.perf_counter() - t_sched) * 1e6)
            body = b'{"id":%d,"targets":%s}' % (k, targets[(offset + k) % n_path])
            res.sent += 1
            progress.sent += 1
            k += 1
            try:
                r = await http.post(frames_url, content=body, headers=headers)
            except httpx.HTTPError as e:
                res.errors[type(e).__name__] += 1
                progress.errors += 1
                continue
            now = time.perf_counter()
            if r.status_code != 200:
                res.errors[f"http_{r.status_code}"] += 1
                progress.errors += 1
                if r.status_code == 404:  # the session is gone: nothing more to send
                    res.lost = True
                    res.lost_reason = "http_404"
                    break
                continue
            results = orjson.loads(r.content)["results"]
            if len(results) != 1 or results[0].get("id") != k - 1:
                res.errors["out_of_order"] += 1
                progress.errors += 1
                continue
            res.answered += 1
            progress.answered += 1
            rtt = now - t_sched
            if rtt > period:
                progress.late += 1
            out = results[0]
            res.t_s.append(t_sched - first)
            res.rtt_us.append(rtt * 1e6)
            res.solve_us.append(float(out.get("solve_us", 0.0)))
            res.server_us.append(float(out.get("server_us", 0.0)))
            res.terminations[str(out.get("termination", "echo"))] += 1
    return res
