"""A chain cut down to some of its effectors (``limb_chain``): the joints on their
paths to the root, and nothing else.

``solver.ik.split`` solves the groups of a frame's effectors that share no variable
(a humanoid's legs and its torso with the arms) one at a time, each on its own limb
chain: the same joints, effectors and limits, at the size of the limb.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from .chain import Chain, build_chain


def limb_chain(chain: Chain, effectors: Sequence[int]) -> tuple[Chain, np.ndarray]:
    """The chain of ``chain.effectors[i]`` for i in ``effectors``, and for each of its
    variables the index of the same variable in ``chain``'s q.

    Kept: every joint on a path from one of those effectors' links to the root, and
    where such a joint follows another (mimic), the leader's joint and its path too.
    The variables keep their names and the whole chain's limits (a follower outside
    the limb still narrows its leader's range).
    """
    by_child = {j.child: j for j in chain.joints}
    by_name = {j.name: j for j in chain.joints}
    keep: set[str] = set()
    links = [chain.effectors[i].link for i in effectors]
    while links:
        link = links.pop()
        while link in by_child:
            joint = by_child[link]
            if joint.name in keep:
                break
            keep.add(joint.name)
            if joint.mimic is not None:  # the leader moves this joint: its path too
                links.append(by_name[joint.mimic.joint].child)
            link = joint.parent
    joints = [j for j in chain.joints if j.name in keep]
    limb = build_chain(joints, [chain.effectors[i] for i in sorted(effectors)])
    index = {name: i for i, name in enumerate(chain.dof_names)}
    variables = np.array([index[name] for name in limb.dof_names], dtype=np.int64)
    limb = replace(
        limb, lower=chain.lower[variables].copy(), upper=chain.upper[variables].copy(), notes=()
    )
    return limb, variables
