"""The bridge's command watchdog on simulated and on wall time, and the real-time factor rule."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

import sim_bridge.bridge as bridge_module
from nehmo_core.errors import InvalidValueError
from nehmo_core.robots import load_cell
from sim_bridge.bridge import SimBridgeNode
from sim_bridge.settings import DEFAULTS, BridgeSettings

CELL = load_cell("dual_ur5")
COMMAND = [0.1] * 6


def _settings(**changes: object) -> BridgeSettings:
    names = BridgeSettings.__dataclass_fields__
    return BridgeSettings(**{k: v for k, v in {**DEFAULTS, **changes}.items() if k in names})


class FakeClock:
    """``time.monotonic`` of the bridge module, moved by hand."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


class RclpyLikeLogger:
    """The standard logger with rclpy's keyword arguments (``throttle_duration_sec``)."""

    def __init__(self) -> None:
        self.log = logging.getLogger("bridge")

    def warning(self, msg: str, **_: object) -> None:
        self.log.warning(msg)

    def info(self, msg: str, **_: object) -> None:
        self.log.info(msg)


def _bridge(clock: FakeClock, **changes: object) -> SimBridgeNode:
    """A running bridge (episode started) without a middleware or a simulator; commands stay
    valid for 1 s unless ``command_validity`` is given (the watchdog tests)."""
    bridge = SimBridgeNode.__new__(SimBridgeNode)
    bridge.s = _settings(**{"command_validity": 1.0, **changes})
    bridge.cell = CELL
    bridge.t_ns = 0
    bridge.started, bridge.done = True, False
    bridge.commands, bridge.commanded, bridge._held = {}, set(), set()
    bridge.dropped = dict.fromkeys(CELL.arm_ids, 0)
    bridge.watchdog_trips = dict.fromkeys(CELL.arm_ids, 0)
    bridge.expired_steps = dict.fromkeys(CELL.arm_ids, 0)
    bridge.velocity_limits = {
        a.arm_id: np.array([j.velocity for j in a.robot.joints]) for a in CELL.arms
    }
    bridge.get_logger = lambda: RclpyLikeLogger()  # type: ignore[method-assign]
    return bridge


def _advance(bridge: SimBridgeNode, clock: FakeClock, sim_s: float, wall_s: float) -> None:
    bridge.t_ns += round(sim_s * 1e9)
    clock.now += wall_s


@pytest.mark.parametrize(
    ("changes", "sim_s", "wall_s", "moving"),
    [
        # simulated time 5x faster than wall time: 0.25 s of simulated time is too old
        ({"sim_time": True, "real_time_factor": 5.0}, 0.25, 0.05, False),
        ({"sim_time": True, "real_time_factor": 5.0}, 0.15, 0.03, True),
        # 10x slower: 0.1 s of simulated time (1 s of wall time) is still fresh
        ({"sim_time": True, "real_time_factor": 0.1}, 0.1, 1.0, True),
        ({"sim_time": True, "real_time_factor": 0.1}, 0.25, 2.5, False),
        # wall time: the age is wall time
        ({}, 0.15, 0.15, True),
        ({}, 0.25, 0.25, False),
    ],
    ids=["rtf5_stale", "rtf5_fresh", "rtf0.1_fresh", "rtf0.1_stale", "wall_fresh", "wall_stale"],
)
def test_command_age_is_measured_on_the_bridge_clock(
    monkeypatch: pytest.MonkeyPatch,
    changes: dict[str, object],
    sim_s: float,
    wall_s: float,
    moving: bool,
) -> None:
    clock = FakeClock()
    monkeypatch.setattr(bridge_module, "time", clock)
    bridge = _bridge(clock, **changes)
    bridge._on_command("ur5_0", SimpleNamespace(data=COMMAND))
    np.testing.assert_array_equal(bridge._applied()["ur5_0"], COMMAND)
    _advance(bridge, clock, sim_s, wall_s)
    applied = bridge._applied()["ur5_0"]
    np.testing.assert_array_equal(applied, COMMAND if moving else np.zeros(6))
    assert bridge.watchdog_trips["ur5_0"] == (0 if moving else 1)


def test_a_dead_planner_is_caught_after_command_timeout_of_simulated_time(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """At 5x real time the last command drives the arm for command_timeout (20 steps at
    100 Hz) of simulated time, not for command_timeout of wall time (100 steps)."""
    clock = FakeClock()
    monkeypatch.setattr(bridge_module, "time", clock)
    bridge = _bridge(clock, sim_time=True, real_time_factor=5.0)
    bridge._on_command("ur5_0", SimpleNamespace(data=COMMAND))
    moving_steps = 0
    for _ in range(100):
        if np.any(bridge._applied()["ur5_0"]):
            moving_steps += 1
        _advance(bridge, clock, 0.01, 0.01 / 5.0)
    assert moving_steps == 21  # ages 0, 0.01, ..., 0.2 s
    assert bridge.watchdog_trips["ur5_0"] == 1


@pytest.mark.parametrize("rtf", [1.0, 5.0])
def test_a_late_planners_command_drives_its_arm_for_one_period_then_the_arm_holds_still(
    monkeypatch: pytest.MonkeyPatch, rtf: float
) -> None:
    """With the default validity (0.06 s of bridge time) a command moves its arm on 7 physics
    steps (ages 0 ... 0.06 s); the arm then holds still, counted, without a watchdog trip, and
    the next command moves it at once."""
    clock = FakeClock()
    monkeypatch.setattr(bridge_module, "time", clock)
    bridge = _bridge(
        clock, sim_time=True, real_time_factor=rtf, command_validity=DEFAULTS["command_validity"]
    )
    bridge._on_command("ur5_0", SimpleNamespace(data=COMMAND))
    moving = []
    for _ in range(15):  # 0.15 s of bridge time: three periods without a new command
        moving.append(bool(np.any(bridge._applied()["ur5_0"])))
        _advance(bridge, clock, 0.01, 0.01 / rtf)
    assert moving == [True] * 7 + [False] * 8
    assert bridge.expired_steps == {"ur5_0": 8, "ur5_1": 0}
    assert bridge.watchdog_trips == {"ur5_0": 0, "ur5_1": 0}
    bridge._on_command("ur5_0", SimpleNamespace(data=COMMAND))
    np.testing.assert_array_equal(bridge._applied()["ur5_0"], COMMAND)


def test_command_validity_must_be_positive() -> None:
    with pytest.raises(InvalidValueError, match="`command_validity` must be > 0"):
        _settings(command_validity=0.0)


@pytest.mark.parametrize("rtf", [0.5, 2.0])
def test_a_real_time_factor_needs_sim_time(rtf: float) -> None:
    with pytest.raises(
        InvalidValueError, match="`real_time_factor` must be 1 without sim_time"
    ) as info:
        _settings(sim_time=False, real_time_factor=rtf)
    assert f"got {rtf!r}" in str(info.value)
    assert _settings(sim_time=True, real_time_factor=rtf).real_time_factor == rtf
    assert _settings(sim_time=False, real_time_factor=1.0).real_time_factor == 1.0
