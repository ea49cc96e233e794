"""The SQP solver: screening rows far from active, restarts after an infeasible
linearization, an infeasible Opt, and the naive step's rows evaluated once."""

from __future__ import annotations

import itertools
from dataclasses import replace

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import _multi_peer_problems

from nehmo_core.planning.numerics.qp import qp_step
from nehmo_core.planning.opt.problem import Constraints
from nehmo_core.planning.solvers.sqp import solve_sqp

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


@pytest.mark.parametrize(("screen", "two_contacts"), [(0.1, False), (0.1, True), (1e-9, True)])
def test_screened_sqp_returns_the_solution_of_the_whole_problem(
    model, screen, two_contacts
) -> None:
    """Rows far from active at the naive step are left out of the iterations and checked at the
    end; with a near-zero margin only the rows broken at the naive step are carried, so the
    check must bring others back. Either way the answer is that of the whole problem. (tol 1e-8:
    at 1e-9 an iteration count is at the mercy of rounding, e.g. of the vector math library.)"""
    rejoined = compared = 0
    for problem in _multi_peer_problems(model, 9, 80 if two_contacts else 40, two_contacts):
        whole = solve_sqp(problem, np.zeros(6), tol=1e-8, screen=None)
        screened = solve_sqp(problem, np.zeros(6), tol=1e-8, screen=screen)
        assert screened.status == whole.status
        if whole.status != "optimal":
            continue
        compared += 1
        np.testing.assert_allclose(screened.y, whole.y, atol=1e-6)
        assert len(screened.constraint) == problem.constraints.count
        assert screened.constraint.min() >= -1e-7
        # would the rows carried at first have sufficed? (solve only those, check the rest)
        c_naive, _ = problem.constraints.evaluate(problem.naive_step())
        rows = problem.constraints.value_count
        kept = c_naive[:rows] < screen
        alone = solve_sqp(
            replace(problem, constraints=problem.constraints.subset(kept)),
            np.zeros(6),
            tol=1e-8,
            screen=None,
        )
        c_alone, _ = problem.constraints.evaluate(alone.y)
        rejoined += bool((c_alone[:rows][~kept] < -1e-7).any())
    assert compared >= 20
    if screen < 0.01:
        assert rejoined >= 1  # the check after the reduced solve had rows to bring back


def test_an_infeasible_linearization_at_the_warm_start_is_not_taken_for_an_infeasible_opt(
    model,
) -> None:
    """From a warm start at a corner of the box (where the last tick's fail-safe leaves it) the
    linearized QP may have no feasible point while Opt has a solution. The SQP must then start
    again (from the naive step, then from y = 0) and return Opt's solution, not ``infeasible``."""
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=6)))
    rescued = 0
    # tol 1e-7 rad: at 1e-9 the damped BFGS tail of one of these problems needs 30 to 60
    # iterations, depending on the CPU's rounding of the generated kernels
    for problem in _multi_peer_problems(model, 22, 30):
        ymax = problem.y_max
        reference = solve_sqp(problem, np.zeros(6), tol=1e-7, screen=None)
        for y0 in corners * ymax:
            c, J = problem.constraints.evaluate(y0)
            first = qp_step(
                2.0 * np.eye(6), 2.0 * (problem.error0 + y0), c, J, -ymax - y0, ymax - y0
            )
            if first.flag != -1:
                continue
            result = solve_sqp(problem, y0, tol=1e-7, screen=None)
            assert result.status == reference.status == "optimal"
            assert result.iterations > 1  # the infeasible first start counts
            np.testing.assert_allclose(result.y, reference.y, atol=1e-6)
            assert result.constraint.min() >= -1e-7
            rescued += 1
    assert rescued >= 5


def test_an_infeasible_opt_is_reported_after_every_start(model) -> None:
    """No step reaches ``V ≥ ε`` when ε exceeds any value: every start's first QP is infeasible."""
    problem = _multi_peer_problems(model, 12, 1)[0]
    hopeless = replace(
        problem, constraints=replace(problem.constraints, epsilon=50.0, margins=None)
    )
    warm = np.full(6, 0.5 * problem.y_max)
    result = solve_sqp(hopeless, warm)
    assert result.status == "infeasible"
    assert result.iterations == 3  # the warm start, the naive step and y = 0, one QP each
    # a warm start equal to the naive step is not tried twice
    assert solve_sqp(hopeless, hopeless.naive_step()).iterations == 2


def test_the_naive_steps_rows_are_evaluated_once(model, monkeypatch) -> None:
    """The naive step's rows, evaluated for the safety check, serve a start from the naive step
    (the first start or a restart): an infeasible Opt costs one evaluation per distinct start."""
    problem = _multi_peer_problems(model, 12, 1)[0]
    hopeless = replace(
        problem, constraints=replace(problem.constraints, epsilon=50.0, margins=None)
    )
    calls = []
    evaluate = Constraints.evaluate
    monkeypatch.setattr(
        Constraints, "evaluate", lambda self, y: calls.append(y.copy()) or evaluate(self, y)
    )
    warm = np.full(6, 0.5 * problem.y_max)
    for start, starts in ((warm, 3), (hopeless.naive_step(), 2)):
        calls.clear()
        result = solve_sqp(hopeless, start, native=False)
        assert result.status == "infeasible"
        assert len(calls) == starts  # naive (the check), the warm start if apart, y = 0
        np.testing.assert_array_equal(calls[0], hopeless.naive_step())
