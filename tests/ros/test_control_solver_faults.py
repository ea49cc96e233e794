"""Repeated solver faults under the control loop (``fault_injection``): a solver that always
raises, one slower than every tick, one that raises inside the planner; the parameter's values."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from _control_helpers import (
    CELL,
    FAIL_SAFE,
    TIMEOUT,
    RecordingPlanner,
    _controller,
    _feed,
    _wait_idle,
)

from nehmo_core.errors import InvalidValueError
from nehmo_ros.control import ArmController


def _run_ticks(c: ArmController, ticks: int, period: float = 0.04) -> list:
    out = []
    for k in range(ticks):
        _feed(c, k * period, 0.0)
        out.append(c.tick(k * period))
        _wait_idle(c)
    return out


def test_a_solver_that_always_raises_commands_the_fail_safe_and_counts() -> None:
    from nehmo_ros.fault_injection import FaultInjectingPlanner, parse_fault

    spec = parse_fault("raise@2")
    assert spec is not None
    c = _controller(FaultInjectingPlanner(RecordingPlanner(), spec))  # type: ignore[arg-type]
    try:
        decisions = _run_ticks(c, 12)
        _wait_idle(c)
        failed = [d for d in decisions if d.status == "failed"]
        assert len(failed) >= 5 and all("injected" in d.error for d in failed)
        for d in failed:
            np.testing.assert_array_equal(d.velocity, FAIL_SAFE)
        assert c.counters.solver_errors == len(failed)
        assert decisions[1].status == "optimal"  # before the fault starts
    finally:
        c.stop()


class _TestClock:
    """Stands in for the ``time`` module of the fault injection: a ``slow`` fault's sleep ends
    once the test's clock (advanced tick by tick) has passed it, not the wall clock."""

    def __init__(self) -> None:
        self.now = 0.0
        self.sleeps: list[float] = []
        self._cond = threading.Condition()
        self._asleep_until: float | None = None

    def sleep(self, seconds: float) -> None:  # the worker thread
        with self._cond:
            self.sleeps.append(seconds)
            end = self._asleep_until = self.now + seconds
            self._cond.notify_all()
            woke = self._cond.wait_for(lambda: self.now >= end - 1e-9, TIMEOUT)
            self._asleep_until = None
            self._cond.notify_all()
        if not woke:
            raise TimeoutError("the test clock never reached the end of the slow-down")

    def advance(self, now: float) -> bool:
        """Set the clock; True if that ends the sleep in progress."""
        with self._cond:
            self.now = now
            self._cond.notify_all()
            return self._asleep_until is not None and now >= self._asleep_until - 1e-9

    def wait_asleep(self) -> None:
        """Wait until a solve sleeps in the slow-down."""
        with self._cond:
            assert self._cond.wait_for(lambda: self._asleep_until is not None, TIMEOUT)


def test_a_slow_solver_misses_every_deadline_and_stays_on_the_fail_safe(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from nehmo_ros import fault_injection
    from nehmo_ros.fault_injection import FaultInjectingPlanner, parse_fault

    clock = _TestClock()
    monkeypatch.setattr(fault_injection, "time", clock)
    spec = parse_fault("slow:0.06")
    assert spec is not None
    c = _controller(FaultInjectingPlanner(RecordingPlanner(), spec))  # type: ignore[arg-type]
    try:
        decisions = []
        for k in range(10):  # on the test's clock: each solve (60 ms) outlasts a 40 ms tick
            if clock.advance(k * 0.04):  # a solve started 2 ticks ago ends before this tick
                _wait_idle(c)
            _feed(c, k * 0.04, 0.0)
            decisions.append(c.tick(k * 0.04))
            clock.wait_asleep()  # the solve of this tick (or of the last) is in its slow-down
        assert clock.sleeps == [0.06] * 5  # every other tick a new solve: ticks 0, 2, 4, 6, 8
        assert decisions[0].status == "starting"
        assert c.counters.deadline_misses == 9  # no solve ever finished within its tick
        for d in decisions[1:]:
            assert d.status == "deadline_missed" and d.fail_safe and not d.hold
            np.testing.assert_array_equal(d.velocity, FAIL_SAFE)
    finally:
        clock.advance(math.inf)  # a solve still in its slow-down ends, so the worker can stop
        c.stop()


@pytest.mark.parametrize(
    ("text", "rule"),
    [
        ("explode", "KIND"),
        ("slow", "finite delay"),
        ("hang:-1", "SECONDS must be > 0"),
        ("raise@x", "KIND"),
    ],
)
def test_fault_injection_values_are_checked(text: str, rule: str) -> None:
    from nehmo_ros.fault_injection import parse_fault

    with pytest.raises(InvalidValueError, match=rule) as info:
        parse_fault(text)
    assert "`fault_injection`" in str(info.value)


def test_fault_injection_is_off_by_default() -> None:
    from nehmo_ros.arm_planner import PARAMS
    from nehmo_ros.fault_injection import parse_fault

    assert PARAMS["fault_injection"].default == "" and parse_fault("") is None


def test_solver_raise_ends_in_the_planners_own_fail_safe() -> None:
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_ros.fault_injection import FaultInjectingPlanner, parse_fault
    from nehmo_ros.planners import build_planner

    inner = build_planner(
        "nehmo", CELL, "ur5_0", "synthetic", PlannerSettings().override({"opt.deadline": 1.0})
    )
    spec = parse_fault("solver_raise@1")
    assert spec is not None
    planner = FaultInjectingPlanner(inner, spec)
    q = {"ur5_0": np.array([0.0, -1.5, 1.5, 0, 0, 0]), "ur5_1": np.array([0.0, -1.5, 1.5, 0, 0, 0])}
    goal = q["ur5_0"] + 0.3
    first = planner.plan(q["ur5_0"], {"ur5_1": q["ur5_1"]}, goal)
    assert not first.telemetry.status.startswith("failed")
    second = planner.plan(q["ur5_0"], {"ur5_1": q["ur5_1"]}, goal)
    assert second.telemetry.status == "failed (InjectedFault)" and second.telemetry.fail_safe
    assert set(np.abs(second.velocity)) <= {0.0, 0.5}
