"""The solvers of problem Opt behind one interface: the exact SQP (default) or IPOPT."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.planning.solvers.ipopt import IpoptSolver
from nehmo_core.planning.solvers.sqp import SolveResult, solve_sqp

__all__ = ["OptSolver", "SqpSolver", "make_solver"]


class OptSolver(Protocol):
    """Solves one Opt problem from a warm start before ``deadline`` (a perf_counter instant)."""

    def __call__(
        self,
        problem: OptProblem,
        y_start: np.ndarray,
        deadline: float,
        hessian: np.ndarray | None = None,
    ) -> SolveResult: ...


@dataclass(frozen=True)
class SqpSolver:
    """:func:`solve_sqp` with fixed tolerance, iteration limit, screening margin and loop
    (by default those of :class:`PlannerSettings`)."""

    tol: float = PlannerSettings.sqp_tol
    max_iter: int = PlannerSettings.sqp_max_iter
    screen: float | None = PlannerSettings.sqp_screen
    native: bool = PlannerSettings.sqp_native

    def __call__(
        self,
        problem: OptProblem,
        y_start: np.ndarray,
        deadline: float,
        hessian: np.ndarray | None = None,
    ) -> SolveResult:
        return solve_sqp(
            problem,
            y_start,
            self.tol,
            self.max_iter,
            deadline,
            hessian,
            screen=self.screen,
            native=self.native,
        )


def make_solver(settings: PlannerSettings) -> OptSolver:
    """The solver named by ``settings.solver``."""
    if settings.solver == "ipopt":
        return IpoptSolver(settings.ipopt_tol, settings.ipopt_max_iter, settings.deadline).solve
    return SqpSolver(
        settings.sqp_tol, settings.sqp_max_iter, settings.sqp_screen, settings.sqp_native
    )
