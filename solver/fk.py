"""Forward kinematics from Python: link and effector poses as 4x4 matrices."""

from __future__ import annotations

import numpy as np

from .chain import Chain
from .kinematics import effector_frame, forward_kinematics
from .types import Matrix, Vector


def _node_frames(chain: Chain, q: Vector) -> tuple[np.ndarray, np.ndarray]:
    cc = chain.compiled
    n_nodes = cc.node_parent.shape[0]
    r = np.zeros((max(n_nodes, 1), 3, 3))
    t = np.zeros((max(n_nodes, 1), 3))
    qa = np.ascontiguousarray(q, dtype=np.float64)
    forward_kinematics(qa, cc.node_parent, cc.node_pre, cc.node_kind, cc.node_axis, cc.node_dof, r, t)
    return r, t


def link_poses(chain: Chain, q: Vector) -> dict[str, Matrix]:
    """World pose (4x4, base = root link frame) of every link for joint values q."""
    r, t = _node_frames(chain, q)
    out: dict[str, Matrix] = {}
    for link, node in chain.compiled.link_node.items():
        m = np.eye(4)
        if node >= 0:
            m[:3, :3] = r[node]
            m[:3, 3] = t[node]
        out[link] = m
    return out


def effector_poses(chain: Chain, q: Vector) -> list[Matrix]:
    """World pose (4x4) of each effector's tip frame, in ``chain.effectors`` order."""
    r, t = _node_frames(chain, q)
    cc = chain.compiled
    out = []
    for e in range(len(chain.effectors)):
        re = np.empty((3, 3))
        pe = np.empty(3)
        effector_frame(e, int(cc.eff_node[e]), cc.eff_tip, r, t, re, pe)
        m = np.eye(4)
        m[:3, :3] = re
        m[:3, 3] = pe
        out.append(m)
    return out
