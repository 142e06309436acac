"""/docs and /redoc in a real headless Chromium: the operations render, nothing leaves 127.0.0.1.

Debian's Chromium (/usr/bin/chromium) driven by Playwright; no browser is downloaded.
Every request the browser starts is recorded (and any not for the service is aborted, so
the test itself never reaches the internet). Chromium also reports requests that the
pages' Content-Security-Policy refused before they were sent (failure "csp": the
Redocly logo ReDoc 2 hard-codes); those never leave the browser and are listed apart. The
CSP reports are collected too: a policy too strict for the UIs would show up as a blocked
script, style, worker or fetch. Screenshots go to tests/live/artifacts/ (git-ignored).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import httpx
import pytest

from .conftest import Server

pytestmark = pytest.mark.live

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parent / "artifacts"
# No GPU or QUIC, none of Chromium's own background traffic (component updates, sync,
# safe browsing lists), and no sandbox (tests and CI run as root, in containers).
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
RENDER_TIMEOUT_MS = 60_000
HTTP_METHODS = {"get", "put", "post", "delete", "options", "head", "patch", "trace"}
RECORD_CSP_VIOLATIONS = """
window.__cspViolations = [];
document.addEventListener("securitypolicyviolation", (e) => {
  window.__cspViolations.push({directive: e.effectiveDirective, blocked: e.blockedURI});
});
"""
# Directives whose refusal would break the page (as opposed to a decorative image).
NEEDED_DIRECTIVES = {
    "script-src-elem",
    "script-src",
    "style-src-elem",
    "style-src",
    "worker-src",
    "connect-src",
    "font-src",
}


def _chromium_or_skip() -> None:
    """Skip without Chromium or Playwright, except in CI (CI=true), where that fails."""
    missing = []
    if not CHROMIUM.exists():
        missing.append(f"{CHROMIUM} (apt-get install chromium)")
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        missing.append("the playwright package (pip install -e '.[test]')")
    if not missing:
        return
    reason = "browser test needs " + " and ".join(missing)
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason}; CI=true, so this is a failure, not a skip", pytrace=False)
    pytest.skip(reason)


@dataclass
class Visit:
    """What one page load did: requests started, CSP refusals, script errors."""

    requests: list[str] = field(default_factory=list)
    refused_by_csp: set[str] = field(default_factory=set)
    csp_violations: list[dict[str, str]] = field(default_factory=list)
    page_errors: list[str] = field(default_factory=list)


def _is_service(url: str, server: Server) -> bool:
    parts = urlsplit(url)
    if parts.scheme in ("data", "blob"):
        return True  # in-page, never a network request
    return f"{parts.scheme}://{parts.netloc}" == server.base


@pytest.fixture(scope="module")
def browser_context(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    _chromium_or_skip()
    from playwright.sync_api import sync_playwright

    profile = tmp_path_factory.mktemp("chromium-profile")  # fresh user data dir
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile),
            executable_path=str(CHROMIUM),
            headless=True,
            args=CHROMIUM_ARGS,
            viewport={"width": 1280, "height": 1600},
        )
        try:
            yield context
        finally:
            context.close()


def _visit(context: Any, server: Server, path: str, ready_selector: str) -> tuple[Any, Visit]:
    visit = Visit()

    def failed(request: Any) -> None:
        # Playwright names Chromium's net::ERR_BLOCKED_BY_CSP "csp".
        if request.failure in ("csp", "net::ERR_BLOCKED_BY_CSP"):
            visit.refused_by_csp.add(request.url)

    def keep_local(route: Any) -> None:
        # Recorded by the "request" handler below either way; aborted here so that a
        # regression shows up as a failed assertion, not as traffic to the internet.
        if _is_service(route.request.url, server):
            route.continue_()
        else:
            route.abort("blockedbyclient")

    page = context.new_page()
    page.add_init_script(RECORD_CSP_VIOLATIONS)
    page.on("request", lambda request: visit.requests.append(request.url))
    page.on("requestfailed", failed)
    page.route("**/*", keep_local)
    page.on("pageerror", lambda error: visit.page_errors.append(str(error)))
    page.goto(f"{server.base}{path}", wait_until="load", timeout=RENDER_TIMEOUT_MS)
    page.wait_for_selector(ready_selector, state="attached", timeout=RENDER_TIMEOUT_MS)
    page.wait_for_load_state("networkidle", timeout=RENDER_TIMEOUT_MS)
    visit.csp_violations = page.evaluate("window.__cspViolations")
    return page, visit


def _screenshot(page: Any, name: str) -> Path:
    ARTIFACTS.mkdir(exist_ok=True)
    path = ARTIFACTS / f"{name}.png"
    page.screenshot(path=str(path))
    print(f"screenshot: {path}")
    return path


def _spec_operations(server: Server) -> set[tuple[str, str]]:
    spec = httpx.get(f"{server.base}/openapi.json", timeout=10.0).json()
    return {
        (method.upper(), path)
        for path, item in spec["paths"].items()
        for method in item
        if method in HTTP_METHODS
    }


def _assert_stayed_local(visit: Visit, server: Server) -> None:
    sent = set(visit.requests) - visit.refused_by_csp
    elsewhere = sorted(url for url in sent if not _is_service(url, server))
    assert not elsewhere, f"requests to hosts other than {server.base}: {elsewhere}"
    broken = [v for v in visit.csp_violations if v["directive"] in NEEDED_DIRECTIVES]
    assert not broken, f"the CSP blocked something the page needs: {broken}"
    assert not visit.page_errors, f"script errors: {visit.page_errors}"
    print(f"{len(sent)} requests sent, all to {server.base}: {sorted(sent)}")
    if visit.refused_by_csp:
        print(f"refused by the CSP, never sent: {sorted(visit.refused_by_csp)}")


def test_swagger_ui_renders_every_operation_offline(browser_context: Any, server: Server) -> None:
    page, visit = _visit(browser_context, server, "/docs", ".opblock")
    try:
        shown = {
            (
                block.query_selector(".opblock-summary-method").inner_text().strip(),
                block.query_selector(".opblock-summary-path").get_attribute("data-path"),
            )
            for block in page.query_selector_all(".opblock")
        }
        icon = page.eval_on_selector("link[rel~='icon']", "link => link.href")
        _screenshot(page, "swagger-ui")
    finally:
        page.close()
    assert ("POST", "/v1/sessions") in shown
    assert shown == _spec_operations(server)
    assert _is_service(icon, server), icon
    assert f"{server.base}/openapi.json" in visit.requests
    _assert_stayed_local(visit, server)


def test_redoc_renders_every_operation_offline(browser_context: Any, server: Server) -> None:
    operation = "li[data-item-id*='/operation/']"
    page, visit = _visit(browser_context, server, "/redoc", operation)
    try:
        # The side menu is an accordion: open each tag in turn and read the operations
        # it shows (so they are rendered, visible, and the menu answers clicks).
        methods: list[str] = []
        tags = [
            item.get_attribute("data-item-id")
            for item in page.query_selector_all(f"li[data-item-id^='tag/']:not({operation})")
        ]
        for tag in reversed(tags):  # ends with the first tag open, for the screenshot
            page.click(f"li[data-item-id='{tag}'] > label")
            in_tag = f"li[data-item-id^='{tag}/operation/'] .operation-type"
            page.wait_for_selector(in_tag, timeout=RENDER_TIMEOUT_MS)
            methods += [
                item.get_attribute("type").upper()  # the text shortens DELETE to "del"
                for item in page.query_selector_all(in_tag)
                if item.is_visible()
            ]
        sections = page.query_selector_all("[data-section-id*='/operation/']")
        icon = page.eval_on_selector("link[rel~='icon']", "link => link.href")
        _screenshot(page, "redoc")
    finally:
        page.close()
    spec = _spec_operations(server)
    assert sorted(methods) == sorted(method for method, _ in spec)
    assert len(sections) == len(spec)
    assert _is_service(icon, server), icon
    assert f"{server.base}/openapi.json" in visit.requests
    _assert_stayed_local(visit, server)
