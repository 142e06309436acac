"""/docs (Swagger UI), /redoc and /asyncapi.json (the WebSocket's AsyncAPI 3 document),
with every script, style and icon served by the service itself.

FastAPI's default pages load their scripts, styles, favicon and (ReDoc) Google fonts from
public CDNs, so without internet they are blank. This follows FastAPI's "Custom Docs UI
Static Assets (Self-Hosting)" recipe: the app is built with ``docs_url=None,
redoc_url=None`` and :func:`add_docs` adds the same pages built by
``get_swagger_ui_html`` / ``get_redoc_html`` pointing at copies of the npm packages'
files under ``service/docs_assets/`` (see its README for versions and sha256).

Caching: asset URLs carry the package version (``/docs-assets/redoc-2.5.4/...``), so a
file at a URL never changes and is served with a one-year ``immutable`` max-age (no
revalidation round trip on every page view; an upgrade is a new URL). Starlette's
ETag/Last-Modified stay for the rare revalidation. The two HTML pages are ``no-cache``
so that they always name the current asset versions.

The pages also carry a Content-Security-Policy that lets the browser fetch only from the
service itself: ReDoc 2.x hard-codes one decorative image from cdn.redoc.ly (the Redocly
logo in its sidebar footer), which the browser then refuses instead of trying the
network; it also keeps any future asset upgrade from reaching out silently.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

from fastapi import FastAPI, Request
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import HTMLResponse

from ..asyncapi import asyncapi_document
from ..responses import CachedStaticFiles, ORJSONResponse, content_security_policy

ASSETS_DIR: Final = Path(__file__).resolve().parent.parent / "docs_assets"
ASSETS_URL: Final = "/docs-assets"
# Folder names under docs_assets/: "<npm package>-<version>", also the URL segment.
SWAGGER_UI: Final = "swagger-ui-dist-5.35.0"
REDOC: Final = "redoc-2.5.4"

DOCS_URL: Final = "/docs"
REDOC_URL: Final = "/redoc"
OAUTH2_REDIRECT_URL: Final = "/docs/oauth2-redirect"
# The WebSocket protocol (AsyncAPI 3), next to /openapi.json (service/asyncapi.py).
ASYNCAPI_URL: Final = "/asyncapi.json"

# The assets' URLs carry their version: cacheable for a year without revalidation.
IMMUTABLE: Final = "public, max-age=31536000, immutable"
# 'unsafe-inline' scripts: FastAPI's Swagger page starts the UI from an inline <script>.
# 'unsafe-inline' styles: both UIs style elements inline at run time (ReDoc through
# styled-components). blob: workers: ReDoc runs its search index in a Worker built from
# a Blob. data: images: Swagger UI's CSS embeds its icons as data: URLs.
CONTENT_SECURITY_POLICY: Final = content_security_policy(
    script_src="'unsafe-inline'",
    style_src="'unsafe-inline'",
    img_src="data:",
    font_src="data:",
    worker_src="blob:",
)
_PAGE_HEADERS: Final = {
    "Cache-Control": "no-cache",
    "Content-Security-Policy": CONTENT_SECURITY_POLICY,
}


def asset_url(root_path: str, package: str, name: str) -> str:
    return f"{root_path}{ASSETS_URL}/{package}/{name}"


def add_docs(app: FastAPI) -> None:
    """Add /docs, /docs/oauth2-redirect, /redoc and the assets they load to ``app``.

    ``app`` must be built with ``docs_url=None, redoc_url=None`` (else FastAPI adds its
    CDN pages first and those win) and with an ``openapi_url``.
    """
    openapi_url = app.openapi_url
    if openapi_url is None:
        raise ValueError("the docs pages need the app's openapi_url")
    if app.docs_url is not None or app.redoc_url is not None:
        raise ValueError("build the app with docs_url=None, redoc_url=None")

    # Every URL is prefixed with the ASGI root_path, as FastAPI's own pages do, so the
    # pages also work behind a proxy that mounts the service under a prefix.
    async def swagger_ui(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        page = get_swagger_ui_html(
            openapi_url=root + openapi_url,
            title=f"{app.title} - Swagger UI",
            oauth2_redirect_url=root + OAUTH2_REDIRECT_URL,
            swagger_js_url=asset_url(root, SWAGGER_UI, "swagger-ui-bundle.js"),
            swagger_css_url=asset_url(root, SWAGGER_UI, "swagger-ui.css"),
            swagger_favicon_url=asset_url(root, SWAGGER_UI, "favicon-32x32.png"),
            # No badge that sends the spec to validator.swagger.io.
            swagger_ui_parameters={"validatorUrl": None},
        )
        page.headers.update(_PAGE_HEADERS)
        return page

    async def swagger_ui_redirect(request: Request) -> HTMLResponse:
        page = get_swagger_ui_oauth2_redirect_html()
        page.headers.update(_PAGE_HEADERS)
        return page

    async def redoc(request: Request) -> HTMLResponse:
        root = request.scope.get("root_path", "")
        page = get_redoc_html(
            openapi_url=root + openapi_url,
            title=f"{app.title} - ReDoc",
            redoc_js_url=asset_url(root, REDOC, "redoc.standalone.js"),
            redoc_favicon_url=asset_url(root, SWAGGER_UI, "favicon-32x32.png"),
            with_google_fonts=False,
        )
        page.headers.update(_PAGE_HEADERS)
        return page

    async def asyncapi(request: Request) -> ORJSONResponse:
        return ORJSONResponse(asyncapi_document(title=app.title, version=app.version))

    app.add_route(DOCS_URL, swagger_ui, include_in_schema=False)
    app.add_route(ASYNCAPI_URL, asyncapi, include_in_schema=False)
    app.add_route(OAUTH2_REDIRECT_URL, swagger_ui_redirect, include_in_schema=False)
    app.add_route(REDOC_URL, redoc, include_in_schema=False)
    app.mount(
        ASSETS_URL,
        CachedStaticFiles(directory=ASSETS_DIR, cache_control=IMMUTABLE),
        name="docs-assets",
    )
