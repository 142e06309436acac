"""How the service's processes log: each line's UTC time and pid, tokens redacted from
uvicorn's lines, passed health checks left out; as one ``logging.config.dictConfig``
dictionary (``log_config``), which ``python -m service`` applies at its start and
``python -m loadtest.serve`` hands to uvicorn, which applies it in every process it
runs, the workers ``--workers`` spawns included (those never run our ``main``: with
``log_config=None`` they had no handler, and their INFO lines went nowhere).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from typing import Any

# The time, the worker's pid (which of several on a machine), then uvicorn's level style;
# uvicorn's own lines, its access log included, go through the same handler.
LOG_FORMAT = "%(asctime)s [%(process)d] %(levelname)s:     %(message)s"

_TOKEN = re.compile(r"(token=)[^&\s\"]+")

# Health checks a balancer or a kubelet sends every 0.5-10 s per worker.
_PROBES = frozenset(("/healthz", "/readyz"))


class UtcTimestamps(logging.Formatter):
    """Each line's time in ISO-8601 UTC to the millisecond (2025-06-01T10:00:00.123Z):
    the lines had none, and an operator reads several workers' logs side by side, across
    machines and time zones."""

    def formatTime(self, record: logging.LogRecord, datefmt: str | None = None) -> str:
        when = time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
        return f"{when}.{int(record.msecs):03d}Z"


class RedactTokens(logging.Filter):
    """uvicorn's access log prints query strings; WebSocket clients may put ?token= there."""

    def filter(self, record: logging.LogRecord) -> bool:
        if isinstance(record.args, tuple):
            record.args = tuple(
                _TOKEN.sub(r"\1<redacted>", a) if isinstance(a, str) else a for a in record.args
            )
        record.msg = _TOKEN.sub(r"\1<redacted>", str(record.msg))
        return True


class QuietProbes(logging.Filter):
    """Drops uvicorn's access-log line of a health check that passed: a balancer's
    probes were most of an idle worker's log (925 /readyz lines in a few minutes). A
    probe that fails (503 while compiling or without Redis) is logged when its status
    changes, and then once per ``repeat_s`` at most: a first start's compile of several
    minutes, probed every 0.5 s by two backends, once logged ~750 identical lines."""

    def __init__(self, repeat_s: float = 30.0, clock: Callable[[], float] = time.monotonic):
        super().__init__()
        self.repeat_s = repeat_s
        self.clock = clock
        self._failed: dict[str, tuple[int, float]] = {}  # path -> (status, when logged)

    def filter(self, record: logging.LogRecord) -> bool:
        args = record.args
        # uvicorn.access: (client address, method, path, HTTP version, status code)
        if isinstance(args, tuple) and len(args) == 5:
            path, status_code = args[2], args[4]
            if path in _PROBES and isinstance(status_code, int):
                if status_code < 400:
                    self._failed.pop(path, None)
                    return False
                now = self.clock()
                last = self._failed.get(path)
                if last is not None and last[0] == status_code and now - last[1] < self.repeat_s:
                    return False
                self._failed[path] = (status_code, now)
        return True


def log_config(level: str) -> dict[str, Any]:
    """The service's logging at ``level`` (IK_LOG_LEVEL), for ``dictConfig`` or
    ``uvicorn.Config(log_config=...)``: one stderr handler on the root logger, so that
    the service's lines and uvicorn's share it. Loggers that exist already keep working
    (``disable_existing_loggers``: modules take ``logging.getLogger("service")`` at
    import). Applied once per process: a second time adds the filters again."""
    return {
        "version": 1,
        "disable_existing_loggers": False,
        "formatters": {"utc": {"()": UtcTimestamps, "fmt": LOG_FORMAT}},
        "filters": {"redact_tokens": {"()": RedactTokens}, "quiet_probes": {"()": QuietProbes}},
        "handlers": {
            "stderr": {
                "class": "logging.StreamHandler",
                "formatter": "utc",
                "stream": "ext://sys.stderr",
            }
        },
        "loggers": {
            "uvicorn.error": {"filters": ["redact_tokens"]},
            "uvicorn.access": {"filters": ["redact_tokens", "quiet_probes"]},
        },
        "root": {"level": level.upper(), "handlers": ["stderr"]},
    }
