"""Self-clearance rows: exact gradients, feasibility of y = 0, and closed-loop self-safety."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.self_clearance import SelfClearance, project_step
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose

ROBOTS = ("ur5", "kinova_gen3_6dof")


@pytest.fixture(scope="module", params=ROBOTS)
def clearance(request: pytest.FixtureRequest) -> SelfClearance:
    sc = SelfClearance(load_robot(request.param), influence=0.3)
    yield sc
    sc.close()


def _random_q(robot, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi))


def test_row_gradients_match_finite_differences(clearance: SelfClearance) -> None:
    robot, rng, h = clearance.robot, np.random.default_rng(7), 1e-4
    checked = 0
    for _ in range(25):
        q = _random_q(robot, rng)
        rows = clearance.rows(q)
        for grad, d, pair in zip(rows.A, rows.distances, rows.pairs, strict=True):
            if d < 0.005:  # in or at contact the witness points may jump
                continue
            fd = np.empty(robot.dof)
            for j in range(robot.dof):
                step = np.zeros(robot.dof)
                step[j] = h
                ahead, behind = clearance.distances(q + step), clearance.distances(q - step)
                fd[j] = (ahead[pair] - behind[pair]) / (2 * h)
            np.testing.assert_allclose(grad, fd, atol=2e-3, err_msg=str(pair))
            checked += 1
    assert checked > 20


def test_rows_admit_standing_still_and_projection_keeps_them(clearance: SelfClearance) -> None:
    robot, rng = clearance.robot, np.random.default_rng(3)
    y_max = 0.05
    projected = 0
    for _ in range(40):
        q = _random_q(robot, rng)
        rows = clearance.rows(q)
        assert np.all(rows.b <= 0.0)
        assert rows.satisfied(np.zeros(robot.dof))
        target = rng.uniform(-y_max, y_max, robot.dof)
        y = project_step(target, rows, y_max)
        assert rows.satisfied(y, tol=1e-8)
        assert np.all(np.abs(y) <= y_max + 1e-12)
        if rows.satisfied(target):
            np.testing.assert_array_equal(y, target)
        else:
            projected += 1
            assert np.linalg.norm(y - target) > 0
    assert projected > 0


def _min_self_distance(world: CellWorld) -> float:
    return min((c.distance for c in world.collisions(margin=0.3)), default=0.3)


@pytest.mark.parametrize("robot_name", ROBOTS)
def test_damped_commands_keep_a_folding_arm_off_itself(robot_name: str) -> None:
    """Full speed on every joint toward folding: with the rows the arm never touches itself."""
    robot = load_robot(robot_name)
    settings = PlannerSettings()
    clearance = SelfClearance(
        robot, settings.self_influence, settings.self_safety, settings.self_gain
    )
    world = CellWorld(Cell("one", (ArmSpec("arm", robot, Pose()),)))
    dt, t_plan, u_max = 0.01, settings.t_plan, settings.u_max
    rng = np.random.default_rng(11)
    undamped_hits = 0
    try:
        for _ in range(6):
            q0 = _random_q(robot, rng) * 0.5
            world.set_joint_positions("arm", q0)
            if world.in_collision():
                continue
            direction = u_max * np.sign(rng.standard_normal(robot.dof))
            for damped in (True, False):
                q = q0.copy()
                for tick in range(400):  # 4 s at full speed
                    u = direction
                    if damped and tick % 4 == 0:  # re-planned at 25 Hz, held in between
                        rows = clearance.rows(q)
                        held = project_step(t_plan * direction, rows, t_plan * u_max) / t_plan
                    u = held if damped else direction
                    q = np.clip(q + dt * u, robot.lower, robot.upper)
                    world.set_joint_positions("arm", q)
                    hit = world.in_collision()
                    if damped:
                        assert not hit, f"self-collision at tick {tick}: {world.collisions()}"
                    elif hit:
                        undamped_hits += 1
                        break
    finally:
        clearance.close()
        world.close()
    assert undamped_hits > 0  # the scenario does fold the arm without the rows


def test_settings_reject_bad_self_clearance_values() -> None:
    with pytest.raises(InvalidValueError, match="self_influence"):
        PlannerSettings(self_influence=0.01, self_safety=0.02)
    with pytest.raises(InvalidValueError, match="self_gain"):
        PlannerSettings(self_gain=0.0)
    assert PlannerSettings.preset("paper").self_clearance is False
    assert PlannerSettings().self_clearance is True
