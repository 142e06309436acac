"""Planned clips: a whole clip of frames solved at once, on ``solver.ik``'s documented
surface (``IKSolver.track``, ``judge``, ``load_frame``, ``free_mask``,
``free_directions``, ``stream_state``, ``restore``) and its compiled kinematics.

Where things are:
    planner.py     ``plan_path``: how a plan is decided (the module docstring), smoothing
    programme.py   the dynamic programme over frames x nodes (``Planner``)
    keyframes.py   keyframe plans, filled-in frames, repairs, cuts in an animation
    kernels.py     the compiled pieces (nodes of a frame, projections, a programme step)
    options.py     ``PathOptions``, ``PlannedPath``
"""

from .options import PathOptions, PlannedPath
from .planner import plan_path

__all__ = ["PathOptions", "PlannedPath", "plan_path"]
