"""The control loop's handling of joint states: stale, rejected, reordered and teleporting
peers, a jumping own state, malformed messages, and a peer's announced speed bound."""

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
    _wait_idle,
)

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.opt.interface import PlanResult
from nehmo_ros.control import ArmController


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
