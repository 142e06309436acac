"""IK benchmark: our solver side by side with its peers, in one run (issue #3, part 5).

    OPENBLAS_NUM_THREADS=1 python -m bench.ik [--quick] [--n 10000] [--peer-n 1000]
        [--streams 3] [--chains panda,ur5,iiwa,tail40,humanoid_arm]
        [--solvers ours,ours-bfgs,scipy,rtb,ikpy,clik] [--markdown bench/RESULTS.md]

Run it from the repository root. Tables go to stdout
(Markdown), progress to stderr. This is a benchmark, not a test: it never fails on a
missed target, it prints PASS/FAIL.

Solvers (settings written out in the report):
  ours        solver.ik.IKSolver, default IKOptions (metric_every=1: Gauss-Newton metric
              every iteration) with tolerances 1e-5 m / 1e-4 rad and a 5000 us budget
  ours-bfgs   the same with metric_every=0 (the article's BFGS: metric only at pass start)
  scipy       scipy.optimize.minimize(method="L-BFGS-B", jac=True, bounds=limits) on OUR
              compiled objective and FK (solver.ik.kinematics.ik_objective on the IKSolver's
              data tuple after _load_targets), tightened ftol/gtol, no restarts
  rtb         roboticstoolbox-python's C++ ik_LM (bench/peers/rtb_peer.py)
  ikpy        ikpy 4 (bench/peers/ikpy_peer.py)
  clik        pinocchio's CLIK loop from its docs (bench/peers/pin_clik.py)
Peers load the URDF; for our example chains (tail40, humanoid_arm) bench/ik_chains.py
writes one from the Chain, and every peer's FK is checked against ours before timing.

Parts:
  a. TRAC-IK's protocol: N uniform random q within limits -> FK pose; solve from the
     mid-limits seed; success = position <= 1e-5 m and rotation <= 1e-4 rad by OUR FK
     (solver.model.forward.effector_poses on the chain), all joints within limits, and a wall time
     <= 5 ms. Never a solver's own flag.
  b. Position only, same targets, <= 1e-5 m.
  c. Tracking: smooth joint paths q(t) = c + A sin(2 pi f t + phi) (inside the limits)
     through FK, 600 frames at 60 Hz per stream; each frame warm-started from the
     solver's previous answer (ours: IKSolver.track); same success rule per frame.
Timing is the wall time of the Python call (IKSolver.solve / .track, peer.solve,
scipy.optimize.minimize), targets prebuilt. Solvers run interleaved target by target
(in a fresh random order for each target) so that load from other users hits all of them alike;
compare the ratios, not the absolute times.

The package, by concern: config (tolerances, solver keys, a run's Config), streams (the
targets of (a)/(b) and the reference paths of (c)), judging (the FK judge and the rows it
fills), adapters (ours, ours planned, the peers) and scipy_lbfgsb (the one adapter that
reaches into the solver), runners (make, warm and time the solvers), report (tables,
verdicts, settings, machine), __main__ (the command line).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # before numpy; the command should set it

# What the probes and bench/ab_core.py import from ``bench.ik``, and target_q, which the
# report names for reproducing a failed target.
from .adapters import Ours, ours_options  # noqa: E402
from .config import Config  # noqa: E402
from .runners import run_solves, run_tracking, warm  # noqa: E402
from .streams import max_step, reference_streams, target_q, targets_for  # noqa: E402

_targets_for = targets_for  # bench/ab_core.py's name for it (that file is being rewritten)

__all__ = [
    "Config",
    "Ours",
    "max_step",
    "ours_options",
    "reference_streams",
    "run_solves",
    "run_tracking",
    "target_q",
    "targets_for",
    "warm",
]
