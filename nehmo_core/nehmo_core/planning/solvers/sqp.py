"""An exact SQP for Opt: a handful of variables, a few constraints, a tiny QP per iteration.

1. If the naive step (the box-clipped minimizer of the cost) satisfies every constraint, it is
   the solution: the cost is convex and its minimizer over the box is feasible.
2. Otherwise iterate from the warm start: linearize the constraints, solve the QP with the
   Lagrangian Hessian approximation ``B`` (the cost's ``2I`` plus a damped BFGS correction for
   the constraints' curvature) exactly with DAQP (a dual active-set solver for small dense QPs),
   and accept the step with a backtracking line search on the ℓ₁ merit function.
3. Stop when a QP step, or the full step just taken, is below ``tol`` at a point whose
   constraint violation is below ``feasibility_tol`` (a KKT point, as IPOPT's); report
   ``infeasible`` when a linearization has no feasible point (after starting again from the
   naive step and from ``y = 0``) and ``timeout`` when the deadline passes.

After the naive-step check, the whole solve (screened iterations and restarts) runs in one C
call (:mod:`.native`) when every pair model has generated code; the Python code below is the
same algorithm and the fallback.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from nehmo_core.planning.numerics.qp import QPStep, qp_step
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import SolverSettings
from nehmo_core.planning.solvers.native import loop

__all__ = ["QPStep", "SolveResult", "qp_step", "solve_sqp"]


@dataclass(frozen=True)
class SolveResult:
    """A solver's answer: step ``y`` [rad], status, iterations, constraint values at ``y``."""

    y: np.ndarray
    status: str  # "naive", "optimal", "infeasible", "iteration_limit", "timeout", "failed"
    iterations: int
    constraint: np.ndarray  # V − ε at y, (m,); NaN for rows a screened solve left unevaluated
    hessian: np.ndarray | None = None  # the final Lagrangian Hessian approximation (n, n)

    @property
    def success(self) -> bool:
        return self.status in ("naive", "optimal")


def _c_status(status: str, flag: int) -> str:
    """A C loop's status, a failure with the QP exit flag that caused it."""
    return f"failed (QP exit flag {flag})" if status == "failed" else status


def _violation(c: np.ndarray) -> float:
    """Total constraint violation ``Σ max(0, −cᵢ)``."""
    return -float(c[c < 0.0].sum())


def _shortfall(c: np.ndarray) -> float:
    """Largest constraint violation ``max(0, −min c)``; infinite if a row is NaN."""
    if not len(c):
        return 0.0
    low = float(c.min())
    return max(0.0, -low) if low == low else np.inf


def _bfgs(B: np.ndarray, s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Powell-damped BFGS update of ``B`` with step ``s`` and Lagrangian-gradient change ``r``."""
    Bs = B @ s
    sBs = float(s @ Bs)
    if sBs <= 1e-18:
        return B
    sr = float(s @ r)
    if sr < 0.2 * sBs:
        theta = 0.8 * sBs / (sBs - sr)
        r = theta * r + (1.0 - theta) * Bs
        sr = float(s @ r)
    return B - np.outer(Bs / sBs, Bs) + np.outer(r / sr, r)


def solve_sqp(
    problem: OptProblem,
    y_start: np.ndarray,
    tol: float = SolverSettings.sqp_tol,
    max_iter: int = SolverSettings.sqp_max_iter,
    deadline: float = np.inf,
    hessian: np.ndarray | None = None,
    feasibility_tol: float = 1e-7,
    screen: float | None = SolverSettings.sqp_screen,
    native: bool = True,
) -> SolveResult:
    """Solve ``problem`` from ``y_start``; ``deadline`` is a ``time.perf_counter()`` instant.

    Converged when a QP step, or a full step just taken, is no longer than ``tol`` [rad] in
    every joint, at a point that violates no constraint by more than ``feasibility_tol`` [m].
    ``hessian`` warm-starts the Lagrangian Hessian approximation (e.g. the previous tick's);
    the default is the cost's ``2I``. ``infeasible`` means that the iterations met a
    linearization without a feasible point from ``y_start``, from the naive step and from
    ``y = 0`` (each tried once).

    ``screen`` [m]: with several V rows, the iterations carry only those below ``screen`` at the
    naive step (their values there are at hand), so each iteration evaluates fewer pairs. At a
    solution of that smaller problem the other V rows are evaluated; rows it breaks join (with any
    now below ``screen``) and the iterations go on from there. The answer is therefore a KKT
    point of the whole problem, as without screening. ``None`` carries every row throughout.

    ``native``: run the solve after the naive-step check in C (:mod:`.native`) when every pair
    model has generated code and a compiler works; the same algorithm as the Python loop, so the
    same answers up to rounding. ``False`` forces the Python loop.
    """
    cons = problem.constraints
    naive = problem.naive_step()
    c, J = cons.evaluate(naive)
    if _shortfall(c) == 0.0:
        return SolveResult(naive, "naive", 0, c)
    n, ymax, rows = len(naive), problem.y_max, cons.value_count
    B = 2.0 * np.eye(n) if hessian is None or hessian.shape != (n, n) else hessian.copy()
    keep = np.ones(rows, dtype=bool)
    if screen is not None and rows > 1:
        keep = c[:rows] < screen
    y = np.minimum(np.maximum(y_start, -ymax), ymax)
    if native and (c_loop := loop()) is not None:
        out = c_loop.solve(
            problem, y, naive, (c, J), B, keep, screen, tol, max_iter, deadline, feasibility_tol
        )
        if out is not None:
            status, iterations, y, c, hessian, flag = out
            return SolveResult(y, _c_status(status, flag), iterations, c, hessian)
    args = (tol, deadline, feasibility_tol, screen, native)

    def at(start: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        return (c, J) if np.array_equal(start, naive) else None  # the naive step's rows: at hand

    result = _screened(problem, y, B, keep, max_iter, *args, at(y))
    # A linearization without a feasible point shows that the QP is infeasible, not Opt: from a
    # warm start far from the solution (e.g. the last tick's fail-safe step, at a corner of the
    # box) it often is not. Before the fail-safe, the iterations start again from the naive step
    # and from standing still (y = 0), unless they started there already.
    tried = [y]
    for start in (naive, np.zeros(n)):
        used = result.iterations
        if result.status != "infeasible" or used >= max_iter:
            break
        if any(np.array_equal(start, t) for t in tried):
            continue
        tried.append(start)
        result = _screened(problem, start, B, keep, max_iter - used, *args, at(start))
        result = replace(result, iterations=used + result.iterations)
    return result


def _screened(
    problem: OptProblem,
    y: np.ndarray,
    B: np.ndarray,
    keep: np.ndarray,
    max_iter: int,
    tol: float,
    deadline: float,
    feasibility_tol: float,
    screen: float | None,
    native: bool,
    start_values: tuple[np.ndarray, np.ndarray] | None = None,
) -> SolveResult:
    """The SQP iterations from ``y`` on the V rows where ``keep``, adding the rows a solution
    breaks (or brings below ``screen``) until it holds them all (see :func:`solve_sqp`).
    ``start_values``: every row's ``(c, J)`` at ``y``, when the caller has them."""
    cons, rows = problem.constraints, problem.constraints.value_count
    keep = keep.copy()
    used = 0
    while True:
        budget = max_iter - used
        if keep.all():
            result = _iterate(
                problem, y, B, tol, budget, deadline, feasibility_tol, native, start_values
            )
            return replace(result, iterations=used + result.iterations)
        carried = np.concatenate([np.flatnonzero(keep), np.arange(rows, cons.count)])
        reduced = replace(problem, constraints=cons.subset(keep))
        if start_values is not None:
            start_values = (start_values[0][carried], start_values[1][carried])
        result = _iterate(
            reduced, y, B, tol, budget, deadline, feasibility_tol, native, start_values
        )
        start_values = None  # the next round starts at the solution, not at y
        used += result.iterations
        if not result.success:
            full = np.full(cons.count, np.nan)  # rows screened out were not evaluated at y
            full[carried] = result.constraint
            return replace(result, iterations=used, constraint=full)
        y = result.y
        # the carried rows are at hand at y: evaluate the others only
        c = np.empty(cons.count)
        c[carried] = result.constraint
        c[np.flatnonzero(~keep)] = cons.subset(~keep).evaluate(y)[0][: rows - int(keep.sum())]
        broken = ~keep & (c[:rows] < -feasibility_tol)
        if not broken.any():
            return SolveResult(y, "optimal", used, c, result.hessian)
        if used >= max_iter:
            return SolveResult(y, "iteration_limit", used, c)
        keep |= c[:rows] < (np.inf if screen is None else screen)  # None: all kept already
        if result.hessian is not None:
            B = result.hessian


def _iterate(
    problem: OptProblem,
    y: np.ndarray,
    B: np.ndarray,
    tol: float,
    max_iter: int,
    deadline: float,
    feasibility_tol: float,
    native: bool = False,
    start_values: tuple[np.ndarray, np.ndarray] | None = None,
) -> SolveResult:
    """SQP iterations on ``problem`` from ``y`` with Hessian approximation ``B`` (in C when
    ``native`` and the C loop can evaluate every model, else in Python); ``start_values`` are
    the rows' ``(c, J)`` at ``y`` if the caller has them."""
    cons, ymax, n = problem.constraints, problem.y_max, len(y)
    if native and (c_loop := loop()) is not None:
        out = c_loop.iterate(problem, y, B, tol, max_iter, deadline, feasibility_tol, start_values)
        if out is not None:
            status, iterations, y, B, c, flag = out
            hessian = B if status == "optimal" else None
            return SolveResult(y, _c_status(status, flag), iterations, c, hessian)
    error0 = problem.error0
    c, J = cons.evaluate(y) if start_values is None else start_values
    rho = 1.0
    for iteration in range(1, max_iter + 1):
        if time.perf_counter() > deadline:
            return SolveResult(y, "timeout", iteration, c)
        grad = 2.0 * (error0 + y)
        lo, hi = -ymax - y, ymax - y
        step = qp_step(B, grad, c, J, lo, hi)
        if not step.feasible and step.flag != -1:  # B lost definiteness to rounding: the cost's 2I
            B = 2.0 * np.eye(n)
            step = qp_step(B, grad, c, J, lo, hi)
        if step.flag == -1:
            return SolveResult(y, "infeasible", iteration, c)
        if not step.feasible:
            return SolveResult(y, f"failed (QP exit flag {step.flag})", iteration, c)
        p, lam = step.p, step.lam
        step_size = max(float(p.max()), -float(p.min()))
        low = float(c.min())
        if step_size <= tol and -low <= feasibility_tol:
            return SolveResult(y, "optimal", iteration, c, B)
        if len(lam):
            rho = max(rho, 1.5 * float(lam.max()) + 1e-3)
        violation = _violation(c) if low < 0.0 else 0.0
        merit = 0.25 * float(grad @ grad) + rho * violation  # ‖e₀ + y‖² = ¼‖grad‖²
        slope = float(grad @ p) - rho * violation
        alpha = 1.0
        while True:
            y_new = np.minimum(np.maximum(y + alpha * p, -ymax), ymax)
            c_new, J_new = cons.evaluate(y_new)
            e = error0 + y_new
            merit_new = float(e @ e) + rho * _violation(c_new)
            if merit_new <= merit + 1e-4 * alpha * slope or alpha < 1e-3:
                break
            alpha *= 0.5
        s = y_new - y
        B = _bfgs(B, s, 2.0 * s - lam @ (J_new - J))
        y, c, J = y_new, c_new, J_new
        if alpha == 1.0 and step_size <= tol and _shortfall(c) <= feasibility_tol:
            # the full step just taken was below tol: near a solution the steps shrink
            # superlinearly, so this point is closer still
            return SolveResult(y, "optimal", iteration, c, B)
    return SolveResult(y, "iteration_limit", max_iter, c)
