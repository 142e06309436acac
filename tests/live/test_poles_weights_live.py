"""Poles and blend weights against a real server (uvicorn on 127.0.0.1): CesiumMan's legs
in Unity's conventions, centimetres; the knee's side from the answers' bone positions.
The same geometry as tests/service/test_poles_weights.py, over real sockets."""

from __future__ import annotations

from typing import Any

import httpx
import msgpack
import pytest
from websockets.sync.client import connect

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
        url = server.base.replace("http", "ws", 1) + f"/v1/sessions/{legs.s.id}/ws"
        far = vec(legs.hip + [5000.0, 5000.0, 5000.0])
        with connect(url, additional_headers=legs.s.headers, open_timeout=TIMEOUT_S) as ws:
            for fid, sign in enumerate((1.0, -1.0), start=1):
                pole = {"position": vec(legs.middle + sign * legs.leg_cm * legs.across)}
                target = {"effector": "right_foot", "position": vec(legs.target), "pole": pole}
                ws.send(msgpack.packb({"type": "frame", "id": fid, **legs.frame([target])}))
                answer: dict[str, Any] = msgpack.unpackb(ws.recv(timeout=TIMEOUT_S))
                assert answer["success"] is True, answer
                assert sign * legs.knee_side(answer["result"]) > 0.02 * legs.leg_cm
            freed = [
                {"effector": "left_foot", "position": vec(legs.left + [0.0, 10.0, 0.0])},
                {"effector": "right_foot", "position": far, "position_weight": 0.0},
            ]
            ws.send(msgpack.packb({"type": "frame", "id": 3, "targets": freed}))
            answer = msgpack.unpackb(ws.recv(timeout=TIMEOUT_S))
            assert answer["success"] is True, answer
            errors = {e["name"]: e for e in answer["result"]["effectors"]}
            assert errors["right_foot"]["position_error_m"] is None
