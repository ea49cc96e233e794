"""Deadline misses of the control loop: no solve time for a miss and the late one after it, the
stale and untrusted peers kept, the fail-safe clipped, and the node's status reading back."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pytest
from _control_helpers import (
    FAIL_SAFE,
    NAMES,
    TIMEOUT,
    RecordingPlanner,
    _controller,
    _feed,
    _in_plan,
    _wait_idle,
)

from nehmo_core.planning.opt.interface import PlanResult
from nehmo_ros.control import Decision


def test_a_missed_deadline_has_no_solve_time_and_the_late_one_follows() -> None:
    """A miss reports NaN (no solve finished in time); the abandoned solve's real time comes
    with the first command after it finished."""
    planner = RecordingPlanner(delay=0.1)  # plan() reports 0.1 s
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)  # job of tick 0 starts
        _in_plan(planner)
        missed = c.tick(0.04)  # tick 0's solve is late
        assert missed.status == "deadline_missed" and missed.tick == 0
        assert math.isnan(missed.solve_time) and math.isnan(missed.late_solve_time)
        busy = c.tick(0.08)  # nothing could be submitted at tick 1: the worker was busy
        assert busy.status == "deadline_missed" and busy.tick == 2
        assert math.isnan(busy.solve_time) and math.isnan(busy.late_solve_time)
        assert math.isnan(c.telemetry(busy).solve_time)
        planner.release.set()
        _wait_idle(c)
        after = c.tick(0.12)
        assert after.late_solve_time == pytest.approx(0.1) and after.late_tick == 0
        _wait_idle(c)
        on_time = c.tick(0.16)  # the job of tick 3 finished in time
        assert on_time.status == "optimal" and on_time.solve_time == pytest.approx(0.1)
        assert math.isnan(on_time.late_solve_time) and on_time.late_tick == -1
    finally:
        c.stop()


def test_a_late_solve_time_comes_with_the_next_planned_command() -> None:
    """The abandoned job finishes between the take and the submit of a tick (the new submit
    drops its result): its solve time still comes, with the next planned command."""

    class SlowOnce(RecordingPlanner):
        def plan(
            self,
            q_self: np.ndarray,
            peers: Mapping[str, np.ndarray],
            q_goal: np.ndarray,
            peer_bounds: Mapping[str, float] | None = None,
        ) -> PlanResult:
            self.delay = 0.06 if not self.calls else 0.0
            return super().plan(q_self, peers, q_goal)

    planner = SlowOnce()
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)
        missed = c.tick(0.04)
        assert missed.status == "deadline_missed" and math.isnan(missed.solve_time)
        take = c._worker.take

        def take_then_finish() -> Decision | None:
            result = take()
            planner.release.set()
            assert c._worker.wait_idle(TIMEOUT)  # the abandoned job ends right after the take
            return result

        c._worker.take = take_then_finish  # type: ignore[method-assign]
        busy = c.tick(0.08)
        c._worker.take = take  # type: ignore[method-assign]
        assert busy.status == "deadline_missed" and math.isnan(busy.late_solve_time)
        _wait_idle(c)
        planned = c.tick(0.12)
        assert planned.status == "optimal" and planned.tick == 2
        assert planned.late_solve_time == pytest.approx(0.06) and planned.late_tick == 0
    finally:
        c.stop()


class SlowFailSafe(RecordingPlanner):
    """A fail-safe held until the test releases it: a tick with a stale peer (policy
    fail_safe) misses."""

    def fail_safe(
        self,
        q_self: np.ndarray,
        peers: Mapping[str, np.ndarray],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        self.entered.set()
        assert self.release.wait(TIMEOUT), "the test never released the fail-safe"
        return FAIL_SAFE.copy()


def test_a_missed_deadline_keeps_the_stale_and_untrusted_peers() -> None:
    planner = SlowFailSafe()
    c = _controller(planner, stale_policy="fail_safe")
    try:
        c.states.update("ur5_1", NAMES, [0.0] * 6, 0.0)  # the peer's last message
        c.states.update("ur5_0", NAMES, [1.0] + [0.0] * 5, 1.0)
        c.tick(1.0)  # observation of tick 0: the peer is stale; its fail-safe is slow
        assert planner.entered.wait(TIMEOUT)
        c.states.update("ur5_1", NAMES, [math.nan] * 6, 1.02)  # rejected: now untrusted too
        c.states.update("ur5_0", NAMES, [1.0] + [0.0] * 5, 1.04)
        missed = c.tick(1.04)  # the solve of tick 0 is late
        assert missed.status == "deadline_missed" and missed.tick == 0
        assert missed.stale == ("ur5_1",) and missed.missing == () and missed.untrusted == ()
        busy = c.tick(1.08)  # nothing could be submitted: the observation of this tick
        assert busy.status == "deadline_missed" and busy.tick == 2
        assert busy.stale == ("ur5_1",) and busy.untrusted == ("ur5_1",)
    finally:
        c.stop()


class BadFailSafe(RecordingPlanner):
    """plan() is slow (every tick misses); the fail-safe returns ``value`` on every joint."""

    def __init__(self, value: float) -> None:
        super().__init__(delay=0.1)
        self.value = value

    def fail_safe(
        self,
        q_self: np.ndarray,
        peers: Mapping[str, np.ndarray],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        return np.full(6, self.value)


@pytest.mark.parametrize(
    ("value", "expected", "hold"),
    [(2.0, 0.5, False), (-3.0, -0.5, False), (math.nan, 0.0, True), (math.inf, 0.0, True)],
    ids=["fast", "fast_negative", "nan", "inf"],
)
def test_the_fail_safe_of_a_missed_deadline_is_clipped_and_finite(
    value: float, expected: float, hold: bool
) -> None:
    planner = BadFailSafe(value)
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)  # the fail-safe is stored; plan() runs
        d = c.tick(0.04)
        assert d.status == "deadline_missed" and d.hold == hold
        np.testing.assert_array_equal(d.velocity, np.full(6, expected))
    finally:
        c.stop()


def test_the_status_of_a_missed_deadline_reads_back_with_its_solve_times() -> None:
    """The node's status: NaN solve time for the miss, the late one in a key of its own, and
    the log schema's decoder still reads both."""
    from nehmo_core.eval.telemetry import telemetry_from_status
    from nehmo_core.logs.messages import DiagnosticStatus, deserialize, serialize
    from nehmo_ros.arm_planner import ArmPlannerNode

    planner = RecordingPlanner(delay=0.1)
    c = _controller(planner)
    node = ArmPlannerNode.__new__(ArmPlannerNode)
    node.arm_id, node.kind, node.controller, node.fault = "ur5_0", "nehmo", c, ""
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        _in_plan(planner)
        missed = c.tick(0.04)
        planner.release.set()
        _wait_idle(c)
        after = c.tick(0.08)
        statuses = []
        for d in (missed, after):
            data = serialize(node._status(d, 0.04, 0))
            msg = deserialize(data, "diagnostic_msgs/msg/DiagnosticStatus")
            assert isinstance(msg, DiagnosticStatus)
            statuses.append((telemetry_from_status(msg), {v.key: v.value for v in msg.values}))
        (record, values), (_, later) = statuses
        assert record.telemetry.status == "deadline_missed"
        assert math.isnan(record.telemetry.solve_time) and values["solve_time"] == "nan"
        assert values["late_solve_time"] == "nan" and values["late_solve_tick"] == "-1"
        assert float(later["late_solve_time"]) == pytest.approx(0.1)
        assert later["late_solve_tick"] == "0"
    finally:
        c.stop()


def test_the_planner_is_told_which_command_runs_while_it_plans() -> None:
    """The command sent at a tick is the one in flight for that tick's solve: the planner's
    own last result when on time, the fail-safe after a missed deadline."""

    class Told(RecordingPlanner):
        def __init__(self, delay: float = 0.0) -> None:
            super().__init__(delay)
            self.told: list[np.ndarray] = []

        def commanded(self, u: np.ndarray) -> None:
            self.told.append(np.array(u))

    planner = Told(delay=0.1)
    c = _controller(planner)
    try:
        _feed(c, 0.0, 1.0)
        first = c.tick(0.0)  # nothing planned yet: zero, and tick 0's solve starts
        _in_plan(planner)
        missed = c.tick(0.04)  # tick 0's solve is late: the fail-safe is sent
        assert missed.status == "deadline_missed"
        planner.release.set()
        _wait_idle(c)
        planner.delay = 0.0
        _feed(c, 0.08, 2.0)
        sent = c.tick(0.08)  # tick 2's solve runs while this command does
        _wait_idle(c)
        on_time = c.tick(0.12)
        _wait_idle(c)
    finally:
        c.stop()
    np.testing.assert_array_equal(planner.told[0], first.velocity)
    np.testing.assert_array_equal(planner.told[1], sent.velocity)
    np.testing.assert_array_equal(sent.velocity, FAIL_SAFE)  # the late solve is dropped
    np.testing.assert_array_equal(planner.told[2], on_time.velocity)
    assert on_time.status == "optimal"


def test_a_plan_from_observations_over_one_and_a_half_periods_old_is_not_sent() -> None:
    """A process that ran late (its tick 200 ms after the previous one, as under a loaded
    machine) holds still instead of sending the plan of the old observations (``late_plan``,
    counted); on time again, the plan of the previous tick is sent."""
    planner = RecordingPlanner()
    c = _controller(planner)
    period_ns = 40_000_000
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0, 0)
        _wait_idle(c)
        _feed(c, 0.04, 2.0)
        on_time = c.tick(0.04, period_ns)  # planned from tick 0: one period old
        assert on_time.status == "optimal" and not on_time.hold
        np.testing.assert_allclose(on_time.velocity, 0.01)
        _wait_idle(c)
        _feed(c, 0.24, 3.0)
        late = c.tick(0.24, 6 * period_ns)  # planned from tick 1, five periods ago
        assert late.status == "late_plan" and late.hold
        np.testing.assert_array_equal(late.velocity, np.zeros(6))
        assert c.counters.late_plans == 1 and c.counters.holds >= 1
        _wait_idle(c)
        _feed(c, 0.28, 4.0)
        again = c.tick(0.28, 7 * period_ns)  # planned from the late tick: one period old
        assert again.status == "optimal"
        np.testing.assert_allclose(again.velocity, 0.03)
    finally:
        c.stop()


def test_a_late_fail_safe_carries_the_stamp_of_the_observations_it_came_from() -> None:
    """A missed deadline commands the fail-safe of the job's observations, stamped with them: it
    is sent one period on, and held back (``late_plan``) when the tick comes too late for it."""
    planner = RecordingPlanner(delay=0.1)
    c = _controller(planner)
    period_ns = 40_000_000
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0, 0)
        _in_plan(planner)
        missed = c.tick(0.04, period_ns)
        assert missed.status == "deadline_missed" and missed.observation_ns == 0
        np.testing.assert_array_equal(missed.velocity, FAIL_SAFE)
        late = c.tick(0.2, 5 * period_ns)  # the same fail-safe, now five periods old
        assert late.status == "late_plan" and late.hold
        np.testing.assert_array_equal(late.velocity, np.zeros(6))
    finally:
        c.stop()


def test_plan_age_can_be_turned_off_and_must_exceed_one_period() -> None:
    from nehmo_core.errors import InvalidValueError
    from nehmo_ros.control import ControlSettings

    planner = RecordingPlanner()
    c = _controller(planner, plan_age=math.inf)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0, 0)
        _wait_idle(c)
        _feed(c, 0.24, 2.0)
        late = c.tick(0.24, 240_000_000)  # six periods on: sent all the same
        assert late.status == "optimal" and c.counters.late_plans == 0
        np.testing.assert_allclose(late.velocity, 0.01)
    finally:
        c.stop()
    with pytest.raises(InvalidValueError, match=r"`plan_age` must be > 1 period"):
        ControlSettings(plan_age=1.0)
