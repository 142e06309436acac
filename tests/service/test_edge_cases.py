"""Solver edge cases through the API (issue #6 item 5): singular poses, the boundary of
reach, joints at their limits, all-fixed chains, a 1,000-joint chain within the time
budget, numbers at the input bounds; and a Hypothesis property: for any finite input
the returned joints are finite and inside the limits."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from starlette.testclient import TestClient

from schemas.common import MAX_COORDINATE
from service.config import Settings

from .helpers import ARM, Created, create

# The example arm: shoulder 0.3 m up, upper arm 0.4 m, forearm 0.35 m; elbow in [0, 2.6].
REACH_TOP = 0.3 + 0.4 + 0.35


def frame(s: Created, client: TestClient, x: float, y: float, z: float) -> dict[str, Any]:
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"targets": [{"effector": "hand", "position": {"x": x, "y": y, "z": z}}]},
        headers=s.headers,
    )
    assert r.status_code == 200, r.text
    result: dict[str, Any] = r.json()["results"][0]
    return result


def assert_inside_limits(s: Created, result: dict[str, Any]) -> None:
    for dof, q in zip(s.body["dof"], result["q"], strict=True):
        assert math.isfinite(q)
        lo = -math.inf if dof["lower"] is None else dof["lower"]
        hi = math.inf if dof["upper"] is None else dof["upper"]
        assert lo <= q <= hi, (dof, q)


@pytest.fixture
def arm(client: TestClient) -> Created:
    return create(client, options={"time_budget_us": 20_000})


def test_singular_fully_stretched_pose_on_the_boundary_of_reach(
    client: TestClient, arm: Created
) -> None:
    # Straight up: the arm fully stretched (elbow 0, at its lower limit): the Jacobian
    # loses rank there and the target is exactly at the boundary of reach.
    result = frame(arm, client, 0.0, 0.0, REACH_TOP)
    assert_inside_limits(arm, result)
    assert result["effectors"][0]["position_error_m"] < 1e-3
    assert result["q"][2] == pytest.approx(0.0, abs=0.05)


def test_just_beyond_reach_gives_the_stretched_pose_not_an_error(
    client: TestClient, arm: Created
) -> None:
    result = frame(arm, client, 0.0, 0.0, REACH_TOP + 0.01)
    assert result["success"] is False and result["status"] != "solved"
    assert_inside_limits(arm, result)
    assert result["effectors"][0]["position_error_m"] == pytest.approx(0.01, abs=2e-3)


def test_all_joints_at_their_limits(client: TestClient, arm: Created) -> None:
    upper = [d["upper"] for d in arm.body["dof"]]
    r = client.put(f"/v1/sessions/{arm.id}/pose", json={"q": upper}, headers=arm.headers)
    assert r.json()["q"] == upper
    # From the corner, a reachable target solves and stays inside.
    result = frame(arm, client, 0.3, 0.1, 0.6)
    assert result["success"] is True
    assert_inside_limits(arm, result)
    # A target that needs every joint at a limit: shoulder.z = 3.1, shoulder.y = 1.5,
    # elbow = 2.6, computed by forward kinematics through a one-frame round trip.
    # The stream defaults pull gently away from the limits (limit_weight): off here; and
    # the two corners are one frame apart only under REACH (smooth moves 0.1 rad a frame).
    patch = {"limit_weight": 0.0, "continuity": "reach"}
    r = client.patch(f"/v1/sessions/{arm.id}", json=patch, headers=arm.headers)
    assert r.status_code == 200
    lower = [d["lower"] for d in arm.body["dof"]]
    for corner in (upper, lower):
        x, y, z = _arm_fk(corner)
        result = frame(arm, client, x, y, z)
        assert_inside_limits(arm, result)
        assert result["effectors"][0]["position_error_m"] < 1e-3


def _arm_fk(q: list[float]) -> tuple[float, float, float]:
    """Hand position of the example arm: rotate z (q0), then y (q1); elbow about y (q2)."""
    qz, qy, qe = q
    # In the shoulder's plane: upper arm along z rotated by qy, forearm by qy + qe.
    r = 0.4 * math.sin(qy) + 0.35 * math.sin(qy + qe)
    h = 0.4 * math.cos(qy) + 0.35 * math.cos(qy + qe)
    return r * math.cos(qz), r * math.sin(qz), 0.3 + h


def test_fk_helper_matches_the_service(client: TestClient, arm: Created) -> None:
    # The solved pose's own FK equals its target (checks _arm_fk against the server).
    result = frame(arm, client, 0.3, 0.1, 0.6)
    assert _arm_fk(result["q"]) == pytest.approx((0.3, 0.1, 0.6), abs=1e-3)


def all_fixed_chain() -> dict[str, Any]:
    return {
        "format": "hierarchy",
        "joints": [
            {"name": "a", "parent": "base", "child": "l1", "kind": "fixed"},
            {
                "name": "b",
                "parent": "l1",
                "child": "l2",
                "kind": "fixed",
                "origin": {"translation": {"x": 0.0, "y": 0.0, "z": 0.5}},
            },
        ],
        "effectors": [{"name": "tip", "link": "l2"}],
    }


def test_all_fixed_chain(client: TestClient) -> None:
    s = create(client, chain=all_fixed_chain())
    assert s.body["n_dof"] == 0
    url = f"/v1/sessions/{s.id}/frames"

    def tip(x: float, y: float, z: float) -> dict[str, Any]:
        body = {"targets": [{"effector": "tip", "position": {"x": x, "y": y, "z": z}}]}
        r = client.post(url, json=body, headers=s.headers)
        assert r.status_code == 200, r.text
        result: dict[str, Any] = r.json()["results"][0]
        return result

    at = tip(0.0, 0.0, 0.5)
    assert at["success"] is True and at["q"] == [] and at["joints"] == {}
    away = tip(1.0, 0.0, 0.0)
    assert away["success"] is False
    assert away["effectors"][0]["position_error_m"] == pytest.approx(math.sqrt(1.25))


def long_chain(n: int, link_m: float = 0.001) -> dict[str, Any]:
    return {
        "format": "hierarchy",
        "joints": [
            {
                "name": f"j{i}",
                "parent": f"l{i}",
                "child": f"l{i + 1}",
                "kind": "revolute",
                "origin": {"translation": {"x": 0.0, "y": 0.0, "z": link_m}},
                "axis": {"x": 0.0, "y": 1.0, "z": 0.0} if i % 2 else {"x": 1.0, "y": 0.0, "z": 0.0},
                "lower": [-1.0],
                "upper": [1.0],
            }
            for i in range(n)
        ],
        "effectors": [{"name": "tip", "link": f"l{n}"}],
    }


def test_thousand_joint_chain_respects_its_time_budget(
    make_client: Callable[..., TestClient],
) -> None:
    client = make_client(Settings(max_joints=1000, max_dof=1000))
    budget_us = 20_000.0
    s = create(client, chain=long_chain(1000), options={"time_budget_us": budget_us})
    assert s.body["n_dof"] == 1000
    for target in ((0.3, 0.2, 0.7), (5.0, 0.0, 0.0)):  # reachable-ish, unreachable
        r = client.post(
            f"/v1/sessions/{s.id}/frames",
            json={
                "targets": [{"effector": "tip", "position": dict(zip("xyz", target, strict=True))}]
            },
            headers=s.headers,
        )
        assert r.status_code == 200
        result = r.json()["results"][0]
        assert_inside_limits(s, result)
        # The compiled solve stops at its deadline (checked between iterations: one
        # iteration of a 1000-joint chain takes a few ms on this machine).
        assert result["solve_us"] <= budget_us + 15_000, result["solve_us"]
        assert result["server_us"] >= result["solve_us"]


def test_chain_at_the_coordinate_bound_stays_finite(client: TestClient) -> None:
    s = create(client, chain=long_chain(10, link_m=MAX_COORDINATE / 10))
    big = MAX_COORDINATE
    for target in ((0.0, 0.0, big), (big, big, big), (-big, 0.0, -big)):
        r = client.post(
            f"/v1/sessions/{s.id}/frames",
            json={
                "targets": [{"effector": "tip", "position": dict(zip("xyz", target, strict=True))}]
            },
            headers=s.headers,
        )
        assert r.status_code == 200
        result = r.json()["results"][0]
        assert result["status"] != "nonfinite"
        assert_inside_limits(s, result)


# -- property: any finite input, finite joints inside the limits ------------------------
coordinate = st.floats(-MAX_COORDINATE, MAX_COORDINATE, allow_nan=False)
small = st.floats(-2.0, 2.0, allow_nan=False)


@pytest.fixture(scope="module")
def property_app(warm_solver: float) -> Any:
    from service.main import create_app

    app = create_app(Settings(max_frames_per_s=0), warmup=lambda _report: 0.0)
    with TestClient(app) as client:
        assert app.state.ik.runner.warmup.ready.wait(30)
        r = client.post("/v1/sessions", json={"chain": ARM})
        yield client, Created(r.json())


@settings(
    max_examples=60,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(
    target=st.one_of(st.tuples(coordinate, coordinate, coordinate), st.tuples(small, small, small)),
    pose=st.lists(st.floats(-10.0, 10.0, allow_nan=False), min_size=3, max_size=3),
)
def test_joints_always_finite_and_inside_limits(
    property_app: Any, target: tuple[float, float, float], pose: list[float]
) -> None:
    client, s = property_app
    r = client.put(f"/v1/sessions/{s.id}/pose", json={"q": pose}, headers=s.headers)
    assert r.status_code == 200
    assert_inside_limits(s, {"q": r.json()["q"]})
    x, y, z = target
    r = client.post(
        f"/v1/sessions/{s.id}/frames",
        json={"targets": [{"effector": "hand", "position": {"x": x, "y": y, "z": z}}]},
        headers=s.headers,
    )
    assert r.status_code == 200, r.text
    result = r.json()["results"][0]
    assert result["status"] != "nonfinite"
    assert_inside_limits(s, result)
