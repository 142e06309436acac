"""Optimizer benchmark on the More-Garbow-Hillstrom set (a benchmark, not a test).

Runs, in one process and on the same problems and starting points:
    ours single-pass BFGS   (the article's reference algorithm: one pass, no analyzer)
    ours multi-pass         (H reset when f stalls over K iterations)
    ours multi-pass + analyzer (the default policy table; no goal given, so it acts
                             on termination codes only: resets on stalls and
                             line-search failures, never on knowledge of f*)
each with analytic and with forward-difference gradients, beside scipy's BFGS and
L-BFGS-B with the same gradients and tightened tolerances (gtol 1e-10, ftol 1e-15).

Success: f <= f* + max(1e-8, 1e-5 |f*|) (f* from MGH, tabulated to 6 digits). Reported: solved count, summed
iterations and function evaluations over the problems every method solved (a fair
effort comparison), and the median wall time per problem.

    OPENBLAS_NUM_THREADS=1 python -m bench.optimizer [--reps 5] [--markdown PATH]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy
from scipy.optimize import minimize as scipy_minimize

from solver import AnalyzerPolicy, GradientMode, MinimizeOptions, minimize
from solver.optim import register_objective
from tests.solver.mgh import PROBLEMS, MGHProblem, mgh_objective

register_objective(mgh_objective, None, PROBLEMS[0].data())

MAX_ITER = 5000


@dataclass(frozen=True)
class Outcome:
    f: float
    iterations: int
    fevals: int
    seconds: float


def ours(
    policy: AnalyzerPolicy, stall_window: int, gradient: GradientMode, *, with_goal: bool = False
) -> Callable[[MGHProblem], Outcome]:
    opts = MinimizeOptions(
        gtol=1e-10,
        stall_window=stall_window,
        gradient=gradient,
        max_iter=MAX_ITER,
        max_fev=200 * MAX_ITER,
        max_passes=512,
        max_restarts=10 if with_goal else 0,
        restart_radius=10.0,
    )

    def run(p: MGHProblem) -> Outcome:
        o = opts
        if with_goal:
            o = replace(opts, f_goal=p.f_star + max(1e-8, 1e-5 * abs(p.f_star)))
        t = time.perf_counter()
        r = minimize(
            mgh_objective,
            p.x0,
            data=p.data(),
            options=o,
            policy=policy,
            rng=np.random.default_rng(0),
        )
        return Outcome(r.f, r.iterations, r.function_evals, time.perf_counter() - t)

    return run


def scipy_method(method: str, analytic: bool) -> Callable[[MGHProblem], Outcome]:
    def run(p: MGHProblem) -> Outcome:
        data = p.data()
        calls = [0]

        def fg(x: np.ndarray) -> tuple[float, np.ndarray]:
            calls[0] += 1
            g = np.zeros_like(x)
            return float(mgh_objective(np.ascontiguousarray(x), g, True, data)), g

        def f_only(x: np.ndarray) -> float:
            calls[0] += 1
            return float(mgh_objective(np.ascontiguousarray(x), np.zeros_like(x), False, data))

        opts = {"gtol": 1e-10, "maxiter": MAX_ITER}
        if method == "L-BFGS-B":
            opts.update({"ftol": 1e-15, "maxfun": 200 * MAX_ITER})
        t = time.perf_counter()
        with np.errstate(all="ignore"):
            if analytic:
                r = scipy_minimize(fg, p.x0, jac=True, method=method, options=opts)
            else:
                r = scipy_minimize(f_only, p.x0, jac="2-point", method=method, options=opts)
        return Outcome(float(r.fun), int(r.nit), calls[0], time.perf_counter() - t)

    return run


def methods() -> dict[str, Callable[[MGHProblem], Outcome]]:
    out: dict[str, Callable[[MGHProblem], Outcome]] = {}
    for grad, label in ((GradientMode.ANALYTIC, "analytic"), (GradientMode.FORWARD, "forward FD")):
        out[f"ours single-pass ({label})"] = ours(AnalyzerPolicy.single_pass(), 0, grad)
        out[f"ours multi-pass ({label})"] = ours(AnalyzerPolicy.multi_pass(), 5, grad)
        out[f"ours multi-pass+analyzer ({label})"] = ours(AnalyzerPolicy.default(), 5, grad)
        # The article's analyzer holds per-function knowledge; given the goal f <= f*
        # it restarts from local minima (10 seeded restarts within +-10 of x0).
        out[f"ours analyzer + goal f* ({label})"] = ours(
            AnalyzerPolicy.default(), 5, grad, with_goal=True
        )
        analytic = grad is GradientMode.ANALYTIC
        out[f"scipy BFGS ({label})"] = scipy_method("BFGS", analytic)
        out[f"scipy L-BFGS-B ({label})"] = scipy_method("L-BFGS-B", analytic)
    return out


def solved(p: MGHProblem, o: Outcome) -> bool:
    # MGH tabulate f* to 6 significant digits: allow that rounding, else 1e-8 absolute.
    return o.f <= p.f_star + max(1e-8, 1e-5 * abs(p.f_star))


def per_problem_table(
    grad: str,
    names: list[str],
    labels: list[str],
    probs: dict[str, MGHProblem],
    results: dict[str, dict[str, Outcome]],
    *,
    with_f_star: bool,
) -> list[str]:
    """Final f (iterations) per problem and method; a cross marks a miss."""
    head = "| problem | " + ("f* | " if with_f_star else "") + " | ".join(names) + " |"
    lines = ["", f"### Per problem: final f (iterations) — {grad} gradients", "", head]
    lines.append("|---|" + ("---|" if with_f_star else "") + "---|" * len(names))
    for lab in labels:
        cells = []
        for m in names:
            o = results[m][lab]
            mark = "" if solved(probs[lab], o) else " ✗"
            cells.append(f"{o.f:.3g} ({o.iterations}){mark}")
        star = f"{probs[lab].f_star:.6g} | " if with_f_star else ""
        lines.append(f"| {lab} | {star}" + " | ".join(cells) + " |")
    return lines


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--reps", type=int, default=3, help="timing repetitions (median)")
    ap.add_argument("--markdown", help="also write the tables as Markdown to this file")
    args = ap.parse_args()
    t0 = time.perf_counter()
    minimize(mgh_objective, PROBLEMS[0].x0, data=PROBLEMS[0].data())  # compile / load cache
    for grad in (GradientMode.FORWARD,):
        minimize(
            mgh_objective,
            PROBLEMS[0].x0,
            data=PROBLEMS[0].data(),
            options=MinimizeOptions(gradient=grad),
        )
    warm = time.perf_counter() - t0
    table = methods()
    results: dict[str, dict[str, Outcome]] = {m: {} for m in table}
    for p in PROBLEMS:
        label = f"{p.name}(n={p.n})"
        print(f"  {label}", file=sys.stderr)
        for m, run in table.items():
            outs = [run(p) for _ in range(args.reps)]
            o = outs[0]
            results[m][label] = Outcome(
                o.f, o.iterations, o.fevals, statistics.median(x.seconds for x in outs)
            )
    labels = [f"{p.name}(n={p.n})" for p in PROBLEMS]
    probs = {f"{p.name}(n={p.n})": p for p in PROBLEMS}
    lines = []
    lines.append(
        f"MGH set: {len(PROBLEMS)} problems; success f <= f* + max(1e-8, 1e-5 |f*|); iteration cap {MAX_ITER}"
    )
    for grad in ("analytic", "forward FD"):
        names = [m for m in table if m.endswith(f"({grad})")]
        common = [lab for lab in labels if all(solved(probs[lab], results[m][lab]) for m in names)]
        lines.append("")
        lines.append(f"### Gradients: {grad} ({len(common)} problems solved by every method)")
        lines.append("")
        lines.append(
            "| method | solved | iterations (common) | f evals (common) | median time per problem [us] |"
        )
        lines.append("|---|---|---|---|---|")
        for m in names:
            r = results[m]
            ok = sum(solved(probs[lab], r[lab]) for lab in labels)
            its = sum(r[lab].iterations for lab in common)
            fev = sum(r[lab].fevals for lab in common)
            med = statistics.median(r[lab].seconds for lab in labels) * 1e6
            lines.append(f"| {m} | {ok}/{len(labels)} | {its} | {fev} | {med:.0f} |")
    lines.append("")
    for grad, with_f_star in (("analytic", True), ("forward FD", False)):
        lines += per_problem_table(
            grad,
            [m for m in table if m.endswith(f"({grad})")],
            labels,
            probs,
            results,
            with_f_star=with_f_star,
        )
    lines.append(
        f"Compile/load of the core before timing: {warm:.2f} s (objectives passed as values are compiled per process)."
    )
    lines.append(
        f"Machine: {os.cpu_count()} cores, {platform.processor() or platform.machine()}; Python {platform.python_version()}, "
        f"numpy {np.__version__}, scipy {scipy.__version__}, numba {__import__('numba').__version__}."
    )
    lines.append(f"Command: `OPENBLAS_NUM_THREADS=1 python -m bench.optimizer --reps {args.reps}`")
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        with open(args.markdown, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
