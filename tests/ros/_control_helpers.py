"""Shared by the tests of the arm_planner's control loop (``test_control_*``): a planner whose
command tells which observation it came from, and a controller around it."""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping

import numpy as np

from nehmo_core.planning.opt.interface import PlanResult, Telemetry
from nehmo_core.robots import load_cell
from nehmo_ros.control import ArmController, ControlSettings

CELL = load_cell("dual_ur5")
NAMES = list(CELL.arm("ur5_0").robot.joint_names)
# The tests tag observations with large steps of the own first joint: no jump test here (the
# jump tests of test_control_peer_states.py turn it on).
SETTINGS = ControlSettings(rate=25.0, peer_timeout=0.25, jump_margin=math.inf)
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

    def commanded(self, u: np.ndarray) -> None:
        pass

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
