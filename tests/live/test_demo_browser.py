"""/demo in a real headless Chromium: drag a hand target, the character's hand follows.

The same browser, flags and request recording as tests/live/test_docs_browser.py (Debian's
/usr/bin/chromium driven by Playwright; every request to a host other than the service is
aborted and fails the test). The page exposes its state as ``window.ikDemo.state``:
answered frames, round trips, and the effector bones' world positions as the page's own
scene graph has them after applying the server's bone rotations. The drag is a real mouse
drag on the canvas, from the handle's screen position. Screenshots go to
tests/live/artifacts/ (git-ignored).

Playwright's waits that take a JavaScript string evaluate it with ``eval``, which the
page's Content-Security-Policy forbids; the test polls ``page.evaluate`` with functions
instead (those run through the DevTools protocol, not ``eval``).
"""

from __future__ import annotations

import math
import re
import time
from collections.abc import Callable, Iterator
from typing import Any

import httpx
import pytest

from .conftest import Server
from .test_docs_browser import (
    CHROMIUM,
    CHROMIUM_ARGS,
    RECORD_CSP_VIOLATIONS,
    Visit,
    _assert_stayed_local,
    _chromium_or_skip,
    _is_service,
    _screenshot,
)

pytestmark = pytest.mark.live

WAIT_S = 60.0
API_KEY = "demo-test-key"
STATE = "() => window.ikDemo ? window.ikDemo.state : null"


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    _chromium_or_skip()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        launched = pw.chromium.launch(
            executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS
        )
        try:
            yield launched
        finally:
            launched.close()


class DemoPage:
    """One /demo page in a fresh context, with what it requested and logged."""

    def __init__(self, browser: Any, server: Server) -> None:
        self.server = server
        self.visit = Visit()
        self.console_errors: list[str] = []
        self.websockets: list[str] = []
        self.context = browser.new_context(viewport={"width": 1280, "height": 800})
        page = self.context.new_page()
        page.add_init_script(RECORD_CSP_VIOLATIONS)
        page.on("request", lambda request: self.visit.requests.append(request.url))
        page.on("pageerror", lambda error: self.visit.page_errors.append(str(error)))
        page.on(
            "console",
            lambda message: message.type == "error" and self.console_errors.append(message.text),
        )
        # Playwright's "request" event does not include WebSockets: recorded apart.
        page.on("websocket", lambda socket: self.websockets.append(socket.url))
        page.route("**/*", self._keep_local)
        self.page = page

    def _keep_local(self, route: Any) -> None:
        if _is_service(route.request.url, self.server):
            route.continue_()
        else:
            route.abort("blockedbyclient")

    def open(self) -> None:
        self.page.goto(f"{self.server.base}/demo", wait_until="load")

    def state(self) -> dict[str, Any]:
        state: dict[str, Any] | None = self.page.evaluate(STATE)
        return state or {}

    def wait_for(self, what: str, test: Callable[[dict[str, Any]], bool]) -> dict[str, Any]:
        deadline = time.monotonic() + WAIT_S
        while time.monotonic() < deadline:
            state = self.state()
            if state and test(state):
                return state
            self.page.wait_for_timeout(100)
        # The page state without its per-frame series (thousands of numbers).
        brief = {k: v for k, v in self.state().items() if k not in ("samples", "roundTripsMs")}
        raise AssertionError(f"timed out waiting for {what}; page state: {brief}")

    def drag(self, handle: str, dx_px: float, dy_px: float) -> None:
        start = self.page.evaluate("(name) => window.ikDemo.screenOf(name)", handle)
        mouse = self.page.mouse
        mouse.move(start["x"], start["y"])
        mouse.down()
        mouse.move(start["x"] + dx_px, start["y"] + dy_px, steps=25)
        mouse.up()

    def assert_clean(self, expected_errors: str | None = None) -> None:
        """No console error (but those matching ``expected_errors``), no script error, no
        error on the page, nothing requested from another host, nothing the CSP blocked."""
        self.visit.csp_violations = self.page.evaluate("() => window.__cspViolations")
        errors = [
            e
            for e in self.console_errors
            if not (expected_errors and re.search(expected_errors, e))
        ]
        assert not errors, f"console errors: {errors}"
        assert not self.state().get("errors"), self.state()["errors"]
        _assert_stayed_local(self.visit, self.server)
        service_ws = self.server.base.replace("http://", "ws://", 1) + "/v1/sessions/"
        assert self.websockets, "the page opened no WebSocket"
        assert all(url.startswith(service_ws) for url in self.websockets), self.websockets

    def close(self) -> None:
        self.context.close()


@pytest.fixture
def demo(browser: Any, server: Server) -> Iterator[DemoPage]:
    page = DemoPage(browser, server)
    try:
        yield page
    finally:
        page.close()


def _answers_drawn(state: dict[str, Any], solved: int) -> bool:
    """At least ``solved`` answers, and one drawn: the page counts an answer when it
    arrives and reads the effectors off the scene when it draws it (a loaded machine
    may count several before the first draw)."""
    effectors = state["effectors"]
    shown = all(name in effectors for name in state["targets"] if not name.startswith("pole"))
    return state["ready"] and state["solved"] >= solved and bool(effectors) and shown


def distance(a: list[float], b: list[float]) -> float:
    return math.dist(a, b)


def test_dragging_a_hand_target_moves_the_hand(demo: DemoPage) -> None:
    demo.open()
    before = demo.wait_for("solved frames", lambda s: _answers_drawn(s, 5))
    hand_before = before["effectors"]["hand_L"]
    target_before = before["targets"]["hand_L"]
    # At rest the hand is on its target.
    assert distance(hand_before, target_before) < 0.01

    # Up and out to the character's left (screen right from this camera).
    demo.drag("hand_L", 90, -160)
    moved = demo.wait_for(
        "the target to move",
        lambda s: distance(s["targets"]["hand_L"], target_before) > 0.15,
    )
    target = moved["targets"]["hand_L"]
    frames_at_release = moved["frames"]
    after = demo.wait_for(
        "the hand to follow",
        lambda s: (
            s["frames"] >= frames_at_release + 10
            and distance(s["effectors"]["hand_L"], target) < 0.5 * distance(hand_before, target)
        ),
    )
    hand_after = after["effectors"]["hand_L"]
    assert distance(hand_after, target) < 0.05, (hand_after, target)
    # The pole handle goes with the left foot's target exactly when the server's schema
    # has a target `pole` field, and the readout says which.
    schema = httpx.get(f"{demo.server.base}/openapi.json", timeout=WAIT_S).json()
    has_poles = "pole" in schema["components"]["schemas"]["Target"]["properties"]
    assert after["poles"] is has_poles
    assert ("sent with foot_L" if has_poles else "not sent") in demo.page.inner_text("#r-pole")
    # The other limbs' targets did not move, and their effectors stayed on them.
    for name in ("hand_R", "foot_L", "foot_R"):
        assert distance(after["effectors"][name], after["targets"][name]) < 0.01, name

    readout = {
        row: demo.page.inner_text(f"#r-{row}")
        for row in ("frames", "termination", "round-trip", "solve", "server", "step", "rates")
    }
    # Solves and drawn frames are counted apart (the solve loop does not wait for drawing).
    rates = re.fullmatch(r"(\d+) solves/s, (\d+) drawn frames/s", readout["rates"])
    assert rates, readout
    assert after["samples"]["drawn"] > 0 and after["samples"]["roundTripMs"], after["samples"]
    solved, answered = map(int, readout["frames"].split(" / "))
    assert solved > 0 and answered >= solved
    assert re.fullmatch(r"\d+\.\d\d ms", readout["round-trip"]), readout
    assert re.fullmatch(r"\d+ us", readout["solve"]) and re.fullmatch(r"\d+ us", readout["server"])
    assert readout["termination"], readout
    assert after["last"]["round_trip_ms"] > 0
    _screenshot(demo.page, "demo-drag")
    demo.assert_clean()


def test_dragging_the_pole_target_swings_the_knee_towards_it(demo: DemoPage) -> None:
    """The pole handle goes with the left foot's target (`pole`, bone shin_L): with the
    knee bent, dragging the handle to one side swings the knee (shin_L's origin, as the
    page's scene graph has it after applying the answers) towards it, and the foot stays
    on its target."""
    demo.open()
    demo.wait_for("solved frames", lambda s: _answers_drawn(s, 5))
    # Lift the foot: a straight leg has no bend for the pole to choose.
    demo.drag("foot_L", 0, -100)
    lifted = demo.wait_for(
        "the foot to follow its lifted target",
        lambda s: (
            s["targets"]["foot_L"][1] > 0.25
            and distance(s["effectors"]["foot_L"], s["targets"]["foot_L"]) < 0.01
        ),
    )
    assert lifted["poles"], "this server's Target has a pole field: the page must send it"
    knee_before, pole_before = lifted["poleBone"], lifted["targets"]["pole_knee_L"]

    # The handle to the character's left (screen right from this camera).
    demo.drag("pole_knee_L", 200, 0)
    moved = demo.wait_for(
        "the pole target to move",
        lambda s: distance(s["targets"]["pole_knee_L"], pole_before) > 0.3,
    )
    pole = moved["targets"]["pole_knee_L"]
    sideways = [p - q for p, q in zip(pole, pole_before, strict=True)]
    length = math.hypot(*sideways)

    def towards_pole(state: dict[str, Any]) -> float:
        """How far the knee moved along the pole's move [m]."""
        moved_by = [p - q for p, q in zip(state["poleBone"], knee_before, strict=True)]
        return sum(m * d for m, d in zip(moved_by, sideways, strict=True)) / length

    after = demo.wait_for(
        "the knee to swing towards the pole",
        lambda s: s["frames"] >= moved["frames"] + 10 and towards_pole(s) > 0.1,
    )
    # Closer to the pole than before, and the foot still on its target: the pole chose
    # the bend, it did not pull the foot off.
    assert distance(after["poleBone"], pole) < distance(knee_before, pole) - 0.1
    assert distance(after["effectors"]["foot_L"], after["targets"]["foot_L"]) < 0.01
    assert "sent with foot_L" in demo.page.inner_text("#r-pole")
    _screenshot(demo.page, "demo-pole")
    demo.assert_clean()


def test_msgpack_compact_and_a_planned_replay(demo: DemoPage) -> None:
    demo.open()
    demo.wait_for("solved frames", lambda s: _answers_drawn(s, 3))
    demo.page.check("input[name=encoding][value=msgpack]")
    demo.page.check("#compact")
    switched = demo.wait_for(
        "frames over MessagePack, compact",
        lambda s: s["encoding"] == "msgpack" and s["compact"] and s["last"] is not None,
    )
    frames_then = switched["frames"]
    demo.wait_for("more frames", lambda s: s["frames"] >= frames_then + 5)

    demo.page.click("#record")
    demo.drag("foot_R", -60, -90)
    demo.wait_for("recorded frames", lambda s: s["frames"] >= frames_then + 30)
    demo.page.click("#record")
    demo.page.click("#replay")
    replayed = demo.wait_for("the planned clip", lambda s: s["clip"] is not None)
    clip = replayed["clip"]
    assert clip["planned"] == clip["recorded"] >= 2
    assert clip["largest_step_rad"] <= clip["tracked_largest_step_rad"] + 1e-9
    assert "dashed: planned" in demo.page.inner_text("#clip-summary")
    _screenshot(demo.page, "demo-planned-replay")
    demo.assert_clean()


def test_an_example_chain_follows_its_target(demo: DemoPage) -> None:
    """two_arm_torso has no bones: the page poses it from the answers' joint values with
    its own forward kinematics, so its hand reaching the target also checks that the
    page's kinematics agree with the server's."""
    demo.open()
    demo.wait_for("solved frames", lambda s: _answers_drawn(s, 3))
    demo.page.select_option("#model", "two_arm_torso")
    before = demo.wait_for(
        "the example chain", lambda s: s["model"] == "two_arm_torso" and s["solved"] >= 3
    )
    assert set(before["effectors"]) == {"left_hand", "right_hand"}
    assert distance(before["effectors"]["left_hand"], before["targets"]["left_hand"]) < 1e-3
    demo.drag("left_hand", 40, -50)
    moved = demo.wait_for(
        "the target to move",
        lambda s: distance(s["targets"]["left_hand"], before["targets"]["left_hand"]) > 0.05,
    )
    target = moved["targets"]["left_hand"]
    after = demo.wait_for(
        "the hand to follow",
        lambda s: (
            s["frames"] >= moved["frames"] + 10
            and distance(s["effectors"]["left_hand"], target) < 0.01
        ),
    )
    assert after["last"]["termination"]
    _screenshot(demo.page, "demo-example-chain")
    demo.assert_clean()


def test_with_api_keys_the_page_asks_for_one(
    browser: Any, start_server: Callable[..., Server]
) -> None:
    server = start_server(IK_API_KEYS=API_KEY)
    demo = DemoPage(browser, server)
    try:
        demo.open()
        demo.page.wait_for_selector("#api-key:not([hidden])", timeout=WAIT_S * 1000)
        demo.page.fill("#api-key-input", "not-the-key")
        demo.page.click("#api-key button")
        # A wrong key is refused and asked for again.
        demo.page.wait_for_selector("#api-key:not([hidden])", timeout=WAIT_S * 1000)
        demo.page.fill("#api-key-input", API_KEY)
        demo.page.click("#api-key button")
        state = demo.wait_for("solved frames", lambda s: _answers_drawn(s, 3))
        assert state["frames"] >= 3
        _screenshot(demo.page, "demo-api-key")
        # Chromium logs every 4xx answer to fetch: here the two refusals, nothing else.
        refused = r"status of 40[13] \(Unauthorized|Forbidden\)"
        assert len(demo.console_errors) == 2, demo.console_errors
        demo.assert_clean(expected_errors=refused)
    finally:
        demo.close()


def test_after_a_restart_that_lost_its_session_the_page_makes_a_new_one(
    browser: Any, tmp_path: Any
) -> None:
    # Sessions in memory: a restarted server has none, and the page's socket reconnects
    # to 4404. The page used to stop there ("not_found" for good, and a model switch
    # failed on deleting the lost session); it now makes a new session for the same
    # model, waiting while the new server answers not_ready.
    first = Server(log_path=tmp_path / "first.log")
    first.wait_ready()
    page = DemoPage(browser, first)
    second: Server | None = None
    try:
        page.open()
        page.wait_for("the page ready", lambda s: s.get("ready") is True)
        page.page.evaluate("() => window.ikDemo.startMotion()")
        page.wait_for("answers", lambda s: s["frames"] >= 20)
        first.stop()
        second = Server(port=first.port, log_path=tmp_path / "second.log")
        second.wait_ready()
        state = page.wait_for(
            "answers from a new session on the restarted server",
            lambda s: s["socket"]["open"] and _frames_answered(second) >= 30,
        )
        assert any("4404" in e for e in state["errors"]), state["errors"]
        assert state["model"] == "character"
        # Its one error on screen is the lost session's; nothing else went wrong.
        assert [e for e in state["errors"] if "4404" not in e] == [], state["errors"]
        assert not page.visit.page_errors, page.visit.page_errors
        _assert_stayed_local(page.visit, second)
    finally:
        page.close()
        if second is not None:
            second.stop()


def _frames_answered(server: Server) -> float:
    text = httpx.get(f"{server.base}/metrics", timeout=5.0).text
    return sum(
        float(line.rsplit(" ", 1)[1])
        for line in text.splitlines()
        if line.startswith("ik_frames_total{")
    )


def test_a_server_that_keeps_losing_sessions_gets_one_new_one_per_five_seconds(
    demo: DemoPage,
) -> None:
    # Every session the page makes is deleted as soon as it is made (a server that keeps
    # losing them): the recovery must not turn into a storm (it made ~8 a second).
    created: list[dict[str, Any]] = []

    def on_response(response: Any) -> None:
        if response.request.method == "POST" and response.url.endswith("/v1/sessions"):
            if response.status == 201:
                created.append(response.json())

    demo.page.on("response", on_response)
    demo.open()
    demo.wait_for("the page ready", lambda s: s.get("ready") is True)
    demo.page.evaluate("() => window.ikDemo.startMotion()")
    demo.wait_for("answers", lambda s: s["frames"] >= 10)
    before = len(created)
    deleted = 0
    deadline = time.monotonic() + 8.0
    while time.monotonic() < deadline:
        for session in created[deleted:]:
            auth = {"Authorization": f"Bearer {session['token']}"}
            httpx.delete(f"{demo.server.base}/v1/sessions/{session['id']}", headers=auth)
            deleted += 1
        demo.page.wait_for_timeout(20)
    # At once, then 5 s later (one still waiting for an answer stops the next one).
    assert 1 <= len(created) - before <= 2, len(created) - before
