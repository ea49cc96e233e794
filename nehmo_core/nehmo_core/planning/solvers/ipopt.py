"""IPOPT through CasADi on Opt: the authors' solver and settings, kept as the reference.

Decision ``u`` [rad/s] (as in the paper, not the step ``y``), cost ``‖q¹ + t_plan·u − q_goal‖²``,
one constraint ``V_i(t_safe, ·) ≥ ε`` per constrained peer (then the self-clearance rows, if
any), limited-memory Hessian, ``tol`` and
``max_iter`` from the settings (1e-3 and 30 by default), started at the warm start. The value
functions enter as CasADi graphs (``PairValueModel.value``). Any IPOPT status other than
success is a failure (the planner then uses the fail-safe).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import casadi as ca
import numpy as np

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.solvers.sqp import SolveResult

__all__ = ["IpoptSolver"]


class IpoptSolver:
    """Builds (and caches) one ``nlpsol`` per constraint layout; ``solve`` mirrors ``solve_sqp``."""

    def __init__(
        self, tol: float = 1e-3, max_iter: int = 30, max_wall_time: float | None = None
    ) -> None:
        self.options: dict[str, Any] = {
            "ipopt.hessian_approximation": "limited-memory",
            "ipopt.tol": tol,
            "ipopt.max_iter": max_iter,
            "ipopt.print_level": 0,
            "ipopt.sb": "yes",
            "print_time": False,
        }
        if max_wall_time is not None:
            self.options["ipopt.max_wall_time"] = max_wall_time
        self._solvers: dict[tuple[object, ...], ca.Function] = {}

    def _build(
        self,
        models: Sequence[PairValueModel],
        layout: tuple[tuple[int, int, float], ...],
        n1: int,
        t_plan: float,
        n_linear: int,
    ) -> ca.Function:
        u = ca.MX.sym("u", n1)
        e0 = ca.MX.sym("e0", n1)
        params = [e0]
        g = []
        if n_linear:  # self-clearance rows A·(t_plan·u) ≥ b; A enters as a parameter
            A = ca.MX.sym("A", n_linear, n1)
            params.append(ca.vec(A))
        for index, count, tau in layout:
            model = models[index]
            states = ca.MX.sym(f"x{index}", model.state_dim, count)
            params.append(ca.vec(states))
            step = ca.vertcat(t_plan * u, ca.DM.zeros(model.n2))
            for k in range(count):
                g.append(model.value(tau, states[:, k] + step))
        if n_linear:  # after the V rows, as in Constraints.evaluate
            g.append(ca.mtimes(A, t_plan * u))
        nlp: dict[str, Any] = {
            "x": u,
            "p": ca.vertcat(*params),
            "f": ca.sumsqr(e0 + t_plan * u),
            "g": ca.vertcat(*g),
        }
        return ca.nlpsol("opt_ipopt", "ipopt", nlp, self.options)

    def solve(
        self,
        problem: OptProblem,
        y_start: np.ndarray,
        deadline: float = np.inf,
        hessian: np.ndarray | None = None,
    ) -> SolveResult:
        """Solve from ``y_start`` (the step; IPOPT starts at ``u = y_start / t_plan``).

        ``hessian`` is accepted for the solver interface and unused (IPOPT keeps its own
        limited-memory approximation)."""
        cons = problem.constraints
        models = cons.models
        layout = tuple(
            (index, len(states), cons.horizon(g)) for g, (index, states) in enumerate(cons.groups)
        )
        n1 = len(problem.error0)
        linear = cons.linear
        n_linear = linear.count if linear is not None else 0
        key = (tuple(id(m) for m in models), layout, n1, problem.t_plan, n_linear)
        solver = self._solvers.get(key)
        if solver is None:
            solver = self._build(models, layout, n1, problem.t_plan, n_linear)
            self._solvers[key] = solver
        parts = [problem.error0]
        lower = [np.full(count, cons.margin(g)) for g, (_, count, _) in enumerate(layout)]
        if linear is not None and n_linear:
            parts.append(linear.A.T.ravel())  # column-major, as ca.vec
            lower.append(linear.b)
        parts.extend(s.ravel() for _, s in cons.groups)  # (k, n) rows: ca.vec of (n, k)
        params, lbg = np.concatenate(parts), np.concatenate(lower)
        u_max = problem.y_max / problem.t_plan
        u0 = np.clip(np.asarray(y_start) / problem.t_plan, -u_max, u_max)
        out = solver(x0=u0, p=params, lbx=-u_max, ubx=u_max, lbg=lbg, ubg=np.inf)
        stats = solver.stats()
        y = np.asarray(out["x"]).ravel() * problem.t_plan
        c = np.asarray(out["g"]).ravel() - lbg
        iterations = int(stats.get("iter_count", 0))
        if time.perf_counter() > deadline:
            return SolveResult(y, "timeout", iterations, c)
        if stats.get("success", False):
            return SolveResult(y, "optimal", iterations, c)
        status = str(stats.get("return_status", "failed"))
        if "Infeasible" in status:
            return SolveResult(y, "infeasible", iterations, c)
        if "Maximum_Iterations" in status:
            return SolveResult(y, "iteration_limit", iterations, c)
        return SolveResult(y, "failed", iterations, c)
