"""schemas <-> solver: the one place where requests become solver objects and results
become answers.

One module per concern:

- ``chains``: chain specs (JSON joints, URDF, examples, glTF / BVH skeletons via
  ``skeletons``) -> ``ChainView``;
- ``conventions``: the client's up axis, handedness and unit <-> the chain's frame;
- ``bones``: joint vectors -> bone local rotations and world transforms;
- ``options``: the server's default ``IKOptions`` and a request's patch on them;
- ``frames``: a request's frames and targets -> solver targets (the pydantic path);
- ``fast_path``: the WebSocket's per-frame fast path (decoded message -> targets);
- ``poses``: ``q`` / ``joints`` <-> joint vectors;
- ``results``: solved frames -> JSON-ready answers;
- ``geometry``: vectors and quaternions -> arrays, shared by the others.

Every solver exception raised while turning a request into solver objects becomes a
``ServiceError`` ``invalid_problem`` naming the request field (``chain.joints[2].lower``).
Routes call these through the package (``convert.targets(...)``).
"""

from .bones import add_bones, bones_dict, fk_dict, wants_bones
from .chains import ChainView, chain_from_spec, check_bone_output
from .fast_path import FastFrame, fast_frame, fast_targets
from .frames import FrameJob, clip_jobs, targets
from .options import apply_options, oneshot_defaults, options_dict, session_defaults
from .poses import clipped_dofs, frame_pose, pose_dict, pose_vector
from .results import (
    ResultBuilder,
    SolvedFrame,
    compact_result_dict,
    plan_steps,
    plan_summary,
    render_frames,
    result_builder,
    result_dict,
)

__all__ = [
    "add_bones",
    "bones_dict",
    "check_bone_output",
    "fk_dict",
    "frame_pose",
    "wants_bones",
    "ChainView",
    "FastFrame",
    "FrameJob",
    "ResultBuilder",
    "SolvedFrame",
    "apply_options",
    "chain_from_spec",
    "clip_jobs",
    "compact_result_dict",
    "plan_steps",
    "fast_frame",
    "fast_targets",
    "oneshot_defaults",
    "options_dict",
    "plan_summary",
    "clipped_dofs",
    "pose_dict",
    "pose_vector",
    "render_frames",
    "result_builder",
    "result_dict",
    "session_defaults",
    "targets",
]
