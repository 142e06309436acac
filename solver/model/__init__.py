"""The kinematic model: joints, effectors, chains, rotations, forward kinematics and
importers (URDF, glTF, BVH). Knows no optimizer and no IK.

Where things are:
    joints.py     ``JointKind``, ``EffectorMode``, ``Transform``, ``Joint``, ``Effector``
    chain.py      ``Chain``, ``build_chain`` (validation) and its compiled arrays
    mimic.py      mimic joints: ``Followers``, leaders resolved, leaders' ranges narrowed
    limbs.py      ``limb_chain``: a chain cut down to some effectors' paths
    notes.py      ``ModelNote``, ``NoteKind``: what an importer read by a convention
    layout.py     the columns of those arrays (shared with ``solver.ik``'s kernels)
    forward.py    forward kinematics (compiled, and ``link_poses`` / ``effector_poses``)
    rotations.py  quaternion / matrix / roll-pitch-yaw conversions
    urdf.py       ``chain_from_urdf``
    gltf.py       ``read_gltf``: a glTF 2.0 skin's joints as a ``Skeleton``
    gltf_container.py  the GLB / JSON container and its buffer checks
    bvh.py        ``read_bvh``: a BVH hierarchy (and its motion) as a ``Skeleton``
    bones.py      ``Skeleton``, ``Bone``, ``Channel``, ``Motion``: what the importers give
    skeleton.py   ``chain_from_skeleton``: a skeleton and per-bone settings as a chain,
                  with bone rotations and transforms for a game engine
    skeleton_settings.py  ``SkeletonSettings``, ``BoneSettings``, ``FreeRoot``
    examples.py   the built-in example chains (``EXAMPLES``)
"""

from .chain import MAX_DOF_HARD, Chain, CompiledChain, build_chain
from .joints import Effector, EffectorMode, Joint, JointKind, Mimic, Transform
from .mimic import Followers
from .notes import ModelNote, NoteKind
from .rotations import matrix_to_quaternion, quaternion_to_matrix, rpy_to_matrix

__all__ = [
    "MAX_DOF_HARD",
    "Chain",
    "CompiledChain",
    "Effector",
    "EffectorMode",
    "Followers",
    "Joint",
    "JointKind",
    "Mimic",
    "ModelNote",
    "NoteKind",
    "Transform",
    "build_chain",
    "matrix_to_quaternion",
    "quaternion_to_matrix",
    "rpy_to_matrix",
]
