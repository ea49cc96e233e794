"""The planner's fail-safe when its solver fails, raises or misses the deadline: the command,
the deadband, the most critical peer, the next start, one evaluation per state."""

from __future__ import annotations

import time

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import CELL, OWN, PEER, UNHURRIED, _near_contact

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.base import SqpSolver
from nehmo_core.planning.solvers.sqp import SolveResult
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import sample_configuration

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model
#: the paper's fail-safe, every joint at full speed (NeHMO's default stills the ones with a
#: slope under a fifth of the largest: the deadband test below)
SWEEP = UNHURRIED.override({"fail_safe.deadband": 0.0})


class _Failing:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))


class _Crashing:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        raise RuntimeError("injected")


class _Slow:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        time.sleep(0.06)
        return SqpSolver()(problem, y_start, np.inf)


@pytest.mark.parametrize(
    ("solver", "status"), [(_Failing(), "failed"), (_Crashing(), "failed (RuntimeError)")]
)
def test_fail_safe_fires_on_solver_failure(model, value_function, solver, status) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], SWEEP, solver=solver)
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and result.telemetry.status == status
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(grad[:6]))
    assert result.telemetry.critical_peer == PEER


class _Recording:
    """The SQP, recording each call's start; fails the calls listed in ``fail``."""

    def __init__(self, fail: set[int]) -> None:
        self.fail, self.starts, self.naive = fail, [], []

    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        self.starts.append(y_start.copy())
        self.naive.append(problem.naive_step())
        if len(self.starts) - 1 in self.fail:
            return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))
        return SqpSolver()(problem, y_start, np.inf, hessian)


def test_a_solve_starts_at_the_last_solution_or_after_a_fail_safe_at_the_naive_step(model) -> None:
    solver = _Recording(fail={1})
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED, solver=solver)
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    results = []
    for _ in range(4):
        results.append(planner.plan(q1, {PEER: q2}, goal))
        q1 = q1 + 0.1 * results[-1].velocity
    assert [r.telemetry.fail_safe for r in results] == [False, True, False, False]
    np.testing.assert_array_equal(solver.starts[0], solver.naive[0])  # after reset()
    np.testing.assert_allclose(solver.starts[1], 0.1 * results[0].velocity, atol=1e-12)
    np.testing.assert_array_equal(solver.starts[2], solver.naive[2])  # not the fail-safe's corner
    np.testing.assert_allclose(solver.starts[3], 0.1 * results[2].velocity, atol=1e-12)


def test_fail_safe_fires_on_a_missed_deadline(model, value_function) -> None:
    planner = NehmoPlanner(
        CELL, OWN, [model], SWEEP.override({"opt.deadline": 0.04}), solver=_Slow()
    )
    q1, q2, goal = _near_contact(model, 7, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and result.telemetry.status == "timeout"
    assert result.telemetry.solve_time > 0.04
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(grad[:6]))


def test_fail_safe_deadband_stills_only_the_joints_that_barely_change_v(
    model, value_function
) -> None:
    settings = PlannerSettings().override({"fail_safe.deadband": 0.3})
    planner = NehmoPlanner(CELL, OWN, [model], settings, solver=_Failing())
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    g = grad[:6]
    dead = np.abs(g) < 0.3 * np.abs(g).max()
    assert dead.any() and not dead.all()
    np.testing.assert_array_equal(result.velocity[dead], 0.0)
    np.testing.assert_array_equal(result.velocity[~dead], 0.5 * np.sign(g[~dead]))
    # the first-order rate of V under the deadband fail-safe stays positive (it still evades)
    assert float(g @ result.velocity) > 0.0
    with pytest.raises(InvalidValueError, match=r"fail_safe\.deadband"):
        PlannerSettings().override({"fail_safe.deadband": 1.0})


def test_fail_safe_picks_the_most_critical_of_several_peers(model) -> None:
    cell = load_cell("triple_ur5")
    planner = NehmoPlanner(cell, "ur5_0", [model], SWEEP, solver=_Failing())
    rng = np.random.default_rng(8)
    robot = cell.arm("ur5_0").robot
    q = {a: sample_configuration(robot, rng) for a in cell.arm_ids}
    result = planner.plan(q["ur5_0"], {a: q[a] for a in ("ur5_1", "ur5_2")}, q["ur5_0"] + 1.0)
    values = {
        p: model.evaluate(0.1, m.state(q["ur5_0"], q[p])[None]) for p, m in planner.pairs.items()
    }
    critical = min(planner.pairs, key=lambda p: values[p][0][0])
    assert result.telemetry.critical_peer == critical
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(values[critical][1][0, :6]))


def test_the_fail_safe_and_the_solve_of_one_state_share_one_evaluation(model) -> None:
    """A node asks for the fail-safe ahead of each solve from the same state: the solve reuses
    that evaluation of V at t_plan and answers as a planner that was not asked first."""
    planner, fresh = (
        NehmoPlanner(CELL, OWN, [model], UNHURRIED),
        NehmoPlanner(CELL, OWN, [model], UNHURRIED),
    )
    q1, q2, goal = _near_contact(model, 8, 1)[0]
    evaluations = []
    evaluate = planner.opt.evaluate

    def counted(*args):  # type: ignore[no-untyped-def]
        evaluations.append(args)
        return evaluate(*args)

    planner.opt.evaluate = counted  # type: ignore[method-assign]
    planner.fail_safe(q1, {PEER: q2})
    first = planner.plan(q1, {PEER: q2}, goal)
    assert len(evaluations) == 1
    alone = fresh.plan(q1, {PEER: q2}, goal)
    np.testing.assert_array_equal(first.velocity, alone.velocity)
    assert first.telemetry.status == alone.telemetry.status
    planner.plan(q1, {PEER: q2 + 0.01}, goal)  # the peer moved: a new state
    planner.plan(q1 + 0.01, {PEER: q2 + 0.01}, goal)  # this arm moved
    assert len(evaluations) == 3
