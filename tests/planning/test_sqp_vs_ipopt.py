"""The SQP against IPOPT as the slow obvious reference: the same solutions, with one peer
and with several, at tight and at the default tolerances."""

from __future__ import annotations

import _opt_helpers
import numpy as np
from _opt_helpers import CELL, OWN, PEER, UNHURRIED, _multi_peer_problems, _near_contact

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.ipopt import IpoptSolver
from nehmo_core.planning.solvers.sqp import solve_sqp

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


def test_sqp_returns_the_ipopt_solution(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    reference = IpoptSolver(tol=1e-10, max_iter=300)
    compared = 0
    for q1, q2, goal in _near_contact(model, 4, 40):
        problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
        fast = solve_sqp(problem, np.zeros(6), tol=1e-9)
        if fast.status != "optimal":
            continue
        ref = reference.solve(problem, np.zeros(6))
        assert ref.status == "optimal"
        np.testing.assert_allclose(fast.y, ref.y, atol=2e-6)  # step [rad]; ū·t_plan = 0.05
        # IPOPT ends ~1e-8 inside the infeasible side of its bound; the costs agree to that.
        assert abs(problem.cost(fast.y) - problem.cost(ref.y)) <= 1e-6 * (1.0 + problem.cost(ref.y))
        assert fast.constraint.min() >= -1e-9
        # the default tolerance (1e-4 rad on the last step) lands within it of the solution
        default = solve_sqp(problem, np.zeros(6), tol=PlannerSettings().solver.sqp_tol)
        assert default.status == "optimal"
        np.testing.assert_allclose(default.y, fast.y, atol=PlannerSettings().solver.sqp_tol)
        assert default.constraint.min() >= -1e-7
        compared += 1
    assert compared >= 5


def test_ipopt_solves_the_multi_peer_problem_the_sqp_solves(model) -> None:
    """Several peers under one model enter IPOPT as one parameter block; its constraint values
    must be those of :meth:`Constraints.evaluate` at its answer, and its answer the SQP's."""
    reference = IpoptSolver(tol=1e-10, max_iter=300)
    compared = 0
    for problem in _multi_peer_problems(model, 13, 8, two_contacts=True):
        assert problem.constraints.groups[0][1].shape[0] == 4  # four peers, one model
        ref = reference.solve(problem, np.zeros(6))
        c, _ = problem.constraints.evaluate(ref.y)
        np.testing.assert_allclose(ref.constraint, c, atol=1e-9)
        fast = solve_sqp(problem, np.zeros(6), tol=1e-9, screen=None)
        if fast.status == "optimal" and ref.status == "optimal":
            np.testing.assert_allclose(fast.y, ref.y, atol=2e-6)
            compared += 1
    assert compared >= 4


def test_default_ipopt_settings_agree_with_sqp_within_their_tolerance(model) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    paper = IpoptSolver()  # tol 1e-3, max_iter 30, limited-memory Hessian
    compared = 0
    for q1, q2, goal in _near_contact(model, 5, 10):
        problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
        fast = solve_sqp(problem, np.zeros(6))
        ref = paper.solve(problem, np.zeros(6))
        if fast.status == "optimal" and ref.status == "optimal":
            compared += 1
            assert abs(problem.cost(fast.y) - problem.cost(ref.y)) <= 1e-2 * problem.cost(ref.y)
    assert compared >= 8  # both optimal on all 10 now: the check compares, not skips
