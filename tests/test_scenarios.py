"""Scenario sampling follows the protocol's ranges (converted to this UR5's zeros)."""

from __future__ import annotations

import numpy as np

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import load_cell, load_robot
from nehmo_core.sim.scenarios import (
    SAMPLING_RANGES,
    goal_error,
    sample_configuration,
    sample_scenario,
)


def test_ur5_samples_in_converted_ranges() -> None:
    ur5 = load_robot("ur5")
    rng = np.random.default_rng(0)
    q = np.array([sample_configuration(ur5, rng) for _ in range(500)])
    box = SAMPLING_RANGES["ur5"]
    # q1 ∈ [−5, −1.5] wrapped: either side of ±π.
    q1 = np.where(q[:, 0] > 0, q[:, 0] - 2 * np.pi, q[:, 0])
    assert q1.min() >= -5.0 - 1e-9 and q1.max() <= -1.5 + 1e-9
    for j in range(1, 6):
        assert q[:, j].min() >= box[j, 0] - 1e-9 and q[:, j].max() <= box[j, 1] + 1e-9
    # The paper's shoulder_lift range [−1, 0.5] is [−1 − π/2, 0.5 − π/2] here.
    assert box[1, 0] == -1.0 - np.pi / 2


def test_scenarios_are_collision_free_and_seeded() -> None:
    cell = load_cell("dual_ur5")
    with CellWorld(cell) as world:
        a = sample_scenario(cell, np.random.default_rng(4), world)
        b = sample_scenario(cell, np.random.default_rng(4), world)
        for arm_id in cell.arm_ids:
            np.testing.assert_array_equal(a.start[arm_id], b.start[arm_id])
        world.set_configuration(a.start)
        assert not world.in_collision()
        world.set_configuration(a.goal)
        assert not world.in_collision()


def test_kinova_samples_within_limits() -> None:
    kin = load_robot("kinova_gen3_6dof")
    rng = np.random.default_rng(1)
    for _ in range(100):
        kin.check_within_limits(sample_configuration(kin, rng))


def test_goal_error_wraps_continuous_joints() -> None:
    ur5 = load_robot("ur5")
    e = goal_error(np.array([3.1, 0, 0, 0, 0, 0]), np.array([-3.1, 0, 0, 0, 0, 0]), ur5)
    assert abs(e[0]) < 0.1
