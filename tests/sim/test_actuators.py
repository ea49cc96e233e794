"""Actuator models in the simulator: ``ideal`` is ``q̇ = u`` exactly; ``realistic`` tracks a
command under the joint acceleration limits after the command latency, and planners read noisy
joint states while collisions use the true ones."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings
from nehmo_core.robots import load_cell, load_robot
from nehmo_core.sim.actuators import (
    REALISTIC_LATENCY,
    REALISTIC_NOISE,
    ActuatorModel,
    ArmTracker,
    actuator_model,
)
from nehmo_core.sim.cell_sim import CellSimulator

CELL = load_cell("dual_ur5")
A, B = CELL.arm_ids
Q0 = {
    A: np.array([0.0, -1.6, 1.2, -1.2, -1.6, 0.0]),
    B: np.array([0.0, -1.6, 1.2, -1.2, -1.6, 0.0]),
}
DT = 0.04


def test_the_ideal_model_integrates_the_command_exactly() -> None:
    u = {A: np.array([0.5, -0.5, 0.3, 0.0, 0.2, -0.1]), B: np.zeros(6)}
    with CellSimulator(CELL, substeps=4) as sim:
        sim.reset(Q0)
        q = Q0[A].copy()
        for _ in range(5):
            sim.step(u, DT)
            q = q + DT * u[A]
        np.testing.assert_array_equal(sim.positions()[A], q)
        for arm, q in sim.observed().items():
            np.testing.assert_array_equal(q, sim.positions()[arm])


def test_a_reversal_under_the_acceleration_limit_keeps_going_the_old_way() -> None:
    """From +0.5 rad/s, a −0.5 command: the joint decelerates at its limit after the latency,
    so it still travels forward by v·latency + v²/(2a) before it turns (analytic)."""
    ur5 = load_robot("ur5")
    model = actuator_model("realistic", ur5)
    a = model.accel[0]  # type: ignore[index]
    tracker = ArmTracker(model, 6)
    q = np.zeros(6)
    tracker.send(0.0, np.full(6, 0.5))
    q = tracker.advance(q, 0.0, 1.0)  # long enough to reach +0.5
    np.testing.assert_allclose(tracker.velocity, 0.5)
    start = q.copy()
    tracker.send(1.0, np.full(6, -0.5))
    furthest, t = start.copy(), 1.0
    for _ in range(100):  # 0.4 s in 4 ms steps
        q = tracker.advance(q, t, 0.004)
        t += 0.004
        furthest = np.maximum(furthest, q)
        assert np.all(np.abs(np.diff([0.5, *tracker.velocity])) <= 1.0 + 1e-12)
    overshoot = furthest[0] - start[0]
    expected = 0.5 * REALISTIC_LATENCY + 0.5**2 / (2 * a)
    assert overshoot == pytest.approx(expected, abs=2e-4)
    np.testing.assert_allclose(tracker.velocity, -0.5)  # 1 rad/s at 5 rad/s² takes 0.2 s


def test_velocity_never_changes_faster_than_the_limit_in_the_simulator() -> None:
    rng = np.random.default_rng(0)
    with CellSimulator(CELL, substeps=4, actuators="realistic") as sim:
        sim.reset(Q0)
        before = {arm: np.zeros(6) for arm in CELL.arm_ids}
        for _ in range(30):
            sim.step({arm: rng.choice([-0.5, 0.5], 6) for arm in CELL.arm_ids}, DT)
            for arm, tracker in sim.trackers.items():
                limit = np.asarray(tracker.model.accel) * DT
                assert np.all(np.abs(tracker.velocity - before[arm]) <= limit + 1e-9)
                before[arm] = tracker.velocity.copy()


def test_nothing_moves_before_the_latency() -> None:
    tracker = ArmTracker(ActuatorModel("test", None, latency=0.012), 6)
    tracker.send(0.0, np.full(6, 0.5))
    q = tracker.advance(np.zeros(6), 0.0, 0.012)
    np.testing.assert_allclose(q, 0.0, atol=1e-12)
    q = tracker.advance(q, 0.012, 0.028)
    np.testing.assert_allclose(q, 0.5 * 0.028, atol=1e-12)


def test_planners_read_noisy_states_seeded_and_collisions_use_true_ones() -> None:
    with CellSimulator(CELL, actuators="realistic") as sim:
        sim.reset(Q0, seed=4)
        first = [sim.observed()[A] for _ in range(200)]
        sim.reset(Q0, seed=4)
        again = [sim.observed()[A] for _ in range(200)]
        np.testing.assert_array_equal(first, again)
        err = np.array(first) - Q0[A]
        assert np.std(err) == pytest.approx(REALISTIC_NOISE, rel=0.15)
        np.testing.assert_array_equal(sim.positions()[A], Q0[A])


def test_bad_models_are_refused_with_the_rule() -> None:
    with pytest.raises(UnknownNameError, match="actuator model"):
        actuator_model("springy", load_robot("ur5"))
    with pytest.raises(InvalidValueError, match=r"facts\.accel_limits"):
        actuator_model("realistic", load_robot("planar_2link"))
    with pytest.raises(InvalidValueError, match="accel"):
        ActuatorModel("x", (5.0, -1.0))
    with pytest.raises(InvalidValueError, match="latency"):
        ActuatorModel("x", None, latency=-0.01)
    with pytest.raises(UnknownNameError, match="actuator model"):
        EpisodeSettings(actuators="springy")


def test_the_shipped_robots_state_their_limits_and_source() -> None:
    for name in ("ur5", "panda", "kinova_gen3_6dof"):
        robot = load_robot(name)
        assert robot.facts.accel_limits is not None and len(robot.facts.accel_limits) == robot.dof
        assert robot.facts.accel_source
