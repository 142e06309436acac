"""Robot files as they ship, through a real server: a mimic gripper solved, the URDF
conventions read with a warning, and each refused class of file answered with a 422
that names the element and says what to change."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest

from solver.model.forward import link_poses
from solver.model.urdf import chain_from_urdf

from .conftest import Server

pytestmark = pytest.mark.live

TIMEOUT_S = 30.0
PANDA = (
    Path(__file__).resolve().parents[1] / "solver" / "data" / "panda_kinematic.urdf"
).read_text()
FINGERS = ["panda_leftfinger", "panda_rightfinger"]


def _create(
    server: Server,
    urdf: str,
    tips: list[str],
    base: str = "panda_link0",
    budget_us: float | None = None,
    **kw: Any,
) -> httpx.Response:
    chain = {"format": "urdf", "urdf": urdf, "base_link": base, "tip_links": tips, **kw}
    body: dict[str, Any] = {"chain": chain}
    if budget_us is not None:
        # continuity "reach": each frame is an independent random pose, not a stream
        # (a smooth session, the default, would move at most 0.1 rad per frame).
        # max_iter 5000 (IKOptions' own, the server's default is 1000): three tips on one
        # hand from random poses take a median ~200 iterations and 1000 ran out on about
        # 6% of them (200 targets, with and without turn restarts); with 5000, none of 200.
        body["options"] = {"time_budget_us": budget_us, "continuity": "reach", "max_iter": 5000}
    return httpx.post(f"{server.base}/v1/sessions", json=body, timeout=TIMEOUT_S)


def test_a_mimic_gripper_solved_through_the_api(server: Server) -> None:
    # A roomy budget: this asserts what is solved, not how fast (bench/urdf_sweep.py),
    # on shared cores where a solve can be descheduled for 10 ms.
    r = _create(server, PANDA, [*FINGERS, "panda_hand_tcp"], mode="position", budget_us=50_000.0)
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["n_dof"] == 8 and len(body["pose"]["q"]) == 8
    assert body["followers"] == [
        {
            "name": "panda_finger_joint2",
            "leader": "panda_finger_joint1",
            "multiplier": 1.0,
            "offset": 0.0,
        }
    ]
    assert (
        body["pose"]["joints"]["panda_finger_joint2"]
        == body["pose"]["joints"]["panda_finger_joint1"]
    )
    headers = {"Authorization": f"Bearer {body['token']}"}
    # Targets from a pose the gripper can take: both fingers open by the same amount.
    chain = chain_from_urdf(PANDA, base_link="panda_link0", tip_links=[*FINGERS, "panda_hand_tcp"])
    rng = np.random.default_rng(7)
    for _ in range(5):
        poses = link_poses(chain, rng.uniform(chain.lower, chain.upper))
        targets = [
            {
                "effector": link,
                "position": dict(zip("xyz", poses[link][:3, 3].tolist(), strict=True)),
            }
            for link in [*FINGERS, "panda_hand_tcp"]
        ]
        r = httpx.post(
            f"{server.base}/v1/sessions/{body['id']}/frames",
            json={"targets": targets},
            headers=headers,
            timeout=TIMEOUT_S,
        )
        assert r.status_code == 200, r.text
        result = r.json()["results"][0]
        assert result["success"], result
        assert len(result["q"]) == 8 and result["q"][7] == result["joints"]["panda_finger_joint1"]
        assert result["joints"]["panda_finger_joint2"] == result["joints"]["panda_finger_joint1"]
    # A follower is not a DOF: setting it says which joint to set instead.
    r = httpx.put(
        f"{server.base}/v1/sessions/{body['id']}/pose",
        json={"joints": {"panda_finger_joint2": 0.01}},
        headers=headers,
        timeout=TIMEOUT_S,
    )
    assert r.status_code == 422 and r.json()["field"] == "joints.panda_finger_joint2"
    assert "set 'panda_finger_joint1' instead" in r.json()["detail"]


def _small(
    joint2: str, *, limit1: str = 'lower="-3" upper="3"', prolog: str = "", epilog: str = ""
) -> str:
    return (
        f'{prolog}<robot name="r"><link name="panda_link0"/><link name="l1"/><link name="tip"/>'
        '<joint name="j1" type="revolute"><parent link="panda_link0"/><child link="l1"/>'
        f'<axis xyz="0 0 1"/><limit {limit1} effort="1" velocity="1"/></joint>'
        f'<joint name="j2" {joint2}<parent link="l1"/><child link="tip"/>'
        f'<origin xyz="0.5 0 0"/><axis xyz="0 0 1"/></joint></robot>{epilog}'
    )


def test_the_files_conventions_are_read_with_a_warning(server: Server) -> None:
    # pybullet's unlimited joint (lower > upper), URDF's default lower (0), a blank line
    # before the declaration and a NUL after the root.
    text = _small(
        'type="prismatic"><limit lower="1" upper="-1"/>',
        limit1='upper="3"',
        prolog='\n<?xml version="1.0"?>',
        epilog="\x00",
    )
    r = _create(server, text, ["tip"], mode="position")
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["dof"] == [
        {"name": "j1", "lower": 0.0, "upper": 3.0},
        {"name": "j2", "lower": None, "upper": None},
    ]
    assert [(w["code"], w["joint"], w["field"]) for w in body["warnings"]] == [
        ("default_limit", "j1", "limit.lower"),
        ("unlimited_by_convention", "j2", "limit"),
    ]


def test_limits_in_degrees_are_kept_with_a_warning(server: Server) -> None:
    r = _create(
        server,
        _small('type="revolute"><limit lower="-1" upper="1"/>', limit1='lower="-170" upper="170"'),
        ["tip"],
    )
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["dof"][0] == {"name": "j1", "lower": -170.0, "upper": 170.0}
    [warning] = body["warnings"]
    assert (warning["code"], warning["joint"], warning["field"]) == (
        "unlikely_units",
        "j1",
        "limit",
    )
    assert "degrees" in warning["message"]


# (id, joint j2's type and limit, what the detail must name, what it must tell to change)
REFUSED = [
    ("floating", 'type="floating">', "j2.type", "base_link='tip'"),
    ("planar", 'type="planar">', "j2.type", "base_link='tip'"),
    ("unknown_type", 'type="ball">', "j2.type", "revolute, continuous, prismatic"),
    ("no_limit", 'type="revolute">', "j2.limit", "add one, or make the joint continuous"),
    ("mimic_unknown", 'type="continuous"><mimic joint="j9"/>', "j2.mimic", "give the name"),
    (
        "zero_axis",
        'type="revolute"><limit lower="0" upper="1"/><axis xyz="0 0 0"/>',
        "j2.axis",
        "or make the joint fixed",
    ),
]


@pytest.mark.parametrize(
    ("joint2", "names", "change"), [pytest.param(*c[1:], id=c[0]) for c in REFUSED]
)
def test_each_refused_file_class_is_a_422_saying_what_to_change(
    server: Server, joint2: str, names: str, change: str
) -> None:
    r = _create(server, _small(joint2), ["tip"])
    if not names:
        assert r.status_code == 201, r.text
        return
    assert r.status_code == 422, r.text
    body = r.json()
    assert body["code"] == "invalid_problem" and body["field"] == "chain.urdf"
    assert body["detail"].startswith(f"chain.urdf: {names}:") and change in body["detail"], body[
        "detail"
    ]


def test_a_mimic_leader_above_the_base_says_which_base_to_choose(server: Server) -> None:
    text = _small('type="continuous"><mimic joint="j1" multiplier="-1"/>')
    r = _create(server, text, ["tip"], base="l1")
    assert r.status_code == 422, r.text
    detail = r.json()["detail"]
    assert (
        detail.startswith("chain.urdf: j2.mimic:") and "choose a base link above both" in detail
    ), detail
    # With the base above both joints, the follower turns at -1 x j1: the tip stays put
    # in the base's frame while j1 turns, and the pose reports both joints.
    r = _create(server, text, ["tip"], mode="position")
    assert r.status_code == 201, r.text
    assert r.json()["pose"]["joints"] == {"j1": 0.0, "j2": -0.0}
