"""The arm_planner's control loop without a middleware: which observation a command comes
from, the worker beside the tick, missed deadlines, a hung or raising solver, holding still."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pytest
from _control_helpers import (
    CELL,
    FAIL_SAFE,
    NAMES,
    SETTINGS,
    RecordingPlanner,
    _controller,
    _feed,
    _in_plan,
    _wait_idle,
)

from nehmo_core.planning.opt.interface import PlanResult, Telemetry
from nehmo_ros.control import ArmController, Decision


def test_command_of_tick_k_comes_from_the_observation_of_tick_k_minus_1() -> None:
    c = _controller(RecordingPlanner())
    try:
        commands = []
        for k in range(5):
            now = k * 0.04
            _feed(c, now, q0=float(k))
            commands.append(c.tick(now, stamp_ns=k * 40_000_000))
            _wait_idle(c)
        assert commands[0].status == "starting" and commands[0].hold
        for k in range(1, 5):
            assert commands[k].status == "optimal"
            assert commands[k].tick == k - 1
            assert commands[k].observation_ns == (k - 1) * 40_000_000
            assert commands[k].velocity[0] == pytest.approx((k - 1) * 0.01)
    finally:
        c.stop()


def test_the_command_is_sent_before_the_solve_of_its_tick_starts() -> None:
    """``send`` gets each tick's decision while no solve runs: the node publishes its command
    without sharing the interpreter with the solve thread. (The planner blocks until the test
    releases it, so a solve started before ``send`` would still be running there.)"""
    planner = RecordingPlanner(delay=0.001)
    c = _controller(planner)
    try:
        seen: list[tuple[int, bool, int]] = []  # (command's tick, worker busy, plan() calls)

        def send(decision: Decision) -> None:
            seen.append((decision.tick, c._worker.busy, len(planner.calls)))

        for k in range(4):
            _feed(c, k * 0.04, q0=float(k))
            decision = c.tick(k * 0.04, stamp_ns=k * 40_000_000, send=send)
            assert seen[-1][0] == decision.tick
            _in_plan(planner)  # the tick's solve did start, after send
            planner.entered.clear()
            planner.release.set()
            _wait_idle(c)
            planner.release.clear()
        assert [(busy, calls) for _, busy, calls in seen] == [(False, k) for k in range(4)]
        c.pause()
        held = c.tick(0.16, send=send)
        assert held.status == "paused" and seen[-1][0] == held.tick
    finally:
        c.stop()


def test_a_tick_may_leave_its_solve_for_later_and_the_command_is_the_same() -> None:
    """``tick(solve=False)`` starts nothing; ``start_solve`` then solves that tick's
    observation (once, however often it is called), and the next command comes from it as if
    the solve had started inside ``tick`` (the node ticks its arms of one process this way)."""
    planner = RecordingPlanner()
    c = _controller(planner)
    try:
        for k in range(3):
            _feed(c, k * 0.04, q0=float(k))
            decision = c.tick(k * 0.04, stamp_ns=k * 40_000_000, solve=False)
            _wait_idle(c)
            assert len(planner.calls) == k  # nothing started yet
            c.start_solve()
            c.start_solve()  # a second call has nothing left to start
            _wait_idle(c)
            assert len(planner.calls) == k + 1
            if k:
                assert decision.status == "optimal" and decision.tick == k - 1
                assert decision.velocity[0] == pytest.approx((k - 1) * 0.01)
        c.pause()
        c.tick(0.12, solve=False)
        c.start_solve()  # a paused tick leaves nothing to solve
        _wait_idle(c)
        assert len(planner.calls) == 3
    finally:
        c.stop()


def test_a_command_carries_the_state_ages_of_its_own_observation() -> None:
    """The status reports the state ages the command was computed from (the previous tick's
    observation), not those seen at the tick that publishes it."""
    c = _controller(RecordingPlanner())
    try:
        _feed(c, 0.0, 0.0)
        c.tick(0.01)  # observation of tick 0: states 10 ms old
        _wait_idle(c)
        c.states.update("ur5_0", NAMES, [0.0] * 6, 0.04)  # the peer's state is not renewed
        command = c.tick(0.05)
        assert command.status == "optimal" and command.tick == 0
        assert command.ages == pytest.approx({"ur5_0": 0.01, "ur5_1": 0.01})
        assert c.last_observation is not None
        assert c.last_observation.ages == pytest.approx({"ur5_0": 0.01, "ur5_1": 0.05})
    finally:
        c.stop()


def test_missed_deadline_publishes_the_fail_safe_of_the_previous_observation() -> None:
    planner = RecordingPlanner(delay=0.1)
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)
        late = c.tick(0.04)
        assert late.status == "deadline_missed" and late.fail_safe
        np.testing.assert_array_equal(late.velocity, FAIL_SAFE)
        assert c.counters.deadline_misses == 1
    finally:
        c.stop()


def test_a_hung_solver_ends_in_holding_still() -> None:
    planner = RecordingPlanner(delay=1.0)
    c = _controller(planner, peer_timeout=0.1)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)
        decisions = [c.tick(0.04 * k) for k in range(1, 6)]
        assert all(d.status == "deadline_missed" for d in decisions)
        assert not decisions[0].hold  # the fail-safe first ...
        assert decisions[-1].hold and not np.any(decisions[-1].velocity)  # ... then hold
    finally:
        c.stop()


def test_solver_exception_yields_the_fail_safe_and_is_reported() -> None:
    c = _controller(RecordingPlanner(error=RuntimeError("boom")))
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _wait_idle(c)
        d = c.tick(0.04)
        assert d.status == "failed" and d.fail_safe and "boom" in d.error
        np.testing.assert_array_equal(d.velocity, FAIL_SAFE)
    finally:
        c.stop()


def test_missing_own_state_or_goal_holds_still() -> None:
    c = ArmController(CELL, "ur5_0", RecordingPlanner(), SETTINGS)  # type: ignore[arg-type]
    try:
        c.states.update("ur5_1", NAMES, [0.0] * 6, 0.0)
        c.tick(0.0)
        _wait_idle(c)
        assert c.tick(0.04).status == "no_own_state"
        _wait_idle(c)
        _feed(c, 0.08, 1.0)
        c.tick(0.08)
        _wait_idle(c)
        d = c.tick(0.12)
        assert d.status == "no_goal" and d.hold and not np.any(d.velocity)
    finally:
        c.stop()


def test_worker_never_blocks_the_tick() -> None:
    planner = RecordingPlanner(delay=0.2)
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)
        d = c.tick(0.04)  # returns while the solve is still held inside plan()
        assert d.status == "deadline_missed" and not planner.release.is_set()
        assert len(planner.calls) == 1
    finally:
        c.stop()


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan], ids=["inf", "-inf", "nan"])
def test_a_non_finite_planned_command_holds(value: float) -> None:
    class NonFinite(RecordingPlanner):
        def plan(
            self,
            q_self: np.ndarray,
            peers: Mapping[str, np.ndarray],
            q_goal: np.ndarray,
            peer_bounds: Mapping[str, float] | None = None,
        ) -> PlanResult:
            return PlanResult(np.full(6, value), Telemetry(0.0, "optimal"))

    c = _controller(NonFinite())
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _wait_idle(c)
        d = c.tick(0.04)
        assert d.status == "non_finite_command" and d.hold
        np.testing.assert_array_equal(d.velocity, np.zeros(6))
    finally:
        c.stop()


def test_pause_holds_without_planning_and_resume_plans_from_a_fresh_state() -> None:
    """Paused: zero commands and no plan() call; the result of a solve started before the
    pause is never commanded. After resume: one zero command whose tick starts a solve of the
    state seen then, and the next command is that solve's."""
    planner = RecordingPlanner()
    c = _controller(planner)
    try:
        t = [k * 0.04 for k in range(12)]
        _feed(c, t[0], 1.0)
        c.tick(t[0])  # starts the solve of q0 = 1
        _wait_idle(c)
        c.pause()
        held = []
        for k in range(1, 5):
            _feed(c, t[k], 2.0)
            held.append(c.tick(t[k]))
        assert [d.status for d in held] == ["paused"] * 4
        assert all(d.hold and not d.velocity.any() for d in held)
        assert len(planner.calls) == 1  # only the solve from before the pause
        c.resume()
        _feed(c, t[5], 3.0)  # the state after the resume
        first = c.tick(t[5])
        _wait_idle(c)
        assert first.status == "resuming" and not first.velocity.any()
        _feed(c, t[6], 3.0)
        second = c.tick(t[6])
        assert second.status == "optimal" and second.tick == first.tick
        assert second.velocity[0] == pytest.approx(0.03)  # planned from q0 = 3, not 1 or 2
        assert [round(float(q[0])) for q in planner.calls] == [1, 3]
    finally:
        c.stop()
