"""The nginx front of docs/operations.md, run for real: the block the page shows,
taken from the page itself, in front of a real uvicorn on 127.0.0.1. It must pass
the config test, carry sessions and WebSocket frames, and name each client to the
worker by the address nginx saw, whatever X-Forwarded-For the client wrote (the
per-address limits depend on it).

Clients take distinct loopback addresses (127.0.0.21, ...), as in test_forwarded.py,
so that each has buckets of its own in the shared server.
"""

from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import httpx
import orjson
import pytest
import yaml  # PyYAML, installed with schemathesis (the test extra)
from websockets.sync.client import connect

from loadtest.cluster import free_port

from .conftest import Server
from .test_forwarded import LIMIT, _creates, _from, _logged
from .test_server import PANDA, TIMEOUT_S

pytestmark = pytest.mark.live

ROOT = Path(__file__).resolve().parents[2]
# The documented upstream, replaced by the test worker's port.
DOC_UPSTREAM = "127.0.0.1:8000"


def documented_server_block() -> str:
    """The ```nginx block of docs/operations.md (the one a reader copies)."""
    text = (ROOT / "docs/operations.md").read_text()
    (block,) = re.findall(r"```nginx\n(.*?)```", text, flags=re.DOTALL)
    return block


def nginx_config(block: str, listen: int, upstream: int, work: Path) -> str:
    """A whole nginx.conf around the documented block: the ``map`` its text asks for,
    a loopback ``listen``, temporary paths of this test's own (no root needed)."""
    assert DOC_UPSTREAM in block
    server = block.replace(DOC_UPSTREAM, f"127.0.0.1:{upstream}")
    server = server.replace("server {", f"server {{\n    listen 127.0.0.1:{listen};", 1)
    temp = "\n".join(
        f"    {kind}_temp_path {work / kind};"
        for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
    )
    return f"""
pid {work / "nginx.pid"};
error_log {work / "error.log"} notice;
worker_processes 1;
events {{ worker_connections 256; }}
http {{
    access_log off;
{temp}
    map $http_upgrade $connection_upgrade {{ default upgrade; '' close; }}
{server}
}}
"""


def ingress_server_block() -> str:
    """deploy/k8s/ik.yaml's Ingress as ingress-nginx renders what it adds: an upstream
    hashed by its ``upstream-hash-by``, its ``configuration-snippet`` inside ``location
    /`` (no ingress controller runs here; this runs the snippet's nginx for real)."""
    docs = yaml.safe_load_all((ROOT / "deploy/k8s/ik.yaml").read_text())
    (ingress,) = [d for d in docs if d and d["kind"] == "Ingress"]
    annotations = ingress["metadata"]["annotations"]
    snippet = annotations["nginx.ingress.kubernetes.io/configuration-snippet"]
    hash_by = annotations["nginx.ingress.kubernetes.io/upstream-hash-by"]
    return f"""upstream ik {{ hash {hash_by} consistent; server {DOC_UPSTREAM}; }}
server {{
    location / {{
{snippet}
        proxy_pass http://ik;
    }}
}}
"""


def nginx_program() -> str:
    found = shutil.which("nginx", path=f"{os.environ.get('PATH', '')}:/usr/sbin")
    if found is not None:
        return found
    if os.environ.get("CI") == "true":
        pytest.fail("nginx not installed; CI=true, so this is a failure", pytrace=False)
    pytest.skip("nginx not installed (.ci/run installs nginx-light)")


class Nginx:
    """nginx in the foreground on a free loopback port, in front of ``upstream``."""

    def __init__(self, upstream: int, block: str | None = None) -> None:
        program = nginx_program()
        block = documented_server_block() if block is None else block
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self._dir = tempfile.TemporaryDirectory(prefix="ik-nginx-")
        work = Path(self._dir.name)
        self.conf = work / "nginx.conf"
        self.conf.write_text(nginx_config(block, self.port, upstream, work))
        checked = subprocess.run(
            [program, "-t", "-c", str(self.conf)], capture_output=True, text=True, timeout=30
        )
        assert checked.returncode == 0, checked.stderr
        self.proc = subprocess.Popen(
            [program, "-c", str(self.conf), "-g", "daemon off;"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 10
        while True:
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    break
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                raise AssertionError("nginx did not start listening")
            time.sleep(0.05)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)
        self._dir.cleanup()


@pytest.fixture(scope="module")
def worker(start_server: Callable[..., Server]) -> Server:
    # As the page says: the worker believes X-Forwarded-For from nginx on 127.0.0.1.
    return start_server(
        IK_FORWARDED_ALLOW_IPS="127.0.0.1", IK_SESSIONS_PER_ADDRESS_PER_MIN=str(LIMIT)
    )


@pytest.fixture(scope="module")
def nginx(worker: Server) -> Iterator[Nginx]:
    front = Nginx(worker.port)
    try:
        yield front
    finally:
        front.stop()


def test_through_nginx_each_client_has_its_own_limit(worker: Server, nginx: Nginx) -> None:
    # Both clients write the same address in a header of their own: nginx replaces it
    # with the address it saw (proxy_set_header X-Forwarded-For $remote_addr).
    for address in ("127.0.0.21", "127.0.0.22"):
        with _from(address) as client:
            assert _creates(client, nginx.base, "192.0.2.9", LIMIT + 1) == [201] * LIMIT + [429]
        assert _logged(worker, f'{address}:0 - "POST /v1/sessions HTTP/1.1" 201')
    assert "192.0.2.9" not in worker.log()


def test_through_nginx_a_websocket_streams_and_sees_its_client(
    worker: Server, nginx: Nginx
) -> None:
    """The upgrade passes (``location /v1/``'s Upgrade and Connection), a frame is
    solved and answered through it, and the worker names the client nginx saw, not the
    address in the client's own header (that location sets X-Forwarded-For again)."""
    with _from("127.0.0.23") as client:
        r = client.post(f"{nginx.base}/v1/sessions", json={"chain": PANDA})
        assert r.status_code == 201, r.text
        sid, token = r.json()["id"], r.json()["token"]
        # The target: the pose the session starts in, moved 2 cm along x.
        fk = client.post(f"{nginx.base}/v1/sessions/{sid}/fk", json={}, headers=_auth(token))
        assert fk.status_code == 200, fk.text
    (effector,) = fk.json()["effectors"]
    position = effector["position"]
    target = {
        "effector": effector["name"],
        "position": {**position, "x": position["x"] + 0.02},
        "orientation": effector["orientation"],
    }
    sock = socket.socket()
    sock.settimeout(TIMEOUT_S)
    sock.bind(("127.0.0.23", 0))
    sock.connect(("127.0.0.1", nginx.port))
    url = nginx.base.replace("http", "ws", 1) + f"/v1/sessions/{sid}/ws"
    headers = {**_auth(token), "X-Forwarded-For": "198.51.100.23"}
    with connect(url, sock=sock, additional_headers=headers, open_timeout=TIMEOUT_S) as ws:
        ws.send(orjson.dumps({"type": "frame", "id": 1, "targets": [target]}).decode())
        answer = orjson.loads(ws.recv(timeout=TIMEOUT_S))
    assert answer["type"] == "result", answer
    assert answer["id"] == 1
    assert answer["result"]["status"] == "solved", answer
    assert _logged(worker, f'127.0.0.23:0 - "WebSocket /v1/sessions/{sid}/ws" [accepted]')
    assert "198.51.100.23" not in worker.log()


def _auth(token: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {token}"}


def test_the_ingress_snippet_routes_sessions_and_keeps_metrics_inside(worker: Server) -> None:
    """The Ingress's nginx (its hash and snippet, run in a real nginx): a session's
    calls pass, /metrics (one pod's figures, anyone's to read through the ingress) is
    refused, also percent-encoded; the pod still serves it to a scraper."""
    ingress = Nginx(worker.port, ingress_server_block())
    try:
        r = httpx.post(f"{ingress.base}/v1/sessions", json={"chain": PANDA}, timeout=TIMEOUT_S)
        assert r.status_code == 201, r.text
        sid, token = r.json()["id"], r.json()["token"]
        got = httpx.get(f"{ingress.base}/v1/sessions/{sid}", headers=_auth(token), timeout=5)
        assert got.status_code == 200 and got.json()["id"] == sid
        for path in ("/metrics", "/%6detrics", "/metrics?name=ik_websockets"):
            assert httpx.get(httpx.URL(ingress.base + path), timeout=5).status_code == 404, path
        assert httpx.get(f"{ingress.base}/readyz", timeout=5).status_code == 200
        assert httpx.get(f"{worker.base}/metrics", timeout=5).status_code == 200
    finally:
        ingress.stop()
