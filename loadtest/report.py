"""Summaries of a run: one dict (the JSON output) and the table printed from it."""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from .records import ClientResult
from .run import RunOutput


def _pcts(x: np.ndarray, scale: float) -> dict[str, float | None]:
    if x.size == 0:
        return {"p50": None, "p95": None, "p99": None, "max": None}
    p50, p95, p99 = np.percentile(x, [50, 95, 99])
    return {
        "p50": float(p50) * scale,
        "p95": float(p95) * scale,
        "p99": float(p99) * scale,
        "max": float(x.max()) * scale,
    }


def measured(results: list[ClientResult], warmup_s: float) -> dict[str, np.ndarray]:
    """Per-frame samples after each client's warm-up, concatenated over clients."""
    cols: dict[str, list[np.ndarray]] = {"t_s": [], "rtt_us": [], "solve_us": [], "server_us": []}
    for r in results:
        t = np.frombuffer(r.t_s, dtype=np.float64)
        keep = t >= warmup_s
        for k in cols:
            cols[k].append(np.frombuffer(getattr(r, k), dtype=np.float64)[keep])
    return {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}


def summarize(out: RunOutput) -> dict[str, Any]:
    """The run's figures (units in the keys), ready for ``json.dumps``."""
    cfg = out.config
    results = out.results
    period_us = 1e6 / cfg.rate_hz
    m = measured(results, cfg.warmup_s)
    window_s = cfg.duration_s - cfg.warmup_s
    errors: Counter[str] = Counter()
    terms: Counter[str] = Counter()
    workers: Counter[str] = Counter()
    for r in results:
        errors.update(r.errors)
        terms.update(r.terminations)
        if r.worker is not None and r.opened:
            workers[r.worker] += 1
    lag = np.concatenate(
        [np.frombuffer(r.send_lag_us, dtype=np.float64) for r in results] or [np.zeros(0)]
    )
    opened = sum(r.opened for r in results)
    return {
        "config": {
            "url": cfg.url,
            "transport": cfg.transport,
            "clients": cfg.clients,
            "rate_hz": cfg.rate_hz,
            "duration_s": cfg.duration_s,
            "warmup_s": cfg.warmup_s,
            "chains": list(cfg.chains),
            "processes": cfg.processes,
            "options": cfg.options,
        },
        "sessions": {
            "opened": opened,
            "lost": sum(r.lost for r in results),
            "lost_reasons": dict(Counter(r.lost_reason for r in results if r.lost)),
            "per_worker": dict(sorted(workers.items())),
        },
        "frames": {
            "sent": sum(r.sent for r in results),
            "answered": sum(r.answered for r in results),
            "measured": int(m["rtt_us"].size),
            "offered_per_s": cfg.clients * cfg.rate_hz,
            "achieved_per_s": m["rtt_us"].size / window_s,
            "late": int((m["rtt_us"] > period_us).sum()),
            "late_fraction": float((m["rtt_us"] > period_us).mean()) if m["rtt_us"].size else 0.0,
            "frame_period_ms": period_us / 1e3,
        },
        "round_trip_ms": _pcts(m["rtt_us"], 1e-3),
        "solve_us": _pcts(m["solve_us"], 1.0),
        "server_us": _pcts(m["server_us"], 1.0),
        "errors": dict(sorted(errors.items())),
        "terminations": dict(terms.most_common()),
        "generator": {
            "wall_s": out.wall_s,
            "cpu_s": out.generator_cpu_s,
            "cpu_per_window": out.generator_cpu_s / max(out.wall_s, 1e-9),
            "send_lag_ms": _pcts(lag, 1e-3),
        },
    }


def _f(v: float | None, fmt: str = "{:,.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def table(s: dict[str, Any]) -> str:
    """The summary as aligned text."""
    c, fr, se = s["config"], s["frames"], s["sessions"]
    rows: list[tuple[str, str]] = [
        ("target", f"{c['url']} over {c['transport']}"),
        (
            "clients x rate",
            f"{c['clients']} x {c['rate_hz']:g} Hz for {c['duration_s']:g} s "
            f"(first {c['warmup_s']:g} s not counted); chains {', '.join(c['chains'])}",
        ),
        ("frames sent / answered", f"{fr['sent']:,} / {fr['answered']:,}"),
        (
            "frames/s offered / achieved",
            f"{fr['offered_per_s']:,.0f} / {fr['achieved_per_s']:,.0f}",
        ),
        (
            "late (> one frame period)",
            f"{fr['late']:,} of {fr['measured']:,} "
            f"({100 * fr['late_fraction']:.2f}%, period "
            f"{fr['frame_period_ms']:.1f} ms)",
        ),
    ]
    for key, label, fmt in (
        ("round_trip_ms", "round trip [ms]", "{:,.2f}"),
        ("server_us", "server_us [us]", "{:,.0f}"),
        ("solve_us", "solve_us [us]", "{:,.0f}"),
    ):
        p = s[key]
        rows.append(
            (
                label + " p50/p95/p99/max",
                " / ".join(_f(p[q], fmt) for q in ("p50", "p95", "p99", "max")),
            )
        )
    rows.append(
        (
            "sessions opened / lost",
            f"{se['opened']} / {se['lost']}" + (f" {se['lost_reasons']}" if se["lost"] else ""),
        )
    )
    if se["per_worker"]:
        rows.append(
            ("sessions per worker", ", ".join(f"{w}: {n}" for w, n in se["per_worker"].items()))
        )
    rows.append(("errors", ", ".join(f"{k}: {v:,}" for k, v in s["errors"].items()) or "none"))
    rows.append(
        ("terminations", ", ".join(f"{k}: {v:,}" for k, v in s["terminations"].items()) or "-")
    )
    g = s["generator"]
    rows.append(
        (
            "generator",
            f"{g['cpu_s']:.1f} s CPU in {g['wall_s']:.1f} s "
            f"({c['processes']} process(es)); send lag p99 {_f(g['send_lag_ms']['p99'])} ms",
        )
    )
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
