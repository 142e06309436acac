"""The kinematic model: joints, effectors, chains, rotations, forward kinematics and
importers (URDF; later glTF / BVH). Knows no optimizer and no IK.

Where things are:
    joints.py     ``JointKind``, ``EffectorMode``, ``Transform``, ``Joint``, ``Effector``
    chain.py      ``Chain``, ``build_chain`` (validation) and its compiled arrays
    layout.py     the columns of those arrays (shared with ``solver.ik``'s kernels)
    forward.py    forward kinematics (compiled, and ``link_poses`` / ``effector_poses``)
    rotations.py  quaternion / matrix / roll-pitch-yaw conversions
    urdf.py       ``chain_from_urdf``
    examples.py   the built-in example chains (``EXAMPLES``)
"""

from .chain import MAX_DOF_HARD, Chain, CompiledChain, build_chain
from .joints import Effector, EffectorMode, Joint, JointKind, Transform
from .rotations import matrix_to_quaternion, quaternion_to_matrix, rpy_to_matrix

__all__ = [
    "MAX_DOF_HARD",
    "Chain",
    "CompiledChain",
    "Effector",
    "EffectorMode",
    "Joint",
    "JointKind",
    "Transform",
    "build_chain",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "rpy_to_matrix",
]
