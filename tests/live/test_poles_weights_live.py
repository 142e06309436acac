"""Poles and blend weights against a real server (uvicorn on 127.0.0.1): CesiumMan's legs
in Unity's conventions, centimetres; the knee's side from the answers' bone positions.
The same geometry as tests/service/test_poles_weights.py, over real sockets."""

from __future__ import annotations

import httpx
import pytest
from ik_client import Client, Encoding

from tests.service.test_poles_weights import Legs, post_frame, vec

from .conftest import Server

pytestmark = pytest.mark.live

TIMEOUT_S = 30.0


def test_a_pole_flips_the_knee_and_weight_zero_frees_a_foot(server: Server) -> None:
    with httpx.Client(base_url=server.base, timeout=TIMEOUT_S) as client:
        legs = Legs(client)  # type: ignore[arg-type]  # httpx.Client speaks TestClient's API
        for sign in (1.0, -1.0):
            legs.reset()
            pole = {"position": vec(legs.middle + sign * 0.5 * legs.leg_cm * legs.across)}
            target = {"effector": "right_foot", "position": vec(legs.target), "pole": pole}
            result = post_frame(legs, legs.frame([target]))
            assert result["success"] is True
            assert sign * legs.knee_side(result) > 0.02 * legs.leg_cm
        far = vec(legs.hip + [5000.0, 5000.0, 5000.0])
        bones = legs.frame([])["bones"]  # the bones' world positions, asked per frame
        # `legs.s` has the id and token a stream takes.
        with (
            Client(server.base, timeout_s=TIMEOUT_S) as ik,
            ik.stream(legs.s, encoding=Encoding.MSGPACK) as stream,  # type: ignore[arg-type]
        ):
            for sign in (1.0, -1.0):
                pole = {"position": vec(legs.middle + sign * legs.leg_cm * legs.across)}
                target = {"effector": "right_foot", "position": vec(legs.target), "pole": pole}
                r = stream.frame([target], bones=bones)  # type: ignore[list-item]
                assert r.success is True, r
                assert sign * legs.knee_side({"bones": r.bones}) > 0.02 * legs.leg_cm
            freed = [
                {"effector": "left_foot", "position": vec(legs.left + [0.0, 10.0, 0.0])},
                {"effector": "right_foot", "position": far, "position_weight": 0.0},
            ]
            r = stream.frame(freed)  # type: ignore[arg-type]
            assert r.success is True, r
            assert r.effectors is not None
            errors = {e.name: e for e in r.effectors}
            assert errors["right_foot"].position_error_m is None
