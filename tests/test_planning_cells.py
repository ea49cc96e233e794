"""Pairs of bigger cells mapped into the trained pair frame; baselines behind the interface."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.baselines import NaivePlanner, TrajectoryTracker, retime
from nehmo_core.planning.chomp import plan_chomp
from nehmo_core.planning.factory import centralized_trackers, make_planner
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.pair_frame import base_yaw_joint, match_pair
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.synthetic import random_value_function
from nehmo_core.planning.value_model import PairValueModel
from nehmo_core.robots import load_cell
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.sim.scenarios import sample_configuration, sample_scenario

UR5_PAIR = [("ur5", "ur5", load_cell("dual_ur5").arm("ur5_1").base)]


def test_first_joints_turn_about_the_base_z_axis() -> None:
    assert base_yaw_joint("ur5") == 1.0
    assert base_yaw_joint("kinova_gen3_6dof") == -1.0  # its joint 1 frame is flipped (rpy π)


@pytest.mark.parametrize(
    ("own", "peer", "own_shift", "peer_shift"),
    [
        ("ur5_0", "ur5_1", 0.0, 0.0),
        ("ur5_0", "ur5_2", -math.pi, 0.0),
        ("ur5_0", "ur5_3", -math.pi / 2, 0.0),
        ("ur5_0", "ur5_4", math.pi / 2, 0.0),
        ("ur5_2", "ur5_0", 0.0, -math.pi),
        ("ur5_1", "ur5_0", 0.0, 0.0),
    ],
)
def test_five_arm_pairs_map_by_first_joint_shifts(own, peer, own_shift, peer_shift) -> None:
    cell = load_cell("five_ur5")
    m = match_pair(cell.arm(own), cell.arm(peer), UR5_PAIR)
    assert m is not None
    assert math.isclose(float(np.cos(m.own_shift[0] - own_shift)), 1.0, abs_tol=1e-9)
    assert math.isclose(float(np.cos(m.peer_shift[0] - peer_shift)), 1.0, abs_tol=1e-9)
    assert np.all(m.own_shift[1:] == 0) and np.all(m.peer_shift[1:] == 0)


def test_mapped_pairs_have_the_same_exact_distance() -> None:
    """Ground truth: the cell pair and its image in the dual cell are the same geometry, up to
    the base link, which turns with the base but not with the first joint (its mesh is only
    nearly round: a few mm on average, up to ~3 cm measured here)."""
    five, dual = load_cell("five_ur5"), load_cell("dual_ur5")
    rng = np.random.default_rng(0)
    robot = five.arm("ur5_0").robot
    with CellWorld(five) as w5, CellWorld(dual) as w2:
        for own, peer in [("ur5_0", "ur5_2"), ("ur5_0", "ur5_3"), ("ur5_4", "ur5_0")]:
            m = match_pair(five.arm(own), five.arm(peer), UR5_PAIR)
            assert m is not None
            errors = []
            for _ in range(10):
                q1, q2 = sample_configuration(robot, rng), sample_configuration(robot, rng)
                w5.set_configuration({own: q1, peer: q2})
                x = m.state(q1, q2)
                w2.set_configuration({"ur5_0": x[:6], "ur5_1": x[6:]})
                errors.append(abs(w5.distance(own, peer) - w2.distance("ur5_0", "ur5_1")))
            assert max(errors) < 0.04 and np.mean(errors) < 0.006


def test_unmodelled_and_far_peers_are_reported() -> None:
    five = load_cell("five_ur5")
    vf = random_value_function("ur5_ur5", "bc", NetworkSettings(width=16, hidden_layers=1))
    model = PairValueModel.from_value_function(vf, "test_cells_bc", backend="vm")
    outer = NehmoPlanner(five, "ur5_1", [model])
    assert set(outer.pairs) == {"ur5_0"}
    # 0.85 m (ur5_3, ur5_4) and 1.2 m (ur5_2) apart: in reach, and no model fits
    assert set(outer.peers_unmodelled) == {"ur5_2", "ur5_3", "ur5_4"}
    assert outer.peers_skipped == ()
    q = {a: np.zeros(6) for a in five.arm_ids}
    result = outer.plan(q["ur5_1"], q, np.ones(6))
    assert result.telemetry.peers_unmodelled == outer.peers_unmodelled
    far = Cell(
        "far", (five.arm("ur5_0"), ArmSpec("ur5_9", five.arm("ur5_1").robot, Pose((5, 0, 0))))
    )
    lone = NehmoPlanner(far, "ur5_0", [model])
    assert lone.peers_skipped == ("ur5_9",) and not lone.pairs
    result = lone.plan(np.zeros(6), {"ur5_9": np.zeros(6)}, np.full(6, 0.01))
    assert result.telemetry.status == "unconstrained"
    np.testing.assert_allclose(result.velocity, 0.1)


def test_naive_and_reckless_go_straight_and_clamp() -> None:
    cell = load_cell("ur5_kinova")
    q = np.zeros(6)
    goal = np.array([1.0, -0.02, 0.0, 3.0, -1.0, 0.01])
    for kind in ("naive", "reckless"):
        planner = make_planner(kind, cell, "kinova_0")
        result = planner.plan(q, {"ur5_0": np.zeros(6)}, goal)
        np.testing.assert_allclose(result.velocity, [0.5, -0.2, 0.0, 0.5, -0.5, 0.1])
    wrapped = NaivePlanner(cell, "ur5_0", PlannerSettings(wrap_goal=True))
    assert wrapped.plan(np.zeros(6), {}, np.array([6.0, 0, 0, 0, 0, 0])).velocity[0] < 0


def test_factory_rejects_unknown_and_centralized_kinds() -> None:
    cell = load_cell("dual_ur5")
    with pytest.raises(UnknownNameError, match="nehmo"):
        make_planner("rrt", cell, "ur5_0")
    with pytest.raises(InvalidValueError, match="`kind`"):
        make_planner("chomp", cell, "ur5_0")
    with pytest.raises(InvalidValueError, match="`models`"):
        make_planner("nehmo", cell, "ur5_0")


def test_tracker_follows_a_retimed_trajectory_within_the_speed_bound() -> None:
    cell = load_cell("dual_ur5")
    path = {"ur5_0": np.array([[0.0] * 6, [1.0] * 6]), "ur5_1": np.zeros((2, 6))}
    trajectory = retime(path, 0.5)
    assert trajectory.times[-1] == pytest.approx(2.0)
    tracker = TrajectoryTracker(cell, trajectory, "ur5_0", period=0.1)
    q = np.zeros(6)
    for _ in range(25):
        u = tracker.plan(q, {}, np.ones(6)).velocity
        assert np.all(np.abs(u) <= 0.5 + 1e-12)
        q = q + 0.1 * u
    np.testing.assert_allclose(q, 1.0, atol=1e-9)


def test_chomp_plans_all_arms_and_checks_the_result_exactly() -> None:
    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(5))
    result = plan_chomp(cell, scenario.start, scenario.goal)
    assert result.collision_free
    for arm in cell.arm_ids:
        w = result.waypoints[arm]
        assert w.shape == (101, 6)
        np.testing.assert_array_equal(w[0], scenario.start[arm])
        err = cell.arm(arm).robot.wrap(w[-1] - scenario.goal[arm])
        np.testing.assert_allclose(err, 0.0, atol=1e-12)


def test_ompl_rrt_connect_finds_a_collision_free_path() -> None:
    pytest.importorskip("ompl")
    from nehmo_core.planning.ompl_planner import OmplSettings

    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(4))
    trackers, summary = centralized_trackers(
        "ompl", cell, scenario.start, scenario.goal, 0.04, ompl=OmplSettings(time_limit=20.0)
    )
    assert summary["success"]
    q = dict(scenario.start)
    with CellWorld(cell) as world:
        for _ in range(1500):
            cmd = {a: trackers[a].plan(q[a], q, scenario.goal[a]).velocity for a in cell.arm_ids}
            q = {a: q[a] + 0.04 * cmd[a] for a in cell.arm_ids}
            world.set_configuration(q)
            assert not world.in_collision(self_collision=False)
    for a in cell.arm_ids:
        assert np.abs(cell.arm(a).robot.wrap(q[a] - scenario.goal[a])).max() < 1e-3
