"""HTTP endpoints: happy paths, status codes, error bodies ({"detail", "code"})."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from starlette.testclient import TestClient

import schemas as S
from schemas.chain import EXAMPLE_ARM, EXAMPLE_BVH_LEG
from service.config import Settings
from solver.model.examples import panda_arm

from .helpers import ARM, Created, create, hand_frame, panda_target


# --- sessions: create / get / patch / pose / delete ------------------------------------
def test_create_session_returns_id_token_joint_order_and_effectors(client: TestClient) -> None:
    r = client.post("/v1/sessions", json={"chain": ARM, "initial_pose": {"joints": {"elbow": 1.0}}})
    assert r.status_code == 201
    body = S.SessionCreated.model_validate(r.json())
    assert r.headers["location"] == f"/v1/sessions/{body.id}"
    assert [d.name for d in body.dof] == ["shoulder.z", "shoulder.y", "elbow"]
    assert body.dof[2].lower == 0.0 and body.dof[2].upper == 2.6
    assert [e.name for e in body.effectors] == ["hand"]
    assert body.pose.joints["elbow"] == 1.0
    assert len(body.id) >= 16 and len(body.token) >= 32


@pytest.mark.parametrize("name", ["panda_arm", "humanoid_arm", "tail", "two_arm_torso"])
def test_create_session_from_each_example(client: TestClient, name: str) -> None:
    created = create(client, {"format": "example", "name": name})
    assert created.body["n_dof"] == len(created.body["dof"]) > 0


def test_create_session_from_urdf(client: TestClient) -> None:
    urdf = (
        '<robot name="r"><link name="base"/><link name="l1"/><link name="tip"/>'
        '<joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>'
        '<axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>'
        '<joint name="j2" type="continuous"><parent link="l1"/><child link="tip"/>'
        '<origin xyz="0.5 0 0"/><axis xyz="0 0 1"/></joint></robot>'
    )
    chain = {
        "format": "urdf",
        "urdf": urdf,
        "base_link": "base",
        "tip_links": ["tip"],
        "mode": "position",
    }
    created = create(client, chain)
    assert [d["name"] for d in created.body["dof"]] == ["j1", "j2"]
    assert created.body["dof"][1] == {"name": "j2", "lower": None, "upper": None}
    r = client.post(
        f"/v1/sessions/{created.id}/frames",
        json={"targets": [{"effector": "tip", "position": {"x": 0.0, "y": 0.5, "z": 0.0}}]},
        headers=created.headers,
    )
    assert r.status_code == 200 and r.json()["results"][0]["success"] is True


def test_get_session_summary_pose_and_counters(client: TestClient, session: Created) -> None:
    client.post(f"/v1/sessions/{session.id}/frames", json=hand_frame(1), headers=session.headers)
    r = client.get(f"/v1/sessions/{session.id}", headers=session.headers)
    assert r.status_code == 200
    info = S.SessionInfo.model_validate(r.json())
    assert info.id == session.id and info.n_dof == 3
    assert info.counters.frames == 1 and info.counters.solved + info.counters.not_solved == 1
    assert info.websockets == 0 and info.idle_ttl_s == 300.0
    assert "token" not in r.json()


def test_patch_changes_only_the_given_options(client: TestClient, session: Created) -> None:
    before = session.body["options"]
    r = client.patch(
        f"/v1/sessions/{session.id}", json={"time_budget_us": 400}, headers=session.headers
    )
    assert r.status_code == 200
    after = r.json()["options"]
    assert after["time_budget_us"] == 400
    assert {k: v for k, v in after.items() if k != "time_budget_us"} == {
        k: v for k, v in before.items() if k != "time_budget_us"
    }


def test_patch_null_keeps_the_value_as_docs_say(client: TestClient, session: Created) -> None:
    # JSON Merge Patch users expect null to reset a field; here it is as if left out
    # (docs/api.md says so), so a client learns it does not get the default back.
    url = f"/v1/sessions/{session.id}"
    client.patch(url, json={"time_budget_us": 400}, headers=session.headers)
    r = client.patch(url, json={"time_budget_us": None}, headers=session.headers)
    assert r.status_code == 200 and r.json()["options"]["time_budget_us"] == 400


def test_put_pose_sets_and_clips_the_pose(client: TestClient, session: Created) -> None:
    r = client.put(
        f"/v1/sessions/{session.id}/pose", json={"q": [0.5, 0.25, 9.0]}, headers=session.headers
    )
    assert r.status_code == 200
    assert r.json()["q"] == [0.5, 0.25, 2.6]  # elbow clipped to its upper limit
    assert r.json()["clipped"] == ["elbow"]  # and the answer says so
    r = client.put(
        f"/v1/sessions/{session.id}/pose", json={"joints": {"elbow": 1.5}}, headers=session.headers
    )
    assert r.json()["joints"] == {"shoulder.z": 0.5, "shoulder.y": 0.25, "elbow": 1.5}
    assert r.json()["clipped"] == []
    r = client.put(
        f"/v1/sessions/{session.id}/pose", json={"joints": {"elbow": -9.0}}, headers=session.headers
    )
    assert r.json()["clipped"] == ["elbow"] and r.json()["q"][:2] == [0.5, 0.25]
    r = client.put(
        f"/v1/sessions/{session.id}/pose", json={"joints": {"elbow": 1.5}}, headers=session.headers
    )
    got = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert got["pose"]["q"] == [0.5, 0.25, 1.5]


def test_delete_then_not_found(client: TestClient, session: Created) -> None:
    assert client.delete(f"/v1/sessions/{session.id}", headers=session.headers).status_code == 204
    r = client.get(f"/v1/sessions/{session.id}", headers=session.headers)
    assert r.status_code == 404 and r.json()["code"] == "not_found"


# --- frames ----------------------------------------------------------------------------
def test_one_frame_result_has_every_field(client: TestClient, session: Created) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames", json=hand_frame(42), headers=session.headers
    )
    assert r.status_code == 200
    (res,) = S.FrameResults.model_validate(r.json()).results
    assert res.id == 42 and res.success and res.status == "solved"
    assert res.termination == "goal_reached"
    assert list(res.joints) == ["shoulder.z", "shoulder.y", "elbow"]
    assert res.q == list(res.joints.values())
    (eff,) = res.effectors
    assert eff.name == "hand" and eff.within_tolerance and eff.rotation_error_rad is None
    assert eff.position_error_m is not None and eff.position_error_m <= 1e-4
    assert res.solve_us > 0 and res.server_us >= res.solve_us
    assert res.iterations >= 0 and res.passes >= 1 and res.restarts >= 0


def test_frame_without_id_echoes_null(client: TestClient, session: Created) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames", json=hand_frame(None), headers=session.headers
    )
    assert r.json()["results"][0]["id"] is None


@pytest.mark.parametrize("inline_budget_us", [1e6, 0.0])  # all inline, all pooled
def test_clip_results_in_order_each_from_the_previous(
    make_client: Callable[..., TestClient], inline_budget_us: float
) -> None:
    client = make_client(Settings(inline_budget_us=inline_budget_us))
    s = create(client, options={"time_budget_us": 20_000})
    frames = [hand_frame(10 + i, y=0.1 + 0.01 * i) for i in range(5)]
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"frames": frames}, headers=s.headers)
    assert r.status_code == 200
    results = S.FrameResults.model_validate(r.json()).results
    assert [x.id for x in results] == [10, 11, 12, 13, 14]
    assert all(x.success for x in results)
    assert [x.server_us for x in results] == sorted(x.server_us for x in results)
    pose = client.get(f"/v1/sessions/{s.id}", headers=s.headers).json()["pose"]["q"]
    assert pose == results[-1].q  # the session continues from the last frame


def test_panda_pose_targets_from_forward_kinematics_are_solved(client: TestClient) -> None:
    s = create(client, {"format": "example", "name": "panda_arm"})
    rng = np.random.default_rng(7)
    chain = panda_arm()
    q = chain.mid_limits()
    frames = []
    for i in range(10):
        q = np.clip(q + rng.normal(0.0, 0.02, q.shape), chain.lower, chain.upper)
        frames.append({"id": i, "targets": [panda_target(q)]})
    r = client.post(f"/v1/sessions/{s.id}/frames", json={"frames": frames}, headers=s.headers)
    results = r.json()["results"]
    # A stream of small steps: judge the success rate, not each frame.
    assert sum(x["success"] for x in results) >= 9
    assert all(x["effectors"][0]["rotation_error_rad"] is not None for x in results)


def test_unreachable_target_is_a_result_not_an_error(client: TestClient, session: Created) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames", json=hand_frame(1, x=5.0), headers=session.headers
    )
    assert r.status_code == 200
    res = r.json()["results"][0]
    assert res["success"] is False and res["status"] in ("not_reached", "budget_exhausted")
    assert res["effectors"][0]["within_tolerance"] is False


# --- one-shot --------------------------------------------------------------------------
def test_solve_one_shot_with_seed(client: TestClient) -> None:
    body = {
        "chain": ARM,
        "targets": hand_frame(None)["targets"],
        "seed": {"q": [0.0, 0.0, 1.0]},
        "id": 9,
        "options": {"position_tolerance_m": 0.001},
    }
    r = client.post("/v1/solve", json=body)
    assert r.status_code == 200
    res = S.FrameResult.model_validate(r.json())
    assert res.id == 9 and res.success


def test_solve_panda_example_pose(client: TestClient) -> None:
    q = panda_arm().mid_limits() + 0.2
    body = {"chain": {"format": "example", "name": "panda_arm"}, "targets": [panda_target(q)]}
    r = client.post("/v1/solve", json=body)
    assert r.status_code == 200 and r.json()["success"] is True


Q_ID = {"w": 1.0, "x": 0.0, "y": 0.0, "z": 0.0}


def test_a_one_shot_target_beyond_the_arm_is_not_reached(client: TestClient) -> None:
    """3 m from a panda's base, with restarts cut by the time: answered not_reached (no
    time would reach it), not budget_exhausted (a robotics user's trial). Which code
    ends the search depends on the clock: ``deadline`` when the 100 us cut it,
    ``stalled`` when it ended first (a fresh CI run met both)."""
    far = {"effector": "tool", "position": {"x": 3.0, "y": 0.0, "z": 0.5}, "orientation": Q_ID}
    body = {"chain": {"format": "example", "name": "panda_arm"}, "targets": [far]}
    body["options"] = {"time_budget_us": 100}
    r = client.post("/v1/solve", json=body)
    assert r.status_code == 200, r.text
    res = r.json()
    assert (res["success"], res["status"]) == (False, "not_reached"), res
    assert res["termination"] in ("deadline", "stalled"), res


# --- errors: auth ----------------------------------------------------------------------
@pytest.mark.parametrize(
    ("method", "path", "body"),
    [
        ("GET", "", None),
        ("PATCH", "", {"time_budget_us": 100}),
        ("PUT", "/pose", {"q": [0, 0, 1]}),
        ("DELETE", "", None),
        ("POST", "/frames", hand_frame(1)),
    ],
)
def test_token_required_on_every_session_call(
    client: TestClient, session: Created, method: str, path: str, body: Any
) -> None:
    url = f"/v1/sessions/{session.id}{path}"
    missing = client.request(method, url, json=body)
    assert missing.status_code == 401 and missing.json()["code"] == "unauthorized"
    assert missing.headers["www-authenticate"] == "Bearer"
    wrong = client.request(method, url, json=body, headers={"Authorization": "Bearer nope"})
    assert wrong.status_code == 403 and wrong.json()["code"] == "forbidden"
    basic = client.request(
        method, url, json=body, headers={"Authorization": f"Basic {session.token}"}
    )
    assert basic.status_code == 401
    other = client.request(
        method, f"/v1/sessions/doesnotexist{path}", json=body, headers=session.headers
    )
    assert other.status_code == 404 and other.json()["code"] == "not_found"
    # The session survived every failed call.
    assert client.get(f"/v1/sessions/{session.id}", headers=session.headers).status_code == 200


def test_token_of_another_session_is_forbidden(client: TestClient, session: Created) -> None:
    other = create(client)
    r = client.get(f"/v1/sessions/{session.id}", headers=other.headers)
    assert r.status_code == 403


# --- errors: capacity and expiry -------------------------------------------------------
def test_session_cap_gives_503_with_retry_after(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_sessions=2, session_ttl_s=60.0))
    create(client)
    create(client)
    r = client.post("/v1/sessions", json={"chain": ARM})
    assert r.status_code == 503 and r.json()["code"] == "too_many_sessions"
    assert 1 <= int(r.headers["retry-after"]) <= 60


def test_idle_session_expires_and_frees_its_slot(make_client: Callable[..., TestClient]) -> None:
    now = [1000.0]
    from service.sessions import InMemorySessionStore

    store = InMemorySessionStore(max_sessions=1, ttl_s=10.0, clock=lambda: now[0])
    client = make_client(Settings(max_sessions=1, session_ttl_s=10.0), store=store)
    s = create(client)
    now[0] += 5.0
    assert client.get(f"/v1/sessions/{s.id}", headers=s.headers).status_code == 200  # touches
    now[0] += 9.0
    assert client.get(f"/v1/sessions/{s.id}", headers=s.headers).status_code == 200
    now[0] += 10.5
    r = client.get(f"/v1/sessions/{s.id}", headers=s.headers)
    assert r.status_code == 404 and r.json()["code"] == "not_found"
    create(client)  # the slot is free again
    now[0] += 11.0
    create(client)  # full, but the idle one expires on the way in
    assert len(store) == 1


# --- errors: validation ----------------------------------------------------------------
def _post_frame(client: TestClient, s: Created, body: Any) -> Any:
    return client.post(f"/v1/sessions/{s.id}/frames", json=body, headers=s.headers)


@pytest.mark.parametrize(
    ("body", "loc_part"),
    [
        ({"targets": [{"effector": "hand", "position": {"x": 1, "y": 2}}]}, "z"),
        ({"targets": [{"effector": "hand", "position": {"x": 1, "y": 2, "z": 3, "w": 4}}]}, "w"),
        ({"targets": []}, "targets"),
        ({"targets": [{"effector": "hand"}]}, "targets"),
        ({"id": -1, "targets": [{"effector": "hand", "position": {"x": 0, "y": 0, "z": 0}}]}, "id"),
        ({"frames": []}, "frames"),
        ({"targets": [{"effector": "hand", "position": {"x": "a", "y": 0, "z": 0}}]}, "x"),
    ],
)
def test_schema_errors_are_422_invalid_format_naming_the_field(
    client: TestClient, session: Created, body: Any, loc_part: str
) -> None:
    r = _post_frame(client, session, body)
    assert r.status_code == 422
    out = r.json()
    assert out["code"] == "invalid_format"
    assert any(loc_part in [str(p) for p in e["loc"]] for e in out["detail"])


def test_non_json_body_is_422(client: TestClient, session: Created) -> None:
    r = client.post(
        f"/v1/sessions/{session.id}/frames",
        content=b"{not json",
        headers={**session.headers, "content-type": "application/json"},
    )
    assert r.status_code == 422 and r.json()["code"] == "invalid_format"
    # The field is the body, not FastAPI's character offset; the message says where.
    assert r.json()["field"] == "body"
    assert r.json()["detail"][0]["msg"].startswith("the body is not valid JSON at character 1")


@pytest.mark.parametrize(
    ("target", "field"),
    [
        ({"effector": "foot", "position": {"x": 0, "y": 0, "z": 0}}, "targets[0].effector"),
        (
            {"effector": "hand", "orientation": {"w": 1, "x": 0, "y": 0, "z": 0}},
            "targets[0].position",
        ),
        (
            {
                "effector": "hand",
                "position": {"x": 0, "y": 0, "z": 0},
                "direction": {"x": 0, "y": 0, "z": 1},
            },
            "targets[0].direction",
        ),
    ],
)
def test_problem_errors_are_422_invalid_problem_naming_the_field(
    client: TestClient, session: Created, target: dict[str, Any], field: str
) -> None:
    r = _post_frame(client, session, {"targets": [target]})
    assert r.status_code == 422
    assert r.json()["code"] == "invalid_problem" and r.json()["field"] == field


def test_two_targets_for_one_effector(client: TestClient, session: Created) -> None:
    t = hand_frame(None)["targets"][0]
    r = _post_frame(client, session, {"targets": [t, t]})
    assert r.status_code == 422 and r.json()["field"] == "targets[1].effector"


def test_clip_longer_than_the_limit(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_frames_per_request=3))
    s = create(client)
    r = _post_frame(client, s, {"frames": [hand_frame(i) for i in range(4)]})
    assert r.status_code == 422 and r.json()["field"] == "frames"


def test_clip_error_names_the_frame(client: TestClient, session: Created) -> None:
    frames = [
        hand_frame(1),
        {"targets": [{"effector": "nope", "position": {"x": 0, "y": 0, "z": 0}}]},
    ]
    r = _post_frame(client, session, {"frames": frames})
    assert r.status_code == 422 and r.json()["field"] == "frames[1].targets[0].effector"
    # Nothing was solved: the clip is checked before the first frame runs.
    info = client.get(f"/v1/sessions/{session.id}", headers=session.headers).json()
    assert info["counters"]["frames"] == 0


def _arm_with(**changes: Any) -> dict[str, Any]:
    import copy

    chain = copy.deepcopy(ARM)
    for path, value in changes.items():
        i, key = path.split("__")
        chain["joints"][int(i)][key] = value
    return chain


@pytest.mark.parametrize(
    ("chain", "field"),
    [
        (_arm_with(**{"1__lower": [3.0]}), "chain.joints[1].lower"),
        (_arm_with(**{"1__axis": {"x": 0, "y": 0, "z": 0}}), "chain.joints[1].axis"),
        (_arm_with(**{"0__axes": "zz"}), "chain.joints[0].axes"),
        (_arm_with(**{"2__name": "elbow"}), "chain.joints[2].name"),
        (_arm_with(**{"1__upper": []}), "chain.joints[1].upper"),
        (_arm_with(**{"2__parent": "nowhere"}), "chain.joints"),
        ({**ARM, "effectors": [{"name": "hand", "link": "nowhere"}]}, "chain.effectors[0].link"),
        (
            {**ARM, "effectors": [{"name": "hand", "link": "hand", "position_weight": 0}]},
            "chain.effectors[0].position_weight",
        ),
    ],
)
def test_invalid_model_names_the_joint_and_field(
    client: TestClient, chain: dict[str, Any], field: str
) -> None:
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422, r.text
    assert r.json()["code"] == "invalid_problem" and r.json()["field"] == field


@pytest.mark.parametrize(
    ("urdf", "field"),
    [
        ("<robot", "chain.urdf"),
        ('<!DOCTYPE r [<!ENTITY a "b">]><robot name="r"/>', "chain.urdf"),
    ],
)
def test_bad_urdf_is_422(client: TestClient, urdf: str, field: str) -> None:
    chain = {"format": "urdf", "urdf": urdf, "base_link": "base", "tip_links": ["tip"]}
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422 and r.json()["field"] == field


_TWO_LINKS = (
    '<robot name="r"><link name="base"/><link name="tip"/>'
    '<joint name="j1" type="continuous"><parent link="base"/><child link="tip"/>'
    '<axis xyz="0 0 1"/></joint></robot>'
)


@pytest.mark.parametrize(
    ("base", "tips", "detail"),
    [
        ("bsae", ["tip"], "chain.base_link: unknown base link 'bsae'; did you mean 'base'?"),
        ("base", ["Tip"], "chain.tip_links[0]: unknown tip link 'Tip'; did you mean 'tip'?"),
        ("base", ["base"], "chain.tip_links[0]: 'base': tip link is the base link"),
        # The later of two alike is the one at fault.
        ("base", ["tip", "tip"], "chain.tip_links[1]: 'tip': duplicate tip link"),
    ],
)
def test_a_link_name_of_the_request_is_named_once_with_the_nearest_names(
    client: TestClient, base: str, tips: list[str], detail: str
) -> None:
    # It read "chain.base_link: bsae.base_link: unknown base link 'bsae'", no suggestion.
    chain = {"format": "urdf", "urdf": _TWO_LINKS, "base_link": base, "tip_links": tips}
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422 and r.json()["detail"] == detail, r.text
    assert r.json()["field"] == detail.split(":")[0]


def test_chain_over_the_dof_limit(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_dof=10))
    r = client.post("/v1/sessions", json={"chain": {"format": "example", "name": "tail"}})
    assert r.status_code == 422 and r.json()["field"] == "chain"


@pytest.mark.parametrize("kind", ["hierarchy", "bvh"])
def test_chain_over_the_effector_limit(make_client: Callable[..., TestClient], kind: str) -> None:
    """IK_MAX_EFFECTORS holds for every chain format (skeletons were not checked)."""
    client = make_client(Settings(max_effectors=2))
    if kind == "bvh":
        bones = ["LeftLeg_end", "LeftLeg", "LeftUpLeg"]
        chain = {**EXAMPLE_BVH_LEG, "effectors": [{"bone": b} for b in bones]}
    else:
        effectors = [{**EXAMPLE_ARM["effectors"][0], "name": f"e{i}"} for i in range(3)]
        chain = {**EXAMPLE_ARM, "effectors": effectors}
    r = client.post("/v1/sessions", json={"chain": chain})
    assert r.status_code == 422, r.text
    assert r.json()["field"] == "chain.effectors", r.text
    assert "too many effectors: 3 > 2" in r.json()["detail"], r.text
    chain["effectors"] = chain["effectors"][:2]
    assert client.post("/v1/sessions", json={"chain": chain}).status_code == 201


def test_options_over_the_budget_cap(client: TestClient, session: Created) -> None:
    r = client.patch(
        f"/v1/sessions/{session.id}", json={"time_budget_us": 999_999}, headers=session.headers
    )
    assert r.status_code == 422 and r.json()["field"] == "time_budget_us"
    r = client.patch(f"/v1/sessions/{session.id}", json={"max_iter": 0}, headers=session.headers)
    assert r.status_code == 422 and r.json()["code"] == "invalid_format"


@pytest.mark.parametrize(
    ("pose", "field"),
    [({"q": [0.0, 1.0]}, "q"), ({"joints": {"knee": 1.0}}, "joints.knee")],
)
def test_bad_pose(client: TestClient, session: Created, pose: Any, field: str) -> None:
    r = client.put(f"/v1/sessions/{session.id}/pose", json=pose, headers=session.headers)
    assert r.status_code == 422 and r.json()["field"] == field


def test_body_over_the_limit_is_413(make_client: Callable[..., TestClient]) -> None:
    client = make_client(Settings(max_body_bytes=2048))
    r = client.post("/v1/solve", json={"chain": ARM, "targets": [], "pad": "x" * 4096})
    assert r.status_code == 413 and r.json()["code"] == "payload_too_large"


def test_chunked_body_over_the_limit_is_413(make_client: Callable[..., TestClient]) -> None:
    """No Content-Length: the body is over the limit only once read (it was a 422)."""
    client = make_client(Settings(max_body_bytes=2048))
    chunks = iter([b'{"chain": {"format": "example", "name": "panda_arm"}, "pad": "', b"x" * 4096])
    r = client.post("/v1/solve", content=chunks, headers={"content-type": "application/json"})
    assert "content-length" not in r.request.headers
    assert r.status_code == 413 and r.json()["code"] == "payload_too_large"


def test_unknown_route_and_method(client: TestClient) -> None:
    assert client.get("/v1/nothing").json()["code"] == "not_found"
    r = client.put("/v1/solve", json={})
    assert r.status_code == 405 and r.json()["code"] == "method_not_allowed"


def test_not_ready_until_warm(make_client: Callable[..., TestClient]) -> None:
    import threading

    gate = threading.Event()

    def slow_warmup(report: object) -> float:
        assert gate.wait(30.0)
        return 0.0

    client = make_client(warmup=slow_warmup)
    try:
        r = client.post("/v1/sessions", json={"chain": ARM})
        assert r.status_code == 503 and r.json()["code"] == "not_ready"
        assert r.headers["retry-after"] == "1"
    finally:
        gate.set()


def test_unexpected_error_is_500_internal_error(
    make_client: Callable[..., TestClient], monkeypatch: pytest.MonkeyPatch
) -> None:
    from service import convert

    client = make_client()
    s = create(client)

    def boom(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("bug")

    monkeypatch.setattr(convert, "targets", boom)
    quiet = TestClient(client.app, raise_server_exceptions=False)
    r = quiet.post(f"/v1/sessions/{s.id}/frames", json=hand_frame(1), headers=s.headers)
    assert r.status_code == 500 and r.json() == {
        "detail": "internal server error",
        "code": "internal_error",
    }


def test_aim_effector_points_along_the_direction(client: TestClient) -> None:
    chain = {**ARM, "effectors": [{"name": "hand", "link": "hand", "mode": "aim"}]}
    s = create(client, chain)
    frame = {
        "id": 1,
        "targets": [{"effector": "hand", "direction": {"x": 2.0, "y": 0.0, "z": 0.0}}],
    }
    r = client.post(f"/v1/sessions/{s.id}/frames", json=frame, headers=s.headers)
    res = r.json()["results"][0]
    assert res["success"] is True
    (eff,) = res["effectors"]
    assert eff["position_error_m"] is None and eff["rotation_error_rad"] <= 1e-3
    zero = {"targets": [{"effector": "hand", "direction": {"x": 0.0, "y": 0.0, "z": 0.0}}]}
    r = client.post(f"/v1/sessions/{s.id}/frames", json=zero, headers=s.headers)
    assert r.status_code == 422 and r.json()["field"] == "targets[0].direction"


def test_initial_pose_outside_the_limits_is_clipped_and_named(client: TestClient) -> None:
    s = create(client, initial_pose={"q": [9.0, 0.25, 1.0]})
    assert s.body["pose"]["clipped"] == ["shoulder.z"]
    assert s.body["pose"]["q"][1:] == [0.25, 1.0]
    assert create(client, initial_pose={"q": [0.0, 0.25, 1.0]}).body["pose"]["clipped"] == []


def test_initial_pose_of_the_wrong_length(client: TestClient) -> None:
    r = client.post("/v1/sessions", json={"chain": ARM, "initial_pose": {"q": [0.0]}})
    assert r.status_code == 422 and r.json()["field"] == "initial_pose.q"
