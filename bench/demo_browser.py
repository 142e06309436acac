"""/demo's solve loop as a browser sees it: solves and drawn frames of a 2-arm + 2-leg
character, and their round trips.

Starts a ``python -m service`` on 127.0.0.1, opens /demo in Debian's headless Chromium
(Playwright, the flags of tests/live/test_docs_browser.py), moves all four targets along
circles (the page's ``ikDemo.startMotion``: 0.12 m, 0.5 Hz, moved at each tick of the
solve loop) and, for each socket setting (JSON or MessagePack, full or compact results),
reads what the page did in ``--seconds``: answers per second, frames drawn per second,
the share solved, and the round trip (sent to handled, in the page,
``performance.now()``), server_us and solve_us.

The page sends the targets on a 60 Hz timer, apart from drawing (at most 4 frames
without an answer; a tick with 4 waiting sends nothing and counts as held), and each
drawn frame shows the newest answer: holding 60 solves/s means answering every tick,
whatever the drawn frame rate.

    OPENBLAS_NUM_THREADS=1 python -m bench.demo_browser --seconds 20
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from loadtest.service_process import ServiceProcess  # noqa: E402
from tests.live.test_docs_browser import CHROMIUM, CHROMIUM_ARGS  # noqa: E402

SETTINGS = [("json", False), ("json", True), ("msgpack", False), ("msgpack", True)]
READY = "() => !!(window.ikDemo && window.ikDemo.state.ready && window.ikDemo.state.solved > 0)"


def percentile(values: list[float], q: float) -> float:
    """Nearest-rank percentile (q in 0..100)."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, max(0, round(q / 100 * len(ordered)) - 1))]


def wait(page: Any, predicate: str, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not page.evaluate(predicate):
        if time.monotonic() > deadline:
            raise TimeoutError(predicate)
        page.wait_for_timeout(100)


def measure(page: Any, encoding: str, compact: bool, seconds: float) -> dict[str, float]:
    """One row: switch the socket, let it settle 1 s, count for ``seconds``."""
    page.evaluate("([e, c]) => window.ikDemo.setEncoding(e, c)", [encoding, compact])
    wait(
        page,
        f"() => window.ikDemo.state.encoding === '{encoding}' && "
        f"window.ikDemo.state.compact === {str(compact).lower()} && "
        "window.ikDemo.state.last !== null",
    )
    page.wait_for_timeout(1000)  # the new socket's first frames
    page.evaluate("() => window.ikDemo.resetStats()")
    page.wait_for_timeout(seconds * 1000)
    samples = page.evaluate(
        "() => ({...window.ikDemo.state.samples, now: performance.now(),"
        " errors: window.ikDemo.state.errors, socket: window.ikDemo.state.socket})"
    )
    rtt = samples["roundTripMs"]
    elapsed_s = (samples["now"] - samples["since"]) / 1000
    if samples["errors"] or not rtt:
        raise RuntimeError(
            f"no frames answered: errors {samples['errors']}, socket {samples['socket']}"
        )
    return {
        "frames": len(rtt),
        "per_s": len(rtt) / elapsed_s,
        "drawn_per_s": samples["drawn"] / elapsed_s,
        "held": samples["held"],
        "missed": samples["missed"],
        "solved_pct": 100 * samples["solved"] / max(1, len(rtt)),
        "rtt_p50": percentile(rtt, 50),
        "rtt_p99": percentile(rtt, 99),
        "rtt_max": max(rtt),
        "server_p50": statistics.median(samples["serverUs"]),
        "solve_p50": statistics.median(samples["solveUs"]),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="per setting")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=800)
    args = ap.parse_args(argv)
    from playwright.sync_api import sync_playwright

    log = Path("bench/out/demo_browser_server.log")
    log.parent.mkdir(parents=True, exist_ok=True)
    server = ServiceProcess(env={}, log_path=log)
    try:
        server.wait_ready()
        with sync_playwright() as pw:
            browser = pw.chromium.launch(
                executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS
            )
            page = browser.new_page(viewport={"width": args.width, "height": args.height})
            problems: list[str] = []
            page.on("pageerror", lambda error: problems.append(str(error)))
            page.on("console", lambda m: m.type == "error" and problems.append(m.text))
            page.goto(f"{server.base}/demo")
            wait(page, READY)
            rate = page.evaluate(
                "() => new Promise((done) => { let n = 0; const t0 = performance.now();"
                " const f = () => (++n < 60 ? requestAnimationFrame(f)"
                " : done(60000 / (performance.now() - t0))); requestAnimationFrame(f); })"
            )
            page.evaluate("() => window.ikDemo.startMotion()")
            try:
                rows = [(e, c, measure(page, e, c, args.seconds)) for e, c in SETTINGS]
            finally:
                if problems:
                    print("# the page's errors:", problems)
            browser.close()
    finally:
        server.stop()

    print(
        f"# /demo in headless Chromium, {args.width}x{args.height}, animation frames: {rate:.1f}/s"
    )
    print(f"# 4 targets moving (2 hands, 2 feet; 19 DOF), {args.seconds:.0f} s per row")
    print()
    print(
        "| encoding | results | frames | solves/s | drawn fps | solved | round trip p50 | p99 "
        "| max | server_us p50 | solve_us p50 |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for encoding, compact, r in rows:
        print(
            f"| {encoding} | {'compact' if compact else 'full'} | {r['frames']} "
            f"| {r['per_s']:.1f} | {r['drawn_per_s']:.1f} | {r['solved_pct']:.1f}% "
            f"| {r['rtt_p50']:.2f} ms | {r['rtt_p99']:.2f} ms | {r['rtt_max']:.2f} ms "
            f"| {r['server_p50']:.0f} | {r['solve_p50']:.0f} |"
        )
    print()
    for encoding, compact, r in rows:
        print(
            f"# {encoding} {'compact' if compact else 'full'}: timer ticks held (4 frames "
            f"waiting) {r['held']}, missed (timer late by a period) {r['missed']}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
