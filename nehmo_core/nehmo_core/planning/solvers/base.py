"""The solvers of problem Opt behind one interface: the exact SQP (default) or IPOPT."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import PlannerSettings, SolverSettings
from nehmo_core.planning.solvers.ipopt import IpoptSolver
from nehmo_core.planning.solvers.native import loop
from nehmo_core.planning.solvers.sqp import SolveResult, solve_sqp

__all__ = ["OptSolver", "SqpSolver", "make_solver", "ready_solver"]


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

    tol: float = SolverSettings.sqp_tol
    max_iter: int = SolverSettings.sqp_max_iter
    screen: float | None = SolverSettings.sqp_screen
    native: bool = SolverSettings.sqp_native

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
    """The solver named by ``settings.solver.name``."""
    if settings.solver.name == "ipopt":
        return IpoptSolver(
            settings.solver.ipopt_tol, settings.solver.ipopt_max_iter, settings.opt.deadline
        ).solve
    return SqpSolver(
        settings.solver.sqp_tol,
        settings.solver.sqp_max_iter,
        settings.solver.sqp_screen,
        settings.solver.sqp_native,
    )


def ready_solver(
    solver: OptSolver, models: Sequence[PairValueModel], settings: PlannerSettings
) -> OptSolver:
    """``solver`` for ``models``, checked (``t_safe`` within every model's horizon) and made
    ready: the C loop built (first use in this cache) and the models loaded now, not in a tick."""
    for model in models:
        if not settings.opt.t_safe <= model.horizon + 1e-9:
            raise InvalidValueError(
                "opt.t_safe",
                f"must be <= the horizon of model {model.name!r} ({model.horizon})",
                settings.opt.t_safe,
            )
    if isinstance(solver, SqpSolver) and solver.native:
        c_loop = loop()
        if c_loop is not None:
            for model in models:
                c_loop.model(model)
    return solver
