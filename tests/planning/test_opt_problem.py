"""Problem Opt and its constraints: the worst-case peer prediction, evaluating a step, the
safety check at the naive step, subsets of the rows, the constraint at the solution."""

from __future__ import annotations

import itertools
from dataclasses import replace

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import CELL, OWN, PEER, UNHURRIED, _multi_peer_problems, _near_contact

from nehmo_core.planning.baselines.naive import NaivePlanner
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.problem import worst_case_disturbance
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.sqp import solve_sqp
from nehmo_core.planning.stages.self_clearance import SelfClearanceRows

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


def test_worst_case_disturbance_is_the_box_corner_minimizer() -> None:
    rng = np.random.default_rng(0)
    corners = np.array(list(itertools.product([-0.5, 0.5], repeat=6)))
    for _ in range(50):
        grad = rng.normal(size=6)
        d = worst_case_disturbance(grad, 0.5)
        brute = corners[np.argmin(corners @ grad)]
        np.testing.assert_array_equal(d, brute)
        assert grad @ d == pytest.approx((corners @ grad).min())


def test_planner_predicts_peers_with_the_brute_force_worst_case(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    q1, q2, goal = _near_contact(model, 1, 1)[0]
    now = planner.current(q1, {PEER: q2})
    problem = planner.problem(q1 - goal, now)
    predicted = problem.constraints.groups[0][1][0]
    corners = np.array(list(itertools.product([-0.5, 0.5], repeat=6)))
    worst = corners[np.argmin(corners @ now.grads[0][6:])]
    np.testing.assert_allclose(predicted[6:], q2 + 0.1 * worst, atol=1e-12)


def test_evaluating_with_an_own_step_equals_evaluating_the_shifted_states(model) -> None:
    x = np.random.default_rng(3).uniform(-2.0, 2.0, size=(3, 12))
    step = np.linspace(-0.05, 0.05, 6)
    shifted, before = x.copy(), x.copy()
    shifted[:, :6] += step
    for rows in (x[:1], x):  # the single-state and the mapped call
        v, g = model.evaluate(0.3, rows, own_step=step)
        v_ref, g_ref = model.evaluate(0.3, shifted[: len(rows)])
        np.testing.assert_array_equal(v, v_ref)
        np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(x, before)  # the input is left alone


def test_safe_unconstrained_step_equals_the_naive_step(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    naive = NaivePlanner(CELL, OWN)
    q1 = np.array([0.0, -2.4, 1.5, -1.6, -1.5, 0.0])  # arms folded away from each other
    q2 = q1.copy()
    goal = q1 + np.array([0.3, 0.01, -0.02, 0.2, -0.6, 0.004])
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.status == "naive"
    assert result.telemetry.min_value > 0.3
    np.testing.assert_array_equal(result.velocity, naive.plan(q1, {}, goal).velocity)


@pytest.mark.parametrize("in_c", [True, False])
def test_a_nan_row_at_the_naive_step_is_not_taken_for_a_safe_one(model, in_c) -> None:
    """A row that evaluates to NaN (here a linear row with a NaN bound; a network could
    overflow) is not satisfied: the naive step is not returned, whatever the other rows say."""
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    q1 = np.array([0.0, -2.4, 1.5, -1.6, -1.5, 0.0])  # the V row far from active
    problem = planner.problem(np.full(6, -0.01), planner.current(q1, {PEER: q1.copy()}))
    assert solve_sqp(problem, np.zeros(6), native=in_c).status == "naive"
    rows = SelfClearanceRows(np.eye(6)[:1], np.array([np.nan]), np.array([0.05]), (("a", "b"),))
    poisoned = replace(problem, constraints=replace(problem.constraints, linear=rows))
    assert solve_sqp(poisoned, np.zeros(6), native=in_c).status != "naive"


def test_constraint_holds_at_the_solution_against_an_adversarial_peer(
    model: PairValueModel, value_function
) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], PlannerSettings().override({"opt.deadline": 1.0}))
    solved = 0
    for q1, q2, goal in _near_contact(model, 3, 12):
        for _ in range(5):  # the peer plays its worst case every step
            result = planner.plan(q1, {PEER: q2}, goal)
            _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
            d = worst_case_disturbance(grad[6:], 0.5)
            if not result.telemetry.fail_safe:
                solved += 1
                x_next = np.concatenate([q1 + 0.1 * result.velocity, q2 + 0.1 * d])
                assert value_function.value(0.3, x_next) >= 0.05 - 1e-6  # independent torch check
            assert np.all(np.abs(result.velocity) <= 0.5 + 1e-12)
            q1, q2 = q1 + 0.1 * result.velocity, q2 + 0.1 * d
    assert solved >= 10


def test_a_subset_of_the_constraints_is_made_once_per_choice_of_rows(model) -> None:
    """A solve's restarts ask for the same screened rows again: they get the same object (with
    what the C loop prepared on it), and its rows are those asked for."""
    cons = _multi_peer_problems(model, 12, 1)[0].constraints
    keep = np.array([True, False, True, False])
    first = cons.subset(keep)
    assert cons.subset(keep.copy()) is first
    assert cons.subset(~keep) is not first
    y = np.full(6, 0.01)
    np.testing.assert_array_equal(first.evaluate(y)[0][:2], cons.evaluate(y)[0][[0, 2]])
