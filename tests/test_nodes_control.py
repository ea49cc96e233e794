"""The arm_planner's control loop without a middleware: timing, fail-safes, bad peer input."""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.opt.interface import PlanResult, Telemetry
from nehmo_core.robots import load_cell
from nehmo_ros.control import ArmController, ControlSettings, Decision

CELL = load_cell("dual_ur5")
NAMES = list(CELL.arm("ur5_0").robot.joint_names)
# The tests tag observations with large steps of the own first joint: no jump test here (the
# jump tests below turn it on).
SETTINGS = ControlSettings(rate=25.0, deadline=0.03, peer_timeout=0.25, jump_margin=math.inf)
FAIL_SAFE = np.full(6, 0.5)
TIMEOUT = 30.0  # [s] longest wait for an event of another thread (never reached when passing)


class RecordingPlanner:
    """Commands the own first joint value, so a command tells which observation it came from.

    With a ``delay`` [s], ``plan()`` reports that solve time and does not return before the
    test sets ``release``: a solve is late because the test says so, not because of the clock.
    ``entered`` is set once ``plan()`` runs (the worker has stored the fail-safe by then).
    """

    arm_id = "ur5_0"
    announces = False
    announcement = 1.0
    peers_unmodelled: tuple[str, ...] = ()
    epsilon_source = ""

    def __init__(self, delay: float = 0.0, error: Exception | None = None) -> None:
        self.delay = delay
        self.error = error
        self.calls: list[np.ndarray] = []
        self.entered = threading.Event()
        self.release = threading.Event()

    def plan(
        self,
        q_self: np.ndarray,
        peers: Mapping[str, np.ndarray],
        q_goal: np.ndarray,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        self.calls.append(np.array(q_self))
        self.entered.set()
        if self.delay:
            assert self.release.wait(TIMEOUT), "the test never released the solve"
        if self.error is not None:
            raise self.error
        return PlanResult(np.full(6, q_self[0] * 0.01), Telemetry(self.delay, "optimal"))

    def fail_safe(
        self,
        q_self: np.ndarray,
        peers: Mapping[str, np.ndarray],
        peer_bounds: Mapping[str, float] | None = None,
    ) -> np.ndarray:
        return FAIL_SAFE.copy()

    def reset(self) -> None:
        pass


def _controller(planner: RecordingPlanner, **changes: object) -> ArmController:
    settings = ControlSettings(**{**SETTINGS.__dict__, **changes})  # type: ignore[arg-type]
    c = ArmController(CELL, "ur5_0", planner, settings)  # type: ignore[arg-type]
    c.set_goal(NAMES, [0.1] * 6)
    stop = c.stop

    def release_then_stop() -> None:  # a solve held by the test ends before the worker stops
        if isinstance(planner, RecordingPlanner):
            planner.release.set()
        stop()

    c.stop = release_then_stop  # type: ignore[method-assign]
    return c


def _in_plan(planner: RecordingPlanner) -> None:
    """Wait until the worker runs ``planner.plan()`` (its fail-safe is stored by then)."""
    assert planner.entered.wait(TIMEOUT)


def _feed(c: ArmController, now: float, q0: float, peer: bool = True) -> None:
    c.states.update("ur5_0", NAMES, [q0, 0, 0, 0, 0, 0], now)
    if peer:
        c.states.update("ur5_1", NAMES, [0.0] * 6, now)


def _wait_idle(c: ArmController, timeout: float = TIMEOUT) -> None:
    assert c.wait_idle(timeout)


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


# ----------------------------------------------------------------------- jumps, untrusted peers
def _jump_controller(planner: RecordingPlanner, **changes: object) -> ArmController:
    return _controller(planner, jump_margin=0.1, **changes)


def _step(c: ArmController, now: float, peer_q: list[float], own_q0: float = 0.0) -> None:
    c.states.update("ur5_0", NAMES, [own_q0, 0, 0, 0, 0, 0], now)
    c.states.update("ur5_1", NAMES, peer_q, now)


@pytest.mark.parametrize(
    ("policy", "expected"), [("fail_safe", FAIL_SAFE), ("hold", np.zeros(6))], ids=["fs", "hold"]
)
def test_a_teleporting_peer_is_untrusted_for_peer_timeout(
    policy: str, expected: np.ndarray
) -> None:
    planner = RecordingPlanner()
    c = _jump_controller(planner, stale_policy=policy)
    try:
        _step(c, 0.0, [0.0] * 6)
        c.tick(0.0)
        _wait_idle(c)
        note = c.states.update("ur5_1", NAMES, [0.8] + [0.0] * 5, 0.01)  # 0.8 rad in 10 ms
        assert note is not None and note.startswith("jumped") and "shoulder_pan_joint" in note
        assert c.states.jumps["ur5_1"] == 1
        c.states.update("ur5_0", NAMES, [0.0] * 6, 0.04)
        c.tick(0.04)
        _wait_idle(c)
        d = c.tick(0.08)
        assert d.status == "untrusted_peer" and d.untrusted == ("ur5_1",)
        np.testing.assert_array_equal(d.velocity, expected)
        calls = len(planner.calls)
        for k in range(3, 12):  # consistent states again: trusted once peer_timeout has passed
            _step(c, 0.04 * k, [0.8] + [0.0] * 5)
            d = c.tick(0.04 * k)
            _wait_idle(c)
        assert d.status == "optimal" and not d.untrusted
        assert len(planner.calls) > calls
    finally:
        c.stop()


def test_motion_within_the_speed_bound_is_no_jump() -> None:
    c = _jump_controller(RecordingPlanner())
    try:
        q, now = np.full(6, np.pi - 0.2), 0.0
        for _ in range(100):  # 0.5 rad/s on every joint at 100 Hz, published wrapped to ±π
            q = (q + 0.005 + np.pi) % (2 * np.pi) - np.pi
            now += 0.01
            assert c.states.update("ur5_1", NAMES, list(q), now) is None
        for _ in range(5):  # a burst of queued messages received together
            q = q + 0.005
            assert c.states.update("ur5_1", NAMES, list(q), now) is None
        assert c.states.jumps["ur5_1"] == 0
    finally:
        c.stop()


def test_a_large_header_stamp_interval_allows_a_large_step() -> None:
    """Simulated time faster than wall time: the stamps tell how long the arm could move."""
    c = _jump_controller(RecordingPlanner())
    try:
        c.states.update("ur5_1", NAMES, [0.0] * 6, 0.0, stamp_ns=1_000_000_000)
        assert c.states.update("ur5_1", NAMES, [0.5] * 6, 0.01, stamp_ns=2_000_000_000) is None
        assert c.states.update("ur5_1", NAMES, [1.0] * 6, 0.02, stamp_ns=2_010_000_000)
    finally:
        c.stop()


def test_a_rejected_peer_state_untrusts_the_peer_at_once() -> None:
    c = _jump_controller(RecordingPlanner())
    try:
        _step(c, 0.0, [0.0] * 6)
        c.tick(0.0)
        _wait_idle(c)
        note = c.states.update("ur5_1", NAMES, [math.nan] * 6, 0.02)
        assert note is not None and note.startswith("rejected")
        c.states.update("ur5_0", NAMES, [0.0] * 6, 0.04)
        c.tick(0.04)  # the peer's last valid state is 40 ms old: fresh, but untrusted
        _wait_idle(c)
        d = c.tick(0.08)
        assert d.status == "untrusted_peer" and d.hold and not d.stale  # the default policy
        assert not np.any(d.velocity)
    finally:
        c.stop()


def test_a_jumping_own_state_holds_the_arm() -> None:
    c = _jump_controller(RecordingPlanner())
    try:
        _step(c, 0.0, [0.0] * 6)
        c.states.update("ur5_0", NAMES, [1.0] + [0.0] * 5, 0.02)
        c.states.update("ur5_1", NAMES, [0.0] * 6, 0.02)
        c.tick(0.02)
        _wait_idle(c)
        d = c.tick(0.06)
        assert d.status == "own_state_untrusted" and d.hold and not np.any(d.velocity)
    finally:
        c.stop()


def test_malformed_messages_are_rejected_not_raised() -> None:
    c = _jump_controller(RecordingPlanner())
    try:
        assert (c.states.update("ur5_1", NAMES, ["x"] * 6, 0.0) or "").startswith("rejected")  # type: ignore[list-item]
        assert (c.states.update("ur5_1", [1, 2], [0.0] * 2, 0.0) or "").startswith("rejected")  # type: ignore[list-item]
        assert c.states.rejected["ur5_1"] == 2
    finally:
        c.stop()


# ------------------------------------------------------------------- repeated solver faults
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
    from nehmo_core.planning.opt.settings import PlannerSettings
    from nehmo_ros.fault_injection import FaultInjectingPlanner, parse_fault
    from nehmo_ros.planners import build_planner

    inner = build_planner("nehmo", CELL, "ur5_0", "synthetic", PlannerSettings(deadline=1.0))
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


# ------------------------------------------------------------- deadline misses: solve times
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


class BoundPlanner(RecordingPlanner):
    """Announces 0.2 and records the peer bounds it is given."""

    announces = True
    announcement = 0.2

    def __init__(self) -> None:
        super().__init__()
        self.bounds: list[dict[str, float]] = []

    def plan(
        self,
        q_self: np.ndarray,
        peers: Mapping[str, np.ndarray],
        q_goal: np.ndarray,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        self.bounds.append(dict(peer_bounds or {}))
        return super().plan(q_self, peers, q_goal)


def test_a_peers_announced_bound_reaches_the_planner_until_the_peer_moves_faster() -> None:
    planner = BoundPlanner()
    c = _controller(planner)
    assert c.announcement == 0.2
    for _ in range(3):
        c.announce("ur5_1", 0.1)
    q_peer = np.zeros(6)
    for k in range(4):  # the peer moves at 0.1·d̄, stamped every 10 ms
        q_peer[0] += 0.1 * 0.5 * 0.01
        c.update_state("ur5_1", NAMES, list(q_peer), k * 0.01, (k + 1) * 10_000_000)
    c.update_state("ur5_0", NAMES, [0.0] * 6, 0.04)
    c.tick(0.04)
    _wait_idle(c)
    assert planner.bounds[-1] == {"ur5_1": 0.1}
    q_peer[0] += 0.5 * 0.01  # full speed for 10 ms: breaks 0.1
    c.update_state("ur5_1", NAMES, list(q_peer), 0.05, 50_000_000)
    c.update_state("ur5_0", NAMES, [0.0] * 6, 0.08)
    c.tick(0.08)
    _wait_idle(c)
    assert planner.bounds[-1] == {"ur5_1": 1.0}
    with pytest.raises(InvalidValueError, match="speed bound"):
        c.announce("ur5_1", -0.5)
    with pytest.raises(InvalidValueError, match="arm_id"):
        c.announce("ur5_0", 0.5)
    c.stop()
