"""A session's continuity policy over HTTP and the WebSocket: ``continuity`` and
``max_joint_step_rad`` in the options, ``largest_step_rad`` and ``jumped`` in every
result (solver side: tests/solver/test_continuity.py)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from starlette.testclient import TestClient

import schemas as S

from .helpers import Created, create

# One revolute joint in [-3, 3] turning a 1 m link: from q = 2.9, the target at angle
# -2.9 needs a 5.8 rad turn (the short way, through +-pi, is outside the limits).
DIAL: dict[str, Any] = {
    "format": "hierarchy",
    "joints": [
        {
            "name": "turn",
            "parent": "base",
            "child": "link",
            "kind": "revolute",
            "axis": {"x": 0.0, "y": 0.0, "z": 1.0},
            "lower": [-3.0],
            "upper": [3.0],
        },
        {
            "name": "tip",
            "parent": "link",
            "child": "hand",
            "kind": "fixed",
            "origin": {"translation": {"x": 1.0, "y": 0.0, "z": 0.0}},
        },
    ],
    "effectors": [{"name": "hand", "link": "hand", "mode": "position"}],
}
# A generous budget: what a frame finds must not depend on how busy the machine is.
OPTIONS = {"max_joint_step_rad": 0.1, "time_budget_us": 50_000.0}


def at_angle(a: float, frame_id: int) -> dict[str, Any]:
    position = {"x": math.cos(a), "y": math.sin(a), "z": 0.0}
    return {"id": frame_id, "targets": [{"effector": "hand", "position": position}]}


def dial_session(client: TestClient, continuity: str) -> Created:
    return create(
        client,
        DIAL,
        options={**OPTIONS, "continuity": continuity},
        initial_pose={"q": [2.9]},
    )


def frames(client: TestClient, s: Created, *frames: dict[str, Any]) -> list[dict[str, Any]]:
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"frames": list(frames)}, headers=s.headers)
    assert r.status_code == 200, r.text
    results: list[dict[str, Any]] = r.json()["results"]
    for result in results:
        S.FrameResult.model_validate(result)
    return results


def test_sessions_default_to_smooth_and_say_so(client: TestClient) -> None:
    created = create(client, DIAL)
    options = S.SolverOptions.model_validate(created.body["options"])
    assert options.continuity == "smooth"
    assert options.max_joint_step_rad == pytest.approx(0.1)


def test_reach_jumps_to_the_other_branch_and_says_so_over_http(client: TestClient) -> None:
    s = dial_session(client, "reach")
    near, far = frames(client, s, at_angle(2.85, 1), at_angle(-2.9, 2))
    assert near["success"] and not near["jumped"]
    assert near["largest_step_rad"] == pytest.approx(0.05, abs=1e-3)
    assert far["success"] and far["jumped"]
    assert far["q"][0] == pytest.approx(-2.9, abs=1e-3)
    assert far["largest_step_rad"] == pytest.approx(5.75, abs=1e-3)


def test_smooth_answers_the_closest_continuous_pose_over_the_websocket(
    client: TestClient,
) -> None:
    s = dial_session(client, "smooth")
    with client.websocket_connect(f"/v1/sessions/{s.id}/ws", headers=s.headers) as ws:
        for frame_id, angle in ((1, 2.85), (2, -2.9)):
            ws.send_json({"type": "frame", **at_angle(angle, frame_id)})
        near, far = (S.ResultMessage.model_validate(ws.receive_json()).result for _ in range(2))
    assert near.success and not near.jumped
    assert far.status == "not_reached" and not far.jumped
    # The closest pose to the target within 0.1 rad of the answer near 2.85: the
    # box's edge.
    assert far.q[0] == pytest.approx(near.q[0] + 0.1, abs=1e-9)
    assert far.largest_step_rad is not None and far.largest_step_rad <= 0.1 + 1e-9


def test_a_patch_switches_the_policy(client: TestClient) -> None:
    s = dial_session(client, "smooth")
    frames(client, s, at_angle(2.85, 1))
    r = client.patch(f"/v1/sessions/{s.id}", json={"continuity": "reach"}, headers=s.headers)
    assert r.status_code == 200, r.text
    (far,) = frames(client, s, at_angle(-2.9, 2))
    assert far["success"] and far["jumped"]


def test_a_planned_clip_reports_each_frames_step(client: TestClient) -> None:
    s = dial_session(client, "smooth")
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"frames": [at_angle(2.85, 1), at_angle(2.8, 2)], "plan": True},
        headers=s.headers,
    )
    assert r.status_code == 200, r.text
    steps = [x["largest_step_rad"] for x in r.json()["results"]]
    assert steps == [pytest.approx(0.05, abs=1e-3), pytest.approx(0.05, abs=1e-3)]


def test_one_shot_results_have_no_previous_answer(client: TestClient) -> None:
    r = client.post("/v1/solve", json={"chain": DIAL, **at_angle(1.0, 1)})
    assert r.status_code == 200, r.text
    assert r.json()["largest_step_rad"] is None and r.json()["jumped"] is False


@pytest.mark.parametrize(
    ("options", "field"),
    [
        ({"continuity": "jump"}, "continuity"),
        ({"max_joint_step_rad": 0.0}, "max_joint_step_rad"),
        ({"max_joint_step_rad": -1.0}, "max_joint_step_rad"),
    ],
)
def test_bad_continuity_options_are_422_naming_the_field(
    client: TestClient, options: dict[str, Any], field: str
) -> None:
    r = client.post("/v1/sessions", json={"chain": DIAL, "options": options})
    assert r.status_code == 422, r.text
    assert field in r.text
