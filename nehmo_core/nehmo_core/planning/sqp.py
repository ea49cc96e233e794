"""An exact SQP for Opt: a handful of variables, a few constraints, a tiny QP per iteration.

1. If the naive step (the box-clipped minimizer of the cost) satisfies every constraint, it is
   the solution: the cost is convex and its minimizer over the box is feasible.
2. Otherwise iterate from the warm start: linearize the constraints, solve the QP with the
   Lagrangian Hessian approximation ``B`` (the cost's ``2I`` plus a damped BFGS correction for
   the constraints' curvature) exactly with DAQP (a dual active-set solver for small dense QPs),
   and accept the step with a backtracking line search on the ℓ₁ merit function.
3. Stop when the step and the constraint violation are below ``tol`` (a KKT point, as IPOPT's);
   report ``infeasible`` when a linearization has no feasible point and ``timeout`` when the
   deadline passes.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import daqp
import numpy as np

from nehmo_core.planning.opt import OptProblem

__all__ = ["QPStep", "SolveResult", "qp_step", "solve_sqp"]


@dataclass(frozen=True)
class SolveResult:
    """A solver's answer: step ``y`` [rad], status, iterations, constraint values at ``y``."""

    y: np.ndarray
    status: str  # "naive", "optimal", "infeasible", "iteration_limit", "timeout", "failed"
    iterations: int
    constraint: np.ndarray  # V − ε at y, (m,)
    hessian: np.ndarray | None = None  # the final Lagrangian Hessian approximation (n, n)

    @property
    def success(self) -> bool:
        return self.status in ("naive", "optimal")


@dataclass(frozen=True)
class QPStep:
    """The SQP's QP subproblem answer: step ``p``, multipliers of ``c + Jp ≥ 0``, DAQP's flag."""

    p: np.ndarray
    lam: np.ndarray  # ≥ 0, one per linearized constraint
    flag: int  # DAQP exit flag: 1 optimal, -1 infeasible, other < 0 solver trouble

    @property
    def feasible(self) -> bool:
        return self.flag >= 1


def qp_step(
    B: np.ndarray, grad: np.ndarray, c: np.ndarray, J: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> QPStep:
    """``min ½pᵀBp + gradᵀp s.t. c + Jp ≥ 0, lo ≤ p ≤ hi`` by DAQP's dual active-set method.

    DAQP solves small dense QPs exactly (up to rounding) and treats the step box as simple
    bounds. ``B`` must be positive definite; the SQP keeps it so by damped BFGS.
    """
    m = len(c)
    upper = np.concatenate([hi, np.full(m, np.inf)])
    lower = np.concatenate([lo, -c])
    p, _, flag, info = daqp.solve(B, grad, J, upper, lower)
    # DAQP's multipliers satisfy Bp + grad + [I; J]ᵀ lam = 0 with lam ≤ 0 on active lower bounds
    lam = np.maximum(0.0, -np.asarray(info["lam"], dtype=np.float64)[len(grad) :])
    return QPStep(np.asarray(p, dtype=np.float64), lam, int(flag))


def _merit(problem: OptProblem, y: np.ndarray, c: np.ndarray, rho: float) -> float:
    return problem.cost(y) + rho * float(np.maximum(0.0, -c).sum())


def _bfgs(B: np.ndarray, s: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Powell-damped BFGS update of ``B`` with step ``s`` and Lagrangian-gradient change ``r``."""
    Bs = B @ s
    sBs = float(s @ Bs)
    if sBs <= 1e-18:
        return B
    sr = float(s @ r)
    theta = 1.0 if sr >= 0.2 * sBs else 0.8 * sBs / (sBs - sr)
    r = theta * r + (1.0 - theta) * Bs
    return B - np.outer(Bs, Bs) / sBs + np.outer(r, r) / float(s @ r)


def solve_sqp(
    problem: OptProblem,
    y_start: np.ndarray,
    tol: float = 1e-7,
    max_iter: int = 30,
    deadline: float = np.inf,
    hessian: np.ndarray | None = None,
) -> SolveResult:
    """Solve ``problem`` from ``y_start``; ``deadline`` is a ``time.perf_counter()`` instant.

    ``hessian`` warm-starts the Lagrangian Hessian approximation (e.g. the previous tick's);
    the default is the cost's ``2I``.
    """
    cons = problem.constraints
    y = problem.naive_step()
    c, J = cons.evaluate(y)
    if np.all(c >= 0.0):
        return SolveResult(y, "naive", 0, c)
    n, ymax = len(y), problem.y_max
    y = np.clip(y_start, -ymax, ymax)
    c, J = cons.evaluate(y)
    B = 2.0 * np.eye(n) if hessian is None or hessian.shape != (n, n) else hessian.copy()
    rho = 1.0
    for iteration in range(1, max_iter + 1):
        if time.perf_counter() > deadline:
            return SolveResult(y, "timeout", iteration, c)
        grad = 2.0 * (problem.error0 + y)
        step = qp_step(B, grad, c, J, -ymax - y, ymax - y)
        if not step.feasible and step.flag != -1:  # B lost definiteness to rounding: the cost's 2I
            B = 2.0 * np.eye(n)
            step = qp_step(B, grad, c, J, -ymax - y, ymax - y)
        if step.flag == -1:
            return SolveResult(y, "infeasible", iteration, c)
        if not step.feasible:
            return SolveResult(y, f"failed (QP exit flag {step.flag})", iteration, c)
        p, lam = step.p, step.lam
        violation = float(np.maximum(0.0, -c).max(initial=0.0))
        if np.abs(p).max() <= tol and violation <= tol:
            return SolveResult(y, "optimal", iteration, c, B)
        rho = max(rho, 1.5 * float(lam.max(initial=0.0)) + 1e-3)
        merit = _merit(problem, y, c, rho)
        slope = float(grad @ p) - rho * float(np.maximum(0.0, -c).sum())
        alpha = 1.0
        while True:
            y_new = np.clip(y + alpha * p, -ymax, ymax)
            c_new, J_new = cons.evaluate(y_new)
            if _merit(problem, y_new, c_new, rho) <= merit + 1e-4 * alpha * slope or alpha < 1e-3:
                break
            alpha *= 0.5
        lagrangian_change = 2.0 * (y_new - y) - (J_new - J).T @ lam
        B = _bfgs(B, y_new - y, lagrangian_change)
        y, c, J = y_new, c_new, J_new
        if (
            alpha == 1.0
            and np.abs(p).max() <= tol
            and float(np.maximum(0.0, -c).max(initial=0.0)) <= tol
        ):
            return SolveResult(y, "optimal", iteration, c, B)
    return SolveResult(y, "iteration_limit", max_iter, c)
