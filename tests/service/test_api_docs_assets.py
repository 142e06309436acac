"""/docs and /redoc name only the service's own assets, which are served and cacheable.

The real browser check (rendering, every request the page makes) is
tests/live/test_docs_browser.py; this one is the fast check of the HTML and headers.
"""

from __future__ import annotations

import hashlib
import re
from pathlib import Path

import pytest
from starlette.testclient import TestClient

from service.routes import docs

# src/href/spec-url="..." in the pages, and the url: '...' Swagger UI loads the spec from.
REFERENCE = re.compile(r"""(?:src|href|spec-url)="([^"]+)"|url: '([^']+)'""")


def _references(html: str) -> list[str]:
    return [src or url for src, url in REFERENCE.findall(html)]


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_page_loads_nothing_from_other_hosts(client: TestClient, page: str) -> None:
    response = client.get(page)
    assert response.status_code == 200
    references = _references(response.text)
    assert len(references) >= 3  # script, favicon, spec (and Swagger UI's stylesheet)
    assert all(ref.startswith("/") and not ref.startswith("//") for ref in references), references
    assert "googleapis" not in response.text
    # The HTML is revalidated so that it always names the current asset versions; the
    # browser may fetch only from the service itself.
    assert response.headers["cache-control"] == "no-cache"
    assert "default-src 'self'" in response.headers["content-security-policy"]
    for ref in references:
        assert client.get(ref).status_code == 200, ref


def test_assets_are_cached_for_a_year_and_revalidate(client: TestClient) -> None:
    url = docs.asset_url("", docs.REDOC, "redoc.standalone.js")
    first = client.get(url)
    assert first.status_code == 200
    assert first.headers["cache-control"] == "public, max-age=31536000, immutable"
    assert first.headers["content-type"].startswith("text/javascript")
    again = client.get(url, headers={"If-None-Match": first.headers["etag"]})
    assert again.status_code == 304
    assert again.headers["cache-control"] == "public, max-age=31536000, immutable"


def test_unknown_asset_is_a_json_404(client: TestClient) -> None:
    response = client.get(docs.asset_url("", docs.SWAGGER_UI, "no-such-file.js"))
    assert response.status_code == 404
    assert response.json()["code"] == "not_found"


def test_asset_files_match_the_recorded_sha256() -> None:
    """The README's sha256 lines cover every vendored file (and nothing is missing)."""
    readme = (docs.ASSETS_DIR / "README.md").read_text()
    recorded = dict(
        (name, digest) for digest, name in re.findall(r"^([0-9a-f]{64})  (\S+/\S+)$", readme, re.M)
    )
    on_disk = {
        str(path.relative_to(docs.ASSETS_DIR)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(docs.ASSETS_DIR.glob("*/*"))
        if path.is_file()
    }
    assert {Path(name).parent.name for name in on_disk} == {docs.SWAGGER_UI, docs.REDOC}
    assert on_disk == recorded
