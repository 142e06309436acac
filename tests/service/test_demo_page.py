"""/demo and its files: served by the service, nothing from elsewhere, licences shipped.

The page in a real browser is tests/live/test_demo_browser.py; this checks what the
service sends: the page names only its own assets, under a policy that lets the browser
load nothing from another host, and every file the bundle's README lists is there with
the sha256 it states.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable
from pathlib import Path

from fastapi.testclient import TestClient

from service.config import Settings
from service.main import create_app
from service.routes.demo import ASSETS_DIR

README = ASSETS_DIR / "README.md"


def client() -> TestClient:
    return TestClient(create_app(Settings()))


def test_the_page_loads_only_its_own_assets() -> None:
    with client() as c:
        page = c.get("/demo")
        assert page.status_code == 200
        assert page.headers["content-type"].startswith("text/html")
        policy = page.headers["content-security-policy"]
        assert "default-src 'self'" in policy and "script-src 'self'" in policy
        assert "unsafe" not in policy
        urls = re.findall(r'(?:src|href)="([^"]+)"', page.text)
        assert {u for u in urls if not u.startswith("data:")} == {
            "/demo-assets/demo.css",
            "/demo-assets/demo.js",
        }
        for url in urls:
            if url.startswith("/"):
                asset = c.get(url)
                assert asset.status_code == 200, url
                assert asset.headers["cache-control"] == "no-cache"
        assert c.get("/demo-assets/character.gltf").json()["asset"]["version"] == "2.0"


def test_the_page_follows_the_root_path() -> None:
    with TestClient(create_app(Settings()), root_path="/ik") as c:
        page = c.get("/demo").text
    assert 'src="/ik/demo-assets/demo.js"' in page and 'data-root="/ik"' in page


def test_every_shipped_file_has_the_sha256_its_readme_states() -> None:
    listed = dict(
        (name, digest)
        for digest, name in re.findall(r"^([0-9a-f]{64})  (\S+)$", README.read_text(), re.M)
        if not name.endswith(".tgz")
    )
    shipped = {p.name for p in ASSETS_DIR.iterdir() if p.name != "README.md"}
    assert set(listed) == shipped
    for name, digest in listed.items():
        assert hashlib.sha256(Path(ASSETS_DIR / name).read_bytes()).hexdigest() == digest, name


def test_the_example_chains_geometry_matches_the_sessions(
    make_client: Callable[..., TestClient],
) -> None:
    """Every DOF a session on an example chain has belongs to a joint the page draws."""
    c = make_client()
    geometry = c.get("/demo/examples.json").json()
    for name, chain in geometry.items():
        created = c.post("/v1/sessions", json={"chain": {"format": "example", "name": name}})
        assert created.status_code == 201, created.text
        drawn = set()
        for joint in chain["joints"]:
            if joint["kind"] == "rotational":
                drawn |= {f"{joint['name']}.{axis}" for axis in joint["axes"]}
            elif joint["kind"] != "fixed":
                drawn.add(joint["name"])
        assert drawn == {d["name"] for d in created.json()["dof"]}, name
        assert [e["name"] for e in chain["effectors"]] == [
            e["name"] for e in created.json()["effectors"]
        ]
