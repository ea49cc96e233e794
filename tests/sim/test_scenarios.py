"""Scenario sampling follows the protocol: ranges (in this UR5's zeros), draws and filters."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode import EpisodeSettings
from nehmo_core.eval.scenario_sets import naive_collides, scenario_set_for, scenario_set_path
from nehmo_core.eval.setups import get_setup
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import load_cell, load_robot
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenarios import (
    DRAW_ORDERS,
    PAPER_SEED,
    SAMPLING_REVISION,
    Scenario,
    draw_order,
    goal_error,
    sample_cell_configuration,
    sample_configuration,
    sample_scenario,
    sampling_box,
    scenario_rng,
)

UP = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])  # this UR5's arm straight up


def _q1_unwrapped(q1: np.ndarray) -> np.ndarray:
    """The protocol's q1 ∈ [−5, −1.5] after wrapping: undo the wrap of the part above π."""
    return np.where(q1 > 0, q1 - 2 * np.pi, q1)


def test_ur5_samples_in_converted_ranges() -> None:
    ur5 = load_robot("ur5")
    rng = np.random.default_rng(0)
    q = np.array([sample_configuration(ur5, rng) for _ in range(500)])
    box = sampling_box(ur5)
    np.testing.assert_array_equal(box, np.array(ur5.facts.sampling_ranges))
    q1 = _q1_unwrapped(q[:, 0])
    assert q1.min() >= -5.0 - 1e-9 and q1.max() <= -1.5 + 1e-9
    assert q[:, 0].min() >= -np.pi and q[:, 0].max() <= np.pi  # wrapped
    for j in range(1, 6):
        assert q[:, j].min() >= box[j, 0] - 1e-9 and q[:, j].max() <= box[j, 1] + 1e-9
    # The paper's shoulder_lift and wrist_1 ranges are shifted by −π/2 here, the others not.
    np.testing.assert_allclose(box[1], [-1.0 - np.pi / 2, 0.5 - np.pi / 2])
    np.testing.assert_allclose(box[3], [-0.2 - np.pi / 2, 0.8 - np.pi / 2])
    np.testing.assert_allclose(box[[2, 4, 5]], [[1.0, 2.0], [-2.5, -0.5], [-1e-4, 0.0]])


def test_kinova_samples_within_limits_clipped_to_a_turn() -> None:
    kin = load_robot("kinova_gen3_6dof")
    box = sampling_box(kin)
    np.testing.assert_allclose(box[:, 1], np.minimum(kin.upper, np.pi))
    rng = np.random.default_rng(1)
    for _ in range(100):
        kin.check_within_limits(sample_configuration(kin, rng))


@pytest.mark.parametrize("name", sorted(DRAW_ORDERS))
def test_draw_orders_name_every_joint_of_their_cell_once(name: str) -> None:
    cell = load_cell(name)
    order = draw_order(cell)
    assert sorted(order.tolist()) == list(range(sum(a.robot.dof for a in cell.arms)))


def test_a_cell_configuration_is_one_draw_in_the_cells_joint_order() -> None:
    """Slow, obvious reference: the k-th uniform number goes to the joint named by token k."""
    cell = load_cell("dual_ur5")
    got = sample_cell_configuration(cell, np.random.default_rng(7))
    u = np.random.default_rng(7).random(12)
    want = {a: np.zeros(6) for a in cell.arm_ids}
    for k, token in enumerate(DRAW_ORDERS["dual_ur5"].split()):
        arm_number, joint = (int(x) - 1 for x in token.split("."))
        lo, hi = sampling_box(load_robot("ur5"))[joint]
        want[cell.arm_ids[arm_number]][joint] = lo + (hi - lo) * u[k]
    for arm in cell.arms:
        np.testing.assert_allclose(got[arm.arm_id], arm.robot.wrap(want[arm.arm_id]), atol=1e-12)


def test_cells_without_a_draw_order_draw_arm_by_arm() -> None:
    cell = load_cell("dual_ur5")
    other = replace(cell, name="my_cell")
    got = sample_cell_configuration(other, np.random.default_rng(3))
    rng = np.random.default_rng(3)
    for arm in other.arms:
        np.testing.assert_array_equal(got[arm.arm_id], sample_configuration(arm.robot, rng))


@pytest.mark.parametrize("name", ["triple_ur5", "five_ur5", "ur5_kinova"])
def test_every_arm_of_a_cell_samples_in_its_box(name: str) -> None:
    cell = load_cell(name)
    rng = np.random.default_rng(2)
    draws = [sample_cell_configuration(cell, rng) for _ in range(200)]
    for arm in cell.arms:
        q = np.array([d[arm.arm_id] for d in draws])
        box = sampling_box(arm.robot).copy()
        if arm.robot.name == "ur5":
            q[:, 0] = _q1_unwrapped(q[:, 0])
        assert np.all(q >= box[:, 0] - 1e-9) and np.all(q <= box[:, 1] + 1e-9), arm.arm_id


def test_scenarios_are_collision_free_and_seeded() -> None:
    cell = load_cell("dual_ur5")
    with CellWorld(cell) as world:
        a = sample_scenario(cell, scenario_rng(4, 2), world)
        b = sample_scenario(cell, scenario_rng(4, 2), world)
        c = sample_scenario(cell, scenario_rng(5, 2), world)
        for arm_id in cell.arm_ids:
            np.testing.assert_array_equal(a.start[arm_id], b.start[arm_id])
            np.testing.assert_array_equal(a.goal[arm_id], b.goal[arm_id])
        assert not np.allclose(a.start["ur5_0"], c.start["ur5_0"])
        for q in (a.start, a.goal):
            world.set_configuration(q)
            assert not world.in_collision()


def test_the_paper_seed_draws_trial_i_from_default_rng_i() -> None:
    assert PAPER_SEED == 0
    for index in (0, 3):
        np.testing.assert_array_equal(
            scenario_rng(0, index).random(4), np.random.default_rng(index).random(4)
        )
    np.testing.assert_array_equal(
        scenario_rng(2, 3).random(4), np.random.default_rng([2, 3]).random(4)
    )
    # Trial 0 of the authors' dual-UR5 set: the first draw is collision-free, so it is the start.
    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, scenario_rng(0, 0))
    first = sample_cell_configuration(cell, np.random.default_rng(0))
    np.testing.assert_array_equal(scenario.start["ur5_1"], first["ur5_1"])
    with pytest.raises(InvalidValueError, match="seed"):
        scenario_rng(-1, 0)
    with pytest.raises(InvalidValueError, match="index"):
        scenario_rng(0, -2)


def test_goal_error_wraps_continuous_joints() -> None:
    ur5 = load_robot("ur5")
    e = goal_error(np.array([3.1, 0, 0, 0, 0, 0]), np.array([-3.1, 0, 0, 0, 0, 0]), ur5)
    assert abs(e[0]) < 0.1


def test_challenging_filter_keeps_inter_arm_collisions_only() -> None:
    cell = load_cell("ur5_kinova")
    settings = EpisodeSettings.for_setup(get_setup("ur5_kinova_challenging"))
    still = np.zeros(6)
    # The UR5 swings down onto the Kinova: an inter-arm collision.
    into_kinova = UP.copy()
    into_kinova[1] = 0.0
    # The UR5, turned away from the Kinova, folds its elbow onto itself: a self-collision only.
    away = UP.copy()
    away[0] = np.pi
    folded = away.copy()
    folded[2] = 3.0
    with CellSimulator(cell, settings.substeps, settings.self_collision) as sim:
        accept = naive_collides(cell, settings, sim)
        assert accept(
            Scenario({"ur5_0": UP, "kinova_0": still}, {"ur5_0": into_kinova, "kinova_0": still})
        )
        assert not accept(
            Scenario({"ur5_0": away, "kinova_0": still}, {"ur5_0": folded, "kinova_0": still})
        )
        assert not accept(
            Scenario({"ur5_0": away, "kinova_0": still}, {"ur5_0": UP, "kinova_0": still})
        )


def test_saved_sets_of_another_sampling_revision_are_redrawn(tmp_path: Path) -> None:
    setup = get_setup("dual_ur5")
    made = scenario_set_for(setup, seed=6, count=1, directory=tmp_path)
    assert made.meta["sampling"] == SAMPLING_REVISION
    path = scenario_set_path(tmp_path, setup, 6)
    data = json.loads(path.read_text())
    data["meta"]["sampling"] = SAMPLING_REVISION - 1
    data["scenarios"][0]["start"]["ur5_0"][2] = 1.5  # a stale draw
    path.write_text(json.dumps(data))
    again = scenario_set_for(setup, seed=6, count=1, directory=tmp_path)
    np.testing.assert_array_equal(
        again.scenarios[0].start["ur5_0"], made.scenarios[0].start["ur5_0"]
    )
    assert json.loads(path.read_text())["meta"]["sampling"] == SAMPLING_REVISION


def test_cells_beyond_the_papers_keep_their_goals_apart(tmp_path: Path) -> None:
    """dual_panda seed 83, candidate 3 has goals 3 mm apart: it is skipped, every kept goal set
    is ``goal_separation`` apart (exact distance), and the kept candidates are the unfiltered
    draws of the same numbers; a saved set drawn without the rule is redrawn."""
    setup = get_setup("dual_panda")
    assert setup.goal_separation == pytest.approx(0.02)
    assert get_setup("dual_ur5").goal_separation == 0.0  # the paper's protocol
    cell = setup.load_cell()
    plain = scenario_set_for(replace(setup, goal_separation=0.0), 83, 5, directory=tmp_path)
    assert plain.indices == (0, 1, 2, 3, 4)
    kept = scenario_set_for(setup, 83, 5, directory=tmp_path)  # the saved plain set is redrawn
    assert kept.indices == (0, 1, 2, 4, 5)
    with CellWorld(cell) as world:

        def separation(goal: dict[str, np.ndarray]) -> float:
            world.set_configuration(goal)
            return world.distance(*cell.arm_ids)

        assert separation(plain.scenarios[3].goal) < 0.01
        assert all(separation(s.goal) >= 0.02 for s in kept.scenarios)
    for i, s in zip(kept.indices[:3], kept.scenarios[:3], strict=True):
        for a in cell.arm_ids:
            np.testing.assert_array_equal(s.goal[a], plain.scenarios[i].goal[a])
    with pytest.raises(InvalidValueError, match="goal_separation"):
        replace(setup, goal_separation=-0.01)
