"""Every request example shown in /docs works when sent as is."""

from __future__ import annotations

from typing import Any

import pytest
from starlette.testclient import TestClient

from .helpers import create


def _examples(client: TestClient, path: str, method: str) -> dict[str, Any]:
    spec = client.get("/openapi.json").json()
    content = spec["paths"][path][method]["requestBody"]["content"]["application/json"]
    examples: dict[str, Any] = content.get("examples", {})
    return {name: ex["value"] for name, ex in examples.items()}


def test_create_session_examples(client: TestClient) -> None:
    examples = _examples(client, "/v1/sessions", "post")
    assert set(examples) == {"hierarchy", "example", "urdf", "gltf", "bvh"}
    for name, body in examples.items():
        r = client.post("/v1/sessions", json=body)
        assert r.status_code == 201, (name, r.text)


@pytest.mark.parametrize("name", ["frame", "clip", "planned clip", "panda"])
def test_frames_examples(client: TestClient, name: str) -> None:
    body = _examples(client, "/v1/sessions/{session_id}/frames", "post")[name]
    chain = {"format": "example", "name": "panda_arm"} if name == "panda" else None
    s = create(client, chain)
    r = client.post(f"/v1/sessions/{s.id}/frames", json=body, headers=s.headers)
    assert r.status_code == 200, r.text
    assert all(x["success"] for x in r.json()["results"]), r.text


def test_schema_examples_of_solve_and_session(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    schemas = spec["components"]["schemas"]
    (solve_body,) = schemas["SolveRequest"]["examples"]
    r = client.post("/v1/solve", json=solve_body)
    assert r.status_code == 200 and r.json()["success"] is True
    (create_body,) = schemas["SessionCreate"]["examples"]
    s = client.post("/v1/sessions", json=create_body)
    assert s.status_code == 201
    h = {"Authorization": f"Bearer {s.json()['token']}"}
    sid = s.json()["id"]
    for example in schemas["PoseIn"]["examples"]:
        assert client.put(f"/v1/sessions/{sid}/pose", json=example, headers=h).status_code == 200
    for example in schemas["OptionsPatch"]["examples"]:
        assert client.patch(f"/v1/sessions/{sid}", json=example, headers=h).status_code == 200


def test_chains_page_hierarchy_example_creates_a_session(client: TestClient) -> None:
    import json
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[2] / "docs" / "chains.md").read_text()
    m = re.search(r"<!-- hierarchy-example:start -->\s*```json\n(.*?)```", page, re.DOTALL)
    assert m is not None
    chain = json.loads(m.group(1))
    s = create(client, chain)
    assert [d["name"] for d in s.body["dof"]] == ["shoulder.z", "shoulder.y", "elbow"]
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"targets": [{"effector": "hand", "position": {"x": 0.3, "y": 0.1, "z": 0.6}}]},
        headers=s.headers,
    )
    assert r.json()["results"][0]["success"] is True


def test_engines_page_session_and_frames_work_in_every_preset(client: TestClient) -> None:
    import json
    import re
    from pathlib import Path

    page = (Path(__file__).resolve().parents[2] / "docs" / "engines.md").read_text()

    def block(name: str) -> str:
        m = re.search(rf"<!-- {name}:start -->\s*```json\n(.*?)```", page, re.DOTALL)
        assert m is not None, name
        return m.group(1)

    session = json.loads(block("engines-session"))
    frames = [json.loads(line) for line in block("engines-frames").splitlines() if line]
    assert {f["preset"] for f in frames} == {"unity", "unreal", "godot", "threejs"}
    q = []
    for example in frames:
        # No deadline: the poses are compared across sessions (busy shared test cores).
        body = {
            **session,
            "conventions": {"preset": example["preset"]},
            "options": {"time_budget_us": 50_000},
        }
        s = client.post("/v1/sessions", json=body)
        assert s.status_code == 201, s.text
        url, headers = (
            f"/v1/sessions/{s.json()['id']}/ws",
            {"Authorization": f"Bearer {s.json()['token']}"},
        )
        with client.websocket_connect(url, headers=headers) as ws:
            ws.send_json(example["frame"])
            answer = ws.receive_json()
        assert answer["success"] is True, (example, answer)
        assert set(answer["result"]["bones"]["local"]) == {"hip", "knee"}
        q.append(answer["result"]["q"])
    # The same physical point in every convention: the same pose.
    assert all(abs(a - b) < 1e-6 for row in q for a, b in zip(row, q[0], strict=True))
