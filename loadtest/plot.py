"""The PNG: latency over time and a latency histogram (matplotlib, the ``loadtest`` extra)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .report import measured
from .run import RunOutput


def write_png(out: RunOutput, summary: dict[str, Any], path: Path) -> None:
    """Scatter of round trips over the run with per-second p50/p99, and their histogram."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no display here
    import matplotlib.pyplot as plt

    cfg = out.config
    m = measured(out.results, 0.0)  # show the warm-up too, shaded
    t, rtt = m["t_s"], m["rtt_us"] * 1e-3
    period_ms = 1e3 / cfg.rate_hz
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(13, 4.8), width_ratios=[1.6, 1])
    if t.size:
        step = max(1, t.size // 50_000)  # keep the file small on long runs
        ax1.scatter(t[::step], rtt[::step], s=2, alpha=0.25, color="tab:blue", label="frame")
        width = min(1.0, max(0.1, cfg.duration_s / 40))  # about 40 bins
        edges = np.arange(0.0, cfg.duration_s + width, width)
        idx = np.digitize(t, edges) - 1
        mids, p50, p99 = [], [], []
        for b in range(len(edges) - 1):
            x = rtt[idx == b]
            if x.size:
                mids.append(edges[b] + 0.5)
                p50.append(np.percentile(x, 50))
                p99.append(np.percentile(x, 99))
        ax1.plot(mids, p50, color="tab:green", label=f"p50 per {width:g} s")
        ax1.plot(mids, p99, color="tab:red", label=f"p99 per {width:g} s")
        ax2.hist(rtt[t >= cfg.warmup_s], bins=80, color="tab:blue", log=True)
    for ax in (ax1, ax2):
        ax.grid(alpha=0.3)
    ax1.axhline(period_ms, color="black", ls="--", lw=1, label=f"one frame ({period_ms:.1f} ms)")
    ax1.axvspan(0, cfg.warmup_s, color="grey", alpha=0.15, label="warm-up (not counted)")
    ax1.set_yscale("log")
    ax1.set_xlabel("time since the first frame [s]")
    ax1.set_ylabel("round trip [ms]")
    ax1.legend(loc="upper right", fontsize=8)
    ax2.axvline(period_ms, color="black", ls="--", lw=1)
    ax2.set_xlabel("round trip [ms]")
    ax2.set_ylabel("frames")
    fr, rt = summary["frames"], summary["round_trip_ms"]
    p99_text = "-" if rt["p99"] is None else f"{rt['p99']:.2f}"
    fig.suptitle(
        f"{cfg.clients} {cfg.transport} clients x {cfg.rate_hz:g} Hz: "
        f"{fr['achieved_per_s']:,.0f} frames/s, p99 {p99_text} ms, late {fr['late']:,}, "
        f"errors {sum(summary['errors'].values()):,}, lost {summary['sessions']['lost']}",
        fontsize=11,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
