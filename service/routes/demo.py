"""/demo: a character and draggable targets in the browser, solved over the WebSocket.

Everything the page loads comes from the service: ``service/demo_assets/`` holds the
page's scripts (``demo.js``: the page, the TypeScript client and three.js;
``demo-worker.js``: its solve loop, a worker that owns the WebSocket; both bundled by
esbuild from ``clients/demo/``; versions, licences and sha256 in that folder's README),
its stylesheet and the character's skeleton (``character.gltf``, made for the demo). No
CDN, no build step at install or start: a fresh clone serves the page offline.

The assets are not versioned in their URLs (the bundle is rebuilt in place), so they are
served with ``no-cache``: the browser revalidates with the ETag starlette sets, and a
rebuilt bundle is picked up at the next load.
"""

from __future__ import annotations

import html
from pathlib import Path
from typing import Final

from fastapi import FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse

from solver.model.chain import Chain
from solver.model.examples import EXAMPLES
from solver.model.joints import Transform
from solver.model.rotations import matrix_to_quaternion

from ..responses import CachedStaticFiles, content_security_policy

ASSETS_DIR: Final = Path(__file__).resolve().parent.parent / "demo_assets"
ASSETS_URL: Final = "/demo-assets"
DEMO_URL: Final = "/demo"
EXAMPLES_URL: Final = "/demo/examples.json"

# The page runs only its own bundle ('self', no inline script); three.js needs no inline
# style, but the page's own code sets element styles through the CSSOM, which CSP allows.
# connect-src 'self' covers fetch and the same host's ws:// (CSP Level 3).
CONTENT_SECURITY_POLICY: Final = content_security_policy(img_src="data: blob:")

_PAGE: Final = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>IK service demo</title>
<link rel="icon" href="data:,">
<link rel="stylesheet" href="{root}{assets}/demo.css">
<script type="module" src="{root}{assets}/demo.js"></script>
</head>
<body data-root="{root}" data-assets="{root}{assets}">
<div id="view"></div>
<aside id="panel">
  <h1>IK service demo</h1>
  <p class="hint">Drag the coloured targets (hands, feet); drag elsewhere to turn the view.</p>
  <form id="api-key" hidden>
    <label>This server needs an API key
      <input id="api-key-input" type="password" autocomplete="off" required></label>
    <button type="submit">Use key</button>
  </form>
  <fieldset>
    <legend>Model</legend>
    <select id="model"></select>
  </fieldset>
  <fieldset>
    <legend>Socket</legend>
    <label><input type="radio" name="encoding" value="json" checked> JSON</label>
    <label><input type="radio" name="encoding" value="msgpack"> MessagePack</label>
    <label><input type="checkbox" id="compact"> compact results</label>
  </fieldset>
  <fieldset>
    <legend>Planned clips</legend>
    <button id="record" type="button">Record a drag</button>
    <button id="replay" type="button" disabled>Replay it planned</button>
    <canvas id="paths" width="300" height="160"></canvas>
    <p id="clip-summary" class="hint"></p>
  </fieldset>
  <table id="readout">
    <tr><th>status</th><td id="r-status">starting</td></tr>
    <tr><th>frames solved</th><td id="r-frames">0</td></tr>
    <tr><th>rates</th><td id="r-rates"></td></tr>
    <tr><th>termination</th><td id="r-termination"></td></tr>
    <tr><th>solve_us</th><td id="r-solve"></td></tr>
    <tr><th>server_us</th><td id="r-server"></td></tr>
    <tr><th>round trip</th><td id="r-round-trip"></td></tr>
    <tr><th>p50 / p99 (last 600)</th><td id="r-percentiles"></td></tr>
    <tr><th>largest joint step</th><td id="r-step"></td></tr>
    <tr><th>pole target</th><td id="r-pole"></td></tr>
  </table>
</aside>
</body>
</html>
"""


def _frame(transform: Transform) -> dict[str, list[float]]:
    return {
        "translation": [float(c) for c in transform.translation],
        "rotation": [float(c) for c in matrix_to_quaternion(transform.rotation)],
    }


def example_geometry() -> dict[str, object]:
    """The built-in example chains' joints and effectors, for the page to draw them:
    ``link = parent * origin * Tr(pivot) * motion(q) * Tr(-pivot)`` (solver/model/chain.py),
    in the chains' own frame (Z up, metres)."""
    out: dict[str, object] = {}
    for name, build in EXAMPLES.items():
        chain: Chain = build()  # type: ignore[operator]  # EXAMPLES' builders differ in signature
        out[name] = {
            "joints": [
                {
                    "name": j.name,
                    "parent": j.parent,
                    "child": j.child,
                    "kind": j.kind.value,
                    "origin": _frame(j.origin),
                    "pivot": [float(c) for c in j.pivot],
                    "axis": [float(c) for c in j.axis],
                    "axes": j.axes,
                }
                for j in chain.joints
            ],
            "effectors": [
                {
                    "name": e.name,
                    "link": e.link,
                    "mode": e.mode.value,
                    "tip": _frame(Transform(e.tip_offset, e.tip_rotation)),
                }
                for e in chain.effectors
            ],
        }
    return out


def demo_page(root_path: str) -> str:
    """The page's HTML, its URLs under ``root_path`` (a proxy's prefix, or "")."""
    return _PAGE.format(root=html.escape(root_path, quote=True), assets=ASSETS_URL)


def add_demo(app: FastAPI) -> None:
    """Add /demo and the files it loads (/demo-assets/...) to ``app``."""

    async def demo(request: Request) -> HTMLResponse:
        page = HTMLResponse(demo_page(request.scope.get("root_path", "")))
        page.headers["Cache-Control"] = "no-cache"
        page.headers["Content-Security-Policy"] = CONTENT_SECURITY_POLICY
        return page

    geometry = example_geometry()

    async def examples(request: Request) -> JSONResponse:
        return JSONResponse(geometry, headers={"Cache-Control": "no-cache"})

    app.add_route(DEMO_URL, demo, include_in_schema=False)
    app.add_route(EXAMPLES_URL, examples, include_in_schema=False)
    app.mount(
        ASSETS_URL,
        CachedStaticFiles(directory=ASSETS_DIR, cache_control="no-cache"),
        name="demo-assets",
    )
