"""Layout of a compiled chain's arrays (``CompiledChain``), shared by the model that
writes them and the compiled kinematics that read them.

    NI  int64[n_nodes, 3]     parent node (-1: root), kind (NODE_*), variable index
                              (-1: none)
    ND  float64[n_nodes, 31]  fixed transform before the motion (3x4, row-major,
                              0:12), unit axis (12:15), world rotation (15:24, row-
                              major) and origin (24:27) written by FK, the
                              Jacobian's axis (27:30): rate x the unit axis, and
                              the rate (30): the motion is rate x q[variable] (1,
                              or a mimic joint's multiplier). The Jacobian reads
                              its own axis so that a column costs what it did
                              before mimic joints (bench/RESULTS.md, issue 26).
    EI  int64[n_eff, 3]       node, mode (MODE_*), active flag
    ED  float64[n_eff, 36]    tip frame in the link (3x4, 0:12), aim axis (12:15),
                              weights w_p, w_r (15, 16), target position (17:20),
                              target rotation (20:29), target direction (29:32),
                              tolerances (32, 33), last errors [m], [rad] (34, 35)

The model fills the static columns (frames, axes, tip, weights); the IK writes the
rest per frame (targets, tolerances, active flags) into its own copies.
"""

from __future__ import annotations

# NI columns
NI_PARENT = 0
NI_KIND = 1
NI_DOF = 2
# ND columns
ND_PRE = 0
ND_AXIS = 12
ND_R = 15
ND_T = 24
ND_JAXIS = 27
ND_RATE = 30
ND_WIDTH = 31
# EI columns
EI_NODE = 0
EI_MODE = 1
EI_ACTIVE = 2
# ED columns
ED_TIP = 0
ED_AIM = 12
ED_WP = 15
ED_WR = 16
ED_TPOS = 17
ED_TROT = 20
ED_TDIR = 29
ED_TOL_P = 32
ED_TOL_R = 33
ED_ERR_P = 34
ED_ERR_R = 35
ED_WIDTH = 36
NODE_FIXED = 0
NODE_ROTATION = 1
NODE_TRANSLATION = 2
MODE_POSITION = 0
MODE_POSE = 1
MODE_AIM = 2
