"""The arm_planner's control loop without a middleware: timing, fail-safes, bad peer input."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Mapping

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.interface import PlanResult, Telemetry
from nehmo_core.robots import load_cell
from nehmo_ros.control import ArmController, ControlSettings

CELL = load_cell("dual_ur5")
NAMES = list(CELL.arm("ur5_0").robot.joint_names)
SETTINGS = ControlSettings(rate=25.0, deadline=0.03, peer_timeout=0.25)
FAIL_SAFE = np.full(6, 0.5)


class RecordingPlanner:
    """Commands the own first joint value, so a command tells which observation it came from."""

    arm_id = "ur5_0"

    def __init__(self, delay: float = 0.0, error: Exception | None = None) -> None:
        self.delay = delay
        self.error = error
        self.calls: list[np.ndarray] = []

    def plan(
        self, q_self: np.ndarray, peers: Mapping[str, np.ndarray], q_goal: np.ndarray
    ) -> PlanResult:
        self.calls.append(np.array(q_self))
        if self.delay:
            time.sleep(self.delay)
        if self.error is not None:
            raise self.error
        return PlanResult(np.full(6, q_self[0] * 0.01), Telemetry(self.delay, "optimal"))

    def fail_safe(self, q_self: np.ndarray, peers: Mapping[str, np.ndarray]) -> np.ndarray:
        return FAIL_SAFE.copy()

    def reset(self) -> None:
        pass


def _controller(planner: RecordingPlanner, **changes: object) -> ArmController:
    settings = ControlSettings(**{**SETTINGS.__dict__, **changes})  # type: ignore[arg-type]
    c = ArmController(CELL, "ur5_0", planner, settings)  # type: ignore[arg-type]
    c.set_goal(NAMES, [0.1] * 6)
    return c


def _feed(c: ArmController, now: float, q0: float, peer: bool = True) -> None:
    c.states.update("ur5_0", NAMES, [q0, 0, 0, 0, 0, 0], now)
    if peer:
        c.states.update("ur5_1", NAMES, [0.0] * 6, now)


def _wait_idle(c: ArmController, timeout: float = 2.0) -> None:
    end = time.monotonic() + timeout
    while c._worker.busy and time.monotonic() < end:
        time.sleep(0.001)


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


def test_missed_deadline_publishes_the_fail_safe_of_the_previous_observation() -> None:
    c = _controller(RecordingPlanner(delay=0.1))
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        time.sleep(0.01)  # the worker has computed the fail-safe and is inside plan()
        late = c.tick(0.04)
        assert late.status == "deadline_missed" and late.fail_safe
        np.testing.assert_array_equal(late.velocity, FAIL_SAFE)
        assert c.counters.deadline_misses == 1
    finally:
        c.stop()


def test_a_hung_solver_ends_in_holding_still() -> None:
    c = _controller(RecordingPlanner(delay=1.0), peer_timeout=0.1)
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        time.sleep(0.01)
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


@pytest.mark.parametrize(
    ("policy", "expected"), [("fail_safe", FAIL_SAFE), ("hold", np.zeros(6))], ids=["fs", "hold"]
)
def test_stale_peer_is_handled_conservatively(policy: str, expected: np.ndarray) -> None:
    planner = RecordingPlanner()
    c = _controller(planner, stale_policy=policy)
    try:
        c.states.update("ur5_1", NAMES, [0.0] * 6, 0.0)  # the peer's last message
        c.states.update("ur5_0", NAMES, [1.0] + [0.0] * 5, 1.0)
        c.tick(1.0)
        _wait_idle(c)
        c.states.update("ur5_0", NAMES, [1.0] + [0.0] * 5, 1.04)
        d = c.tick(1.04)
        assert d.status == "stale_peer" and d.stale == ("ur5_1",)
        np.testing.assert_array_equal(d.velocity, expected)
        assert not planner.calls  # the planner never planned against a stale peer
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


@pytest.mark.parametrize(
    ("names", "position", "rule"),
    [
        (NAMES, [0.0, math.nan, 0, 0, 0, 0], "finite"),
        (NAMES, [0.0] * 5, "joints"),
        ([], [0.0] * 7, "6 joint values"),
        ([*NAMES[:5], "elbow"], [0.0] * 6, "joints"),
    ],
    ids=["nan", "short", "long_unnamed", "unknown_name"],
)
def test_bad_joint_states_are_rejected_and_counted(
    names: list[str], position: list[float], rule: str
) -> None:
    c = ArmController(CELL, "ur5_0", RecordingPlanner(), SETTINGS)  # type: ignore[arg-type]
    try:
        c.states.update("ur5_1", NAMES, [0.2] * 6, 0.0)
        reason = c.states.update("ur5_1", names, position, 0.01)
        assert reason is not None and rule in reason
        assert c.states.rejected["ur5_1"] == 1
        got = c.states.get("ur5_1")
        assert got is not None and got[1] == 0.0  # the previous state stays, and ages
    finally:
        c.stop()


def test_joint_states_are_reordered_by_name() -> None:
    c = ArmController(CELL, "ur5_0", RecordingPlanner(), SETTINGS)  # type: ignore[arg-type]
    try:
        c.states.update("ur5_1", list(reversed(NAMES)), [6.0, 5, 4, 3, 2, 1], 0.0)
        got = c.states.get("ur5_1")
        assert got is not None
        np.testing.assert_array_equal(got[0], [1, 2, 3, 4, 5, 6])
    finally:
        c.stop()


def test_goal_outside_joint_limits_is_rejected() -> None:
    c = ArmController(CELL, "ur5_0", RecordingPlanner(), SETTINGS)  # type: ignore[arg-type]
    try:
        with pytest.raises(InvalidValueError, match="joint limits"):
            c.set_goal(NAMES, [10.0] * 6)
        assert c.goal is None
    finally:
        c.stop()


@pytest.mark.parametrize(
    ("changes", "name"),
    [({"rate": 0.0}, "rate"), ({"deadline": 0.05}, "deadline"), ({"peer_timeout": -1}, "peer")],
)
def test_bad_control_settings_name_the_parameter(changes: dict[str, float], name: str) -> None:
    with pytest.raises(InvalidValueError, match=f"`{name}"):
        ControlSettings(**changes)  # type: ignore[arg-type]


def test_unknown_stale_policy_lists_the_valid_ones() -> None:
    with pytest.raises(UnknownNameError, match="fail_safe"):
        ControlSettings(stale_policy="ignore")


def test_worker_never_blocks_the_tick() -> None:
    c = _controller(RecordingPlanner(delay=0.2))
    try:
        _feed(c, 0.0, 1.0)
        c.tick(0.0)
        started = time.perf_counter()
        c.tick(0.04)
        assert time.perf_counter() - started < 0.02
        assert threading.active_count() >= 2
    finally:
        c.stop()
