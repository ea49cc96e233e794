"""The stall escape: moving along the level set when Opt stops short of the goal, the escape's
length, yielding at the goal, a new goal, fail-safe ticks during an escape, the paper preset."""

from __future__ import annotations

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import CELL, OWN, PEER, _near_contact

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.base import SqpSolver
from nehmo_core.planning.solvers.sqp import SolveResult
from nehmo_core.sim.scenarios import sample_configuration

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


def _stalled_case(model: PairValueModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A state whose goal lies straight through the peer's level set: Opt stops at it."""
    q1, q2, _ = _near_contact(model, 5, 1)[0]
    _, g = model.evaluate(0.1, np.concatenate([q1, q2])[None])
    return q1, q2, q1 - 1.5 * g[0, :6] / np.abs(g[0, :6]).max()


def _closed_loop(planner: NehmoPlanner, q1, q2, goal, ticks: int) -> list:
    """The own arm integrates its commands over 0.04 s ticks; the peer stands still."""
    out = []
    for _ in range(ticks):
        result = planner.plan(q1, {PEER: q2}, goal)
        out.append((q1.copy(), result))
        q1 = q1 + 0.04 * result.velocity
    return out


def test_stall_escape_moves_along_the_level_set_and_keeps_the_constraint(model) -> None:
    q1, q2, goal = _stalled_case(model)
    settings = PlannerSettings().override(
        {"opt.deadline": 1.0, "escape.stall_ticks": 5, "escape.escape_ticks": 10}
    )
    stuck = _closed_loop(
        NehmoPlanner(CELL, OWN, [model], settings.override({"escape.enabled": False})),
        q1,
        q2,
        goal,
        60,
    )
    tail = np.array([q for q, _ in stuck[-20:]])
    assert np.abs(tail - tail[-1]).max() < 1e-3  # without the escape the arm stops for good
    assert np.linalg.norm(tail[-1] - goal) > 0.1
    assert not any(r.telemetry.escaping for _, r in stuck)
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    run = _closed_loop(planner, q1, q2, goal, 60)
    escaping = [i for i, (_, r) in enumerate(run) if r.telemetry.escaping]
    assert escaping, "the stall was not detected"
    first = escaping[0]
    assert escaping[:10] == list(range(first, first + 10))  # one escape lasts escape_ticks
    moved = np.linalg.norm(run[first + 9][0] - run[first][0])
    assert moved > 0.05  # [rad]: it left the stall point
    for _, r in run:
        if not r.telemetry.fail_safe:
            assert r.telemetry.min_constraint >= -1e-6  # every step, escaping or not, is safe
    # deterministic, and reset() clears the escape state
    planner.reset()
    again = _closed_loop(planner, q1, q2, goal, 60)
    np.testing.assert_array_equal(
        np.array([r.velocity for _, r in again]), np.array([r.velocity for _, r in run])
    )


def test_escape_length_doubles_until_the_goal_error_reaches_a_new_low(model) -> None:
    settings = PlannerSettings().override(
        {"escape.stall_ticks": 3, "escape.escape_ticks": 4, "escape.stall_progress": 0.1}
    )
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    assert settings.opt.t_plan * settings.opt.u_max == pytest.approx(
        0.05
    )  # progress: > 0.005 rad/call

    def feed(errors: list[float]) -> list[int]:
        left = []
        for e in errors:
            planner.stage("escape").track(np.array([e, 0, 0, 0, 0, 0]), pressed=True)
            left.append(planner.stage("escape").escape_left)
        return left

    feed([1.0, 0.9])  # progress toward a new low
    assert feed([0.9, 0.9, 0.9]) == [0, 0, 4]  # stalled for stall_ticks calls: escape 4 calls
    assert feed([1.0, 1.1, 1.2, 1.2]) == [3, 2, 1, 0]
    # back to the trap, making progress on the way but never below the best error (0.9)
    assert feed([1.1, 1.0, 0.9, 0.9, 0.9, 0.9]) == [0, 0, 0, 0, 0, 8]  # same trap: 2× longer
    feed([1.2] * 8)
    assert feed([1.1, 1.0, 0.9, 0.9, 0.9, 0.9]) == [0, 0, 0, 0, 0, 16]  # 4×, the cap
    feed([1.2] * 16)
    feed([1.0, 0.8, 0.7])  # a new low: the next trap starts over
    assert feed([0.7, 0.7, 0.7]) == [0, 0, 4]


def test_an_arm_held_at_its_goal_against_a_peer_yields_then_returns(model) -> None:
    rng = np.random.default_rng(7)
    robot = CELL.arm(OWN).robot
    settings = PlannerSettings().override(
        {"opt.deadline": 1.0, "escape.stall_ticks": 5, "escape.yield_ticks": 8}
    )
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    while True:  # the own arm at its goal, the peer pressing it (V row within stall_margin)
        q1, q2 = sample_configuration(robot, rng), sample_configuration(robot, rng)
        problem = planner.problem(np.zeros(6), planner.current(q1, {PEER: q2}))
        c_still, _ = problem.constraints.evaluate(np.zeros(6))
        if 0.0 <= c_still[0] < 0.005:
            break
    run = _closed_loop(planner, q1, q2, q1.copy(), 40)
    flags = [r.telemetry.escaping for _, r in run]
    assert not any(flags[:5]) and flags[5:13] == [True] * 8  # yields after stall_ticks
    v = [model.evaluate(0.1, np.concatenate([q, q2])[None])[0][0] for q, _ in run]
    assert v[13] > v[5] + 0.005  # it made room: V against the peer grew while yielding
    assert np.linalg.norm(run[-1][0] - q1) < np.linalg.norm(run[13][0] - q1)  # and went back


def test_paper_preset_and_kind_have_no_escape(model) -> None:
    assert PlannerSettings().escape.enabled
    assert not PlannerSettings.preset("paper").escape.enabled
    from nehmo_core.planning.factory import make_planner

    planner = make_planner("nehmo_paper", CELL, OWN, [model])
    assert isinstance(planner, NehmoPlanner) and not planner.settings.escape.enabled


class _Switchable:
    """The SQP solver until ``fail`` is set, then a failing one."""

    def __init__(self) -> None:
        self.fail = False

    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        if self.fail:
            return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))
        return SqpSolver()(problem, y_start, np.inf, hessian)


def _into_an_escape(planner: NehmoPlanner, q1, q2, goal) -> np.ndarray:
    """Run the closed loop until the first escaping tick; the own state after that tick."""
    for _ in range(60):
        result = planner.plan(q1, {PEER: q2}, goal)
        q1 = q1 + 0.04 * result.velocity
        if result.telemetry.escaping:
            assert planner.stage("escape").escape_left > 0  # the escape goes on for more calls
            return q1
    raise AssertionError("the stall was not detected")


def test_a_new_goal_ends_an_escape_and_is_followed_at_once(model) -> None:
    q1, q2, goal = _stalled_case(model)
    settings = PlannerSettings().override(
        {"opt.deadline": 1.0, "escape.stall_ticks": 5, "escape.escape_ticks": 10}
    )
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    # the same goal (equal values, another object) keeps a running escape going
    q = _into_an_escape(planner, q1, q2, goal)
    assert planner.plan(q, {PEER: q2}, goal.tolist()).telemetry.escaping
    planner.reset()
    q = _into_an_escape(planner, q1, q2, goal)
    # a goal up V's gradient (away from the peer): the unconstrained step toward it is safe
    _, g = model.evaluate(0.1, np.concatenate([q, q2])[None])
    new_goal = q + 0.3 * np.sign(g[0, :6])
    result = planner.plan(q, {PEER: q2}, new_goal)
    assert not result.telemetry.escaping and not result.telemetry.fail_safe
    toward = new_goal - q
    cosine = result.velocity @ toward / np.linalg.norm(result.velocity) / np.linalg.norm(toward)
    assert cosine > 0.9
    # the stall and escape state restarted from the new goal
    escape = planner.stage("escape")
    assert escape.escape_left == 0 and escape.stall == 0 and escape.escapes == 0  # type: ignore[attr-defined]
    assert escape.best_error == pytest.approx(np.linalg.norm(q - new_goal))  # type: ignore[attr-defined]


def test_fail_safe_ticks_during_an_escape_are_not_reported_as_escaping(model) -> None:
    q1, q2, goal = _stalled_case(model)
    solver = _Switchable()
    settings = PlannerSettings().override(
        {"opt.deadline": 1.0, "escape.stall_ticks": 5, "escape.escape_ticks": 10}
    )
    planner = NehmoPlanner(CELL, OWN, [model], settings, solver=solver)
    q = _into_an_escape(planner, q1, q2, goal)
    solver.fail = True
    result = planner.plan(q, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and not result.telemetry.escaping
    assert (
        planner.stage("escape").escape_left > 0
    )  # the escape itself goes on after the fail-safe tick
