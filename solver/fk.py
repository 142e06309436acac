"""Forward kinematics from Python: link and effector poses as 4x4 matrices."""

from __future__ import annotations

import numpy as np

from .chain import Chain
from .kinematics import ND_R, ND_T, effector_frame_py, forward_kinematics
from .types import Matrix, Vector


def _node_frames(chain: Chain, q: Vector) -> np.ndarray:
    cc = chain.compiled
    nd = cc.nd.copy()
    qa = np.ascontiguousarray(q, dtype=np.float64).reshape(-1)
    if qa.shape != (chain.n_dof,):
        raise ValueError(f"q must have {chain.n_dof} values, got {qa.shape[0]}")
    forward_kinematics(qa, cc.ni, nd)
    return nd


def link_poses(chain: Chain, q: Vector) -> dict[str, Matrix]:
    """World pose (4x4, base = root link frame) of every link for joint values q."""
    nd = _node_frames(chain, q)
    out: dict[str, Matrix] = {}
    for link, node in chain.compiled.link_node.items():
        m = np.eye(4)
        if node >= 0:
            m[:3, :3] = nd[node, ND_R : ND_R + 9].reshape(3, 3)
            m[:3, 3] = nd[node, ND_T : ND_T + 3]
        out[link] = m
    return out


def effector_poses(chain: Chain, q: Vector) -> list[Matrix]:
    """World pose (4x4) of each effector's tip frame, in ``chain.effectors`` order."""
    nd = _node_frames(chain, q)
    cc = chain.compiled
    out = []
    for e in range(len(chain.effectors)):
        frame = effector_frame_py(e, cc.ei, cc.ed, nd)
        m = np.eye(4)
        m[:3, :3] = np.array(frame[:9]).reshape(3, 3)
        m[:3, 3] = frame[9:]
        out.append(m)
    return out
