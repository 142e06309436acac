"""The per-frame solve, compiled: one call validates the targets and the seed, runs the
optimizer's core (again on the exact task if the regularised one missed), polishes an
answer a few tolerances short of its goal (``polish``), reports the pose errors and
takes the null-space step.

One module because these functions call each other inside numba and share the layout
of the output block (errors, final H, pass log) that ``result.IKResult`` reads.
"""

from __future__ import annotations

import math

from .._clock import now_s
from .._jit import jit, jit_leaf
from ..errors import InvalidProblem
from ..model import Chain
from ..model.layout import (
    ED_ERR_P,
    ED_ERR_R,
    ED_TDIR,
    ED_TPOS,
    ED_TROT,
    ED_WP,
    ED_WR,
    EI_ACTIVE,
    EI_MODE,
    MODE_AIM,
    MODE_POSE,
    MODE_POSITION,
)
from ..optim import codes as C
from ..optim.loop import WORK_ROWS, CoreResult, run_solver_leaf
from .kinematics import (
    DD_HI,
    DD_LO,
    DD_QREF,
    DD_REST,
    DD_XLAST,
    MISC_GOAL,
    MISC_LIMIT,
    MISC_POLISH_STEPS,
    MISC_POSTURE,
    effector_errors,
    is_last_point,
)
from .metric import null_space_step
from .polish import POLISH_RESERVE, POLISH_WITHIN, polish

SEED_NOT_FINITE = -2  # ``solve_frame``'s "bad" code for a seed with NaN or inf
TARGETS_OK = -1  # ``solve_frame``'s "bad" code when targets and seed are valid
# ``solve_frame``'s status codes: indexes of ``result.STATUSES``.
STATUS_SOLVED = 0
STATUS_NOT_REACHED = 1
STATUS_BUDGET_EXHAUSTED = 2
STATUS_NONFINITE = 3


@jit_leaf
def check_targets(data):  # type: ignore[no-untyped-def]
    """-1 if the loaded targets are valid, else 3 * effector + problem (0 non-finite,
    1 rotation not orthonormal with det +1, 2 zero direction); normalises directions.

    Checked here, in compiled code, because the same checks in numpy cost ~25 us per
    target (np.allclose, det), more than a 7-DOF solve.
    """
    ei = data[2]
    ed = data[3]
    for e in range(ei.shape[0]):
        if ei[e, EI_ACTIVE] == 0:
            continue
        for k in range(ED_TPOS, ED_TDIR + 3):
            if not math.isfinite(ed[e, k]):
                return 3 * e
        if ei[e, EI_MODE] == MODE_POSE:
            t = ED_TROT
            worst = 0.0
            for a in range(3):
                for b in range(3):
                    dot = 0.0
                    for c in range(3):
                        dot += ed[e, t + 3 * a + c] * ed[e, t + 3 * b + c]
                    worst = max(worst, abs(dot - (1.0 if a == b else 0.0)))
            r = ed[e, t : t + 9]
            det = (
                r[0] * (r[4] * r[8] - r[5] * r[7])
                - r[1] * (r[3] * r[8] - r[5] * r[6])
                + r[2] * (r[3] * r[7] - r[4] * r[6])
            )
            if worst > 1e-6 or det < 0.0:
                return 3 * e + 1
        elif ei[e, EI_MODE] == MODE_AIM:
            d = ED_TDIR
            norm = math.sqrt(ed[e, d] ** 2 + ed[e, d + 1] ** 2 + ed[e, d + 2] ** 2)
            if norm < 1e-12:
                return 3 * e + 2
            for c in range(3):
                ed[e, d + c] /= norm
    return -1


def scratch_size(n: int, m: int) -> int:
    """Length of ``solve_frame``'s float scratch for n variables and m effectors."""
    return WORK_ROWS * n + 3 * n + 3 * m + n * n


@jit_leaf
def solve_frame(  # type: ignore[no-untyped-def]
    data, x0, h0, fopt, iopt, policy, out_x, out, null_space_step_rad, scratch, ints
):
    """One compiled call per frame: validate targets and seed, solve, report errors,
    and (``null_space_step_rad`` > 0, solved frames only) take the null-space step
    towards the rest pose (DD_REST).

    With a posture or limit weight, the solve is the regularised one first (its
    restarts held back); a frame that misses the goal is then solved again from the
    seed on the exact task, with the restarts and the budget left (see the comment at
    the call: the preferences must not cost the tolerances).

    An answer that ends within ``polish.POLISH_WITHIN`` tolerances of the goal gets
    up to MISC_POLISH_STEPS Levenberg-Marquardt steps after the optimizer, within the
    time budget (``polish``: kept only if they meet the goal; its steps count as
    iterations, its objective calls as evaluations, its time in the solve's). The
    optimizer's deadline then comes ``polish.POLISH_RESERVE`` of the budget earlier.

    One call and flat outputs because at ~20-40 us per solve, every Python-level
    step around it showed up in bench/ik/: a numba dispatch type-checks each
    array argument, and each returned array or nested tuple is boxed.

    Writes the pose into ``out_x`` and, into ``out``: per-effector errors (m x 3:
    position error, nan if not targeted (or weighted 0); rotation error, nan if not
    constrained (or weighted 0);
    1.0 if targeted), the final inverse Hessian (n x n), then the pass log.
    ``h0`` (the initial H) is read, never written.

    ``scratch`` (float64[scratch_size(n, m)]) and ``ints`` (int64[3]) are work space,
    the caller's: compiled without reference counting (``jit_leaf``), this function
    and everything it calls allocate nothing.

    Returns (bad_target, status, termination code, iterations, evaluations,
    passes, restarts, solve seconds); status indexes ``result.STATUSES``.
    """
    bad = check_targets(data)
    ei = data[2]
    dd = data[4]
    n = x0.shape[0]
    m = ei.shape[0]
    for i in range(n):
        if not math.isfinite(x0[i]):
            bad = SEED_NOT_FINITE
    if bad != -1:
        return bad, 0, 0, 0, 0, 0, 0, 0.0
    for i in range(n):
        dd[DD_QREF, i] = x0[i]  # the posture pull is towards the seed
    errors = out[: 3 * m].reshape((m, 3))
    h = out[3 * m : 3 * m + n * n].reshape((n, n))
    log = out[3 * m + n * n :].reshape((-1, C.N_LOG))
    for i in range(n):
        for j in range(n):
            h[i, j] = h0[i, j]
    # The scratch, cut into its parts (views: nothing is allocated).
    work = scratch[: WORK_ROWS * n].reshape((WORK_ROWS, n))
    k = WORK_ROWS * n
    out_g = scratch[k : k + n]
    moved = scratch[k + n : k + 2 * n]
    ns_g = scratch[k + 2 * n : k + 3 * n]
    k += 3 * n
    moved_flat = scratch[k : k + 3 * m]  # also the polish's 2m saved weights
    moved_errors = moved_flat.reshape((m, 3))
    ns_h = scratch[k + 3 * m : k + 3 * m + n * n].reshape((n, n))
    trace = scratch[:0].reshape((0, 5))  # records nothing
    # fg=None: the core binds the objective registered for this data type (cacheable).
    # The build without reference counting: the IK objective and metric allocate
    # nothing (their scratch is DD's rows), see _jit.jit_leaf.
    misc = data[5]
    w_posture = misc[MISC_POSTURE]
    w_limit = misc[MISC_LIMIT]
    # A goal of -inf (the pole shaping pass, ``poles``) is never met: nothing to retry.
    regularised = (w_posture > 0.0 or w_limit > 0.0) and fopt[C.F_F_GOAL] > -math.inf
    restarts = iopt[C.I_MAX_RESTARTS]
    # A share of a finite time budget is kept for the polish: the optimizer's deadline
    # comes that much earlier (restored below). Under a 5 ms budget, tail40's frames
    # that stall a hair off the goal end on the deadline, with no time left to finish.
    max_polish = int(misc[MISC_POLISH_STEPS])
    budget = fopt[C.F_BUDGET]
    if max_polish > 0 and math.isfinite(budget) and fopt[C.F_F_GOAL] > -math.inf:
        fopt[C.F_BUDGET] = budget * (1.0 - POLISH_RESERVE)
    if regularised:
        iopt[C.I_MAX_RESTARTS] = 0  # restarts belong to the exact phase (see below)
    res = run_solver_leaf(
        None, data, x0, h, dd[DD_LO], dd[DD_HI], fopt, iopt, policy, log, trace, out_x, out_g,
        work, ints,
    )  # fmt: skip
    code = res.code
    nit = res.iterations
    nfev = res.function_evals
    passes = res.passes
    elapsed = res.elapsed_s
    n_restarts = res.restarts
    polished = False
    if regularised:
        iopt[C.I_MAX_RESTARTS] = restarts
        if res.goal_measure > 1.0:
            # The posture pull and the limit band are preferences among poses that meet
            # the tolerances, never a reason to miss them: where the target needs a joint
            # inside the band (an arm stretched against its elbow stop), the regularised
            # f's minimum sits off the target (1-6e-5 m, bench/tracking.py) and every
            # restart ends there too. So a frame that misses is solved again from its
            # seed on the exact task (regularisation off), with the restarts and
            # whatever budget is left (from the seed, not from the regularised answer:
            # on the 40-DOF tail that answer lay deep against several limits, where the
            # exact solve crawled; from the seed it took 3 iterations). Its passes
            # follow in the log (one INITIAL start). The regularised answer is kept
            # (in ``moved``), with its termination code, if the exact solve ends
            # further from the goal (H, carried by a stream with carry_hessian, is
            # then the exact run's: an approximation either way, not worth an n x n copy).
            for i in range(n):
                moved[i] = out_x[i]
            misc[MISC_POSTURE] = 0.0
            misc[MISC_LIMIT] = 0.0
            exact = _continue_exact(
                data, x0, h, fopt, iopt, policy, log[passes:], trace, out_x, out_g, work,
                ints, nit, nfev, elapsed,
            )  # fmt: skip
            misc[MISC_POSTURE] = w_posture
            misc[MISC_LIMIT] = w_limit
            dd[DD_XLAST, 0] = math.nan  # the cached f was the exact one: stale now
            closer = exact.passes > 0 and exact.goal_measure > res.goal_measure
            if closer:
                for i in range(n):
                    out_x[i] = moved[i]  # the regularised answer was closer
            if exact.passes > 0:
                if not closer:  # the code describes the answer returned
                    code = exact.code
                nit += exact.iterations
                nfev += exact.function_evals
                passes += exact.passes
                elapsed += exact.elapsed_s
                n_restarts += exact.restarts
    fopt[C.F_BUDGET] = budget
    # The solve's answer is usually the point it evaluated last (ED holds its errors,
    # MISC its goal measure): reuse that instead of one more FK.
    if is_last_point(out_x, dd):
        measure = data[5][MISC_GOAL]
        _copy_errors(data, errors)
    else:
        measure = _report(data, out_x, errors)
    # An answer a few tolerances short of the goal: a bounded Levenberg-Marquardt
    # polish after the optimizer (``polish``), within the time the solve left; not on
    # a pole shaping pass (goal -inf), which has no goal to meet.
    time_left = budget - elapsed
    if (
        1.0 < measure <= POLISH_WITHIN
        and max_polish > 0
        and time_left > 0.0
        and fopt[C.F_F_GOAL] > -math.inf
    ):
        started = now_s()
        steps, evaluations = polish(
            data, out_x, max_polish, fopt[C.F_MAX_STEP], started + time_left, out_g, moved,
            ns_g, ns_h, moved_flat, work[0], work[1],
        )  # fmt: skip
        nit += steps
        nfev += evaluations
        elapsed += now_s() - started
        if steps > 0:
            measure = _report(data, out_x, errors)
            polished = True
    if measure <= 1.0 and null_space_step_rad > 0.0:
        if null_space_step(out_x, data, dd[DD_REST], null_space_step_rad, moved, ns_h, ns_g):
            if _report(data, moved, moved_errors) <= 1.0:
                # Loops, not slice assignment: that needs numba's runtime (a copy in case
                # the two overlap), which this build does not have.
                for i in range(n):
                    out_x[i] = moved[i]
                for e in range(m):
                    for c in range(3):
                        errors[e, c] = moved_errors[e, c]
    if measure <= 1.0:
        status = STATUS_SOLVED
        if polished:
            code = C.GOAL_REACHED  # the polish met the goal the optimizer stopped short of
    elif code == C.NONFINITE or not math.isfinite(measure):
        status = STATUS_NONFINITE
    elif code == C.MAX_ITER or code == C.MAX_FEV or code == C.DEADLINE:
        status = STATUS_BUDGET_EXHAUSTED
    else:
        status = STATUS_NOT_REACHED
    return bad, status, code, nit, nfev, passes, n_restarts, elapsed


@jit_leaf
def _continue_exact(  # type: ignore[no-untyped-def]
    data, x0, h, fopt, iopt, policy, log, trace, out_x, out_g, work, ints, nit, nfev, elapsed
):
    """The core from x0 (the answer into out_x) within the budgets a first run left
    (``nit`` iterations, ``nfev`` evaluations, ``elapsed`` seconds spent), H reset (the
    objective's metric seeds it). A result with 0 passes, out_x untouched, when
    nothing is left. The option vectors are restored on return."""
    dd = data[4]
    max_iter = iopt[C.I_MAX_ITER]
    max_fev = iopt[C.I_MAX_FEV]
    budget = fopt[C.F_BUDGET]
    if nit >= max_iter or nfev >= max_fev or elapsed >= budget or log.shape[0] == 0:
        return CoreResult(0.0, math.inf, 0.0, C.MAX_ITER, 0, 0, 0, 0, 0, 0, 0.0)
    n = x0.shape[0]
    for i in range(n):
        for j in range(n):
            h[i, j] = 1.0 if i == j else 0.0
    iopt[C.I_MAX_ITER] = max_iter - nit
    iopt[C.I_MAX_FEV] = max_fev - nfev
    fopt[C.F_BUDGET] = budget - elapsed
    res = run_solver_leaf(
        None, data, x0, h, dd[DD_LO], dd[DD_HI], fopt, iopt, policy, log, trace, out_x,
        out_g, work, ints,
    )  # fmt: skip
    iopt[C.I_MAX_ITER] = max_iter
    iopt[C.I_MAX_FEV] = max_fev
    fopt[C.F_BUDGET] = budget
    return res


@jit_leaf
def _report(data, q, errors):  # type: ignore[no-untyped-def]
    """Errors at q into ``errors`` (see ``solve_frame``); returns the goal measure."""
    measure = effector_errors(q, data)
    _copy_errors(data, errors)
    return measure


@jit_leaf
def _copy_errors(data, errors):  # type: ignore[no-untyped-def]
    """The errors in ED (those of the last q evaluated) into ``errors`` (m x 3)."""
    ei = data[2]
    ed = data[3]
    for e in range(ei.shape[0]):
        active = ei[e, EI_ACTIVE] != 0
        errors[e, 0] = ed[e, ED_ERR_P] if active and ed[e, ED_WP] > 0.0 else math.nan
        constrained = active and ei[e, EI_MODE] != MODE_POSITION and ed[e, ED_WR] > 0.0
        errors[e, 1] = ed[e, ED_ERR_R] if constrained else math.nan
        errors[e, 2] = 1.0 if active else 0.0


@jit
def report_only(data, q, out):  # type: ignore[no-untyped-def]
    """Validate targets and report errors at q into the head of ``out`` (the errors
    block of ``solve_frame``'s layout) without solving."""
    m = data[2].shape[0]
    errors = out[: 3 * m].reshape((m, 3))
    bad = check_targets(data)
    for i in range(q.shape[0]):
        if not math.isfinite(q[i]):
            bad = SEED_NOT_FINITE
    if bad != -1:
        return bad, 0.0
    return bad, _report(data, q, errors)


def raise_bad_target(chain: Chain, bad: int) -> None:
    """Raise the ``InvalidProblem`` that ``solve_frame``'s "bad" code names (a seed with
    NaN or inf, or the effector and part of a malformed target); nothing for TARGETS_OK."""
    if bad == SEED_NOT_FINITE:
        raise InvalidProblem("seed must be finite")
    if bad >= 0:
        name = chain.effectors[bad // 3].name
        what = (
            "numbers must be finite",
            "rotation must be orthonormal with det +1",
            "direction must not be zero",
        )[bad % 3]
        raise InvalidProblem(f"target for {name!r}: {what}")
