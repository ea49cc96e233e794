"""Pairs of bigger cells mapped into the trained pair frame; baselines behind the interface."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.baselines.chomp import plan_chomp
from nehmo_core.planning.baselines.naive import NaivePlanner, TrajectoryTracker, retime
from nehmo_core.planning.factory import centralized_trackers, make_planner
from nehmo_core.planning.models.pair_frame import (
    base_yaw_joint,
    inverse_pose,
    match_pair,
    pose_from_matrix,
)
from nehmo_core.planning.models.registry import SHIPPED_PAIRS, ModelRegistry, pair_geometry
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import PlanResult, Telemetry, WithoutValues
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell, load_robot
from nehmo_core.robots.loader import cell_from_dict
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenarios import sample_configuration, sample_scenario, scenario_rng

UR5_PAIR = [("ur5", "ur5", load_cell("dual_ur5").arm("ur5_1").base)]


def test_first_joints_turn_about_the_base_z_axis() -> None:
    assert base_yaw_joint(load_robot("ur5")) == 1.0
    # the Kinova's joint 1 frame is flipped (rpy π)
    assert base_yaw_joint(load_robot("kinova_gen3_6dof")) == -1.0


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


def test_poses_invert_and_round_trip_through_matrices() -> None:
    rng = np.random.default_rng(0)
    for pitch in [*rng.uniform(-3, 3, 20), math.pi / 2, -math.pi / 2]:
        pose = Pose(tuple(rng.normal(size=3)), (rng.uniform(-3, 3), pitch, rng.uniform(-3, 3)))
        np.testing.assert_allclose(
            pose_from_matrix(pose.matrix()).matrix(), pose.matrix(), atol=1e-12
        )
        np.testing.assert_allclose(
            inverse_pose(pose).matrix() @ pose.matrix(), np.eye(4), atol=1e-12
        )


def test_kinova_controlled_pairs_map_into_the_kinova_ur5_frame() -> None:
    """The Kinova (first joint about −z) turned in its cell maps by shifts onto kinova_ur5."""
    import torch

    from nehmo_core.hjr.systems.arm_pairs import make_arm_pair_system

    frame = inverse_pose(load_cell("ur5_kinova").arm("kinova_0").base)  # the UR5 seen from it
    model = [("kinova_gen3_6dof", "ur5", frame)]
    yaw = 0.7  # the UR5's base yaw; the Kinova sits 0.6 m along the UR5's +y, turned by 0.9
    c, s_ = math.cos(yaw), math.sin(yaw)
    cell = cell_from_dict(
        {
            "name": "turned",
            "arms": [
                {"id": "u", "robot": "ur5", "base": {"xyz": [0.3, -0.1, 0], "rpy": [0, 0, yaw]}},
                {
                    "id": "k",
                    "robot": "kinova_gen3_6dof",
                    "base": {
                        "xyz": [0.3 - 0.6 * s_, -0.1 + 0.6 * c, 0],
                        "rpy": [0, 0, yaw - math.pi / 2 + 0.9],
                    },
                },
            ],
        }
    )
    m = match_pair(cell.arm("k"), cell.arm("u"), model)
    assert m is not None and m.model_index == 0
    assert math.isclose(float(np.cos(m.own_shift[0] + 0.9)), 1.0, abs_tol=1e-9)  # s = −1
    assert math.isclose(float(np.cos(m.peer_shift[0] + math.pi / 2)), 1.0, abs_tol=1e-9)
    system = make_arm_pair_system("kinova_ur5")
    rng = np.random.default_rng(0)
    errors = []
    with CellWorld(cell) as world:
        for _ in range(300):
            qk, qu = rng.uniform(-2.2, 2.2, 6), rng.uniform(-np.pi, np.pi, 6)
            world.set_configuration({"k": qk, "u": qu})
            d = world.distance("k", "u", 1.0)
            if d < 0.1:
                x = torch.tensor(m.state(qk, qu)[None], dtype=torch.float32)
                with torch.no_grad():
                    errors.append(abs(float(system.boundary(x)) - d))
    assert len(errors) > 20 and np.mean(errors) < 0.025  # as for the untouched cell


@pytest.mark.parametrize(
    ("cell_name", "expected"),
    [
        ("triple_ur5", ["ur5_ur5", "ur5_ur5_opposite"]),
        ("five_ur5", ["ur5_ur5", "ur5_ur5_diag", "ur5_ur5_opposite"]),
    ],
)
def test_shipped_bc_sym_models_cover_every_pair_of_the_multi_ur5_cells(
    cell_name: str, expected: list[str]
) -> None:
    """Every ordered arm pair maps onto one shipped bc+sym pair model, so nehmo constrains all
    peers; the bc and DeepReach rows have the 0.6 m model only."""
    cell = load_cell(cell_name)
    registry = ModelRegistry()
    assert registry.sources_for("nehmo", cell) == expected
    assert registry.sources_for("nehmo_paper", cell) == expected
    assert registry.sources_for("nehmo_no_sym", cell) == ["ur5_ur5"]
    geometry = [pair_geometry(name) for name in expected]
    for own, peer in itertools.permutations(cell.arms, 2):
        mapping = match_pair(own, peer, geometry)
        assert mapping is not None, (own.arm_id, peer.arm_id)
        gap = np.linalg.norm(np.subtract(own.base.xyz, peer.base.xyz))
        used = geometry[mapping.model_index][2]
        assert np.linalg.norm(used.xyz) == pytest.approx(gap)


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


class _Telemetry(WithoutValues):
    """Wraps a planner and keeps every plan's telemetry."""

    def __init__(self, planner: NehmoPlanner) -> None:
        self.planner = planner
        self.arm_id = planner.arm_id
        self.seen: list[Telemetry] = []

    def reset(self) -> None:
        self.planner.reset()

    def plan(
        self,
        q_self: ArrayLike,
        peers: Mapping[str, ArrayLike],
        q_goal: ArrayLike,
        peer_bounds: Mapping[str, float] | None = None,
    ) -> PlanResult:
        """The wrapped planner's command; it announces nothing, so it hears no bounds."""
        result = self.planner.plan(q_self, peers, q_goal)
        self.seen.append(result.telemetry)
        return result


def test_nehmo_on_both_arms_of_the_ur5_kinova_cell() -> None:
    """Table IV's NeHMO/NeHMO row: each arm plans with its own game (kinova_ur5 for the Kinova)."""
    cell = load_cell("ur5_kinova")
    settings = EpisodeSettings(time_limit=20.0)
    kinds = {"ur5_0": "nehmo", "kinova_0": "nehmo"}
    with CellSimulator(cell, settings.substeps) as sim:
        # scenario 0 of the challenging set (seed 0): the naive planners collide
        scenario = sample_scenario(cell, scenario_rng(0, 0), sim.world)
        naive = {a: NaivePlanner(cell, a) for a in cell.arm_ids}
        assert run_episode(cell, scenario, naive, settings, simulator=sim).outcome == "collision"
        unhurried = PlannerSettings().override(
            {"opt.deadline": 3600.0}
        )  # no solve is cut short on a loaded machine
        planners = build_planners(
            cell, kinds, scenario, 1 / settings.rate, ModelRegistry(), unhurried
        )
        kinova, ur5 = planners["kinova_0"], planners["ur5_0"]
        assert isinstance(kinova, NehmoPlanner) and isinstance(ur5, NehmoPlanner)
        own_model = kinova.models[kinova.pairs["ur5_0"].model_index]
        assert own_model.name == "nehmo_kinova_ur5_bc_sym" and own_model.robot1 == kinova.robot.name
        assert "ur5_kinova" in ur5.models[ur5.pairs["kinova_0"].model_index].name
        watched = {"ur5_0": _Telemetry(ur5), "kinova_0": _Telemetry(kinova)}
        result = run_episode(cell, scenario, watched, settings, kinds=kinds, simulator=sim)
    assert result.outcome != "collision" and not result.collisions
    seen = watched["kinova_0"].seen
    assert seen and all(t.critical_peer == "ur5_0" for t in seen)
    values = np.array([t.min_value for t in seen])
    assert np.all(np.isfinite(values))
    # the first plan saw the start state through kinova_ur5: V(t_plan, (q_kinova, q_ur5))
    x0 = np.concatenate([scenario.start["kinova_0"], scenario.start["ur5_0"]])
    v0, _ = own_model.evaluate(kinova.settings.opt.t_plan, x0[None, :])
    assert values[0] == pytest.approx(float(v0[0]), abs=1e-9)
    assert values.min() > 0.0  # it kept a positive margin on the way


def test_missing_pair_models_are_named() -> None:
    # every pair of shipped robots is modelled at equal mounting heights: a Panda mounted 0.3 m
    # above a Kinova is not
    kinova_panda = cell_from_dict(
        {
            "name": "kinova_panda",
            "arms": [
                {"id": "k0", "robot": "kinova_gen3_6dof"},
                {"id": "p1", "robot": "panda", "base": {"xyz": [0.6, 0, 0.3]}},
            ],
        }
    )
    scenario = sample_scenario(kinova_panda, scenario_rng(0, 0))
    assert ("kinova_gen3_6dof", "ur5") in SHIPPED_PAIRS
    kinds = {"k0": "nehmo", "p1": "naive"}
    with pytest.raises(NehmoError, match=r"'k0'.*\('kinova_gen3_6dof', 'panda'\)") as e:
        build_planners(kinova_panda, kinds, scenario, 0.04, ModelRegistry())
    assert "p1 (panda) 0.60 m away, +0.30 m up" in str(e.value)
    assert "equal mounting height" in str(e.value)
    assert "kinova_ur5" in str(e.value) and "ur5_kinova" in str(e.value)


def test_naive_and_reckless_go_straight_and_clamp() -> None:
    cell = load_cell("ur5_kinova")
    q = np.zeros(6)
    goal = np.array([1.0, -0.02, 0.0, 3.0, -1.0, 0.01])
    for kind in ("naive", "reckless"):
        planner = make_planner(kind, cell, "kinova_0")
        result = planner.plan(q, {"ur5_0": np.zeros(6)}, goal)
        np.testing.assert_allclose(result.velocity, [0.5, -0.2, 0.0, 0.5, -0.5, 0.1])
    wrapped = NaivePlanner(cell, "ur5_0", PlannerSettings().override({"opt.wrap_goal": True}))
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
    # the episode runner's latency: the command planned at tick k acts during tick k + 1
    cell = load_cell("dual_ur5")
    bend = np.array([1.0, 0.5, 0.25, -1.0, 0.0, 0.3])
    path = {"ur5_0": np.array([[0.0] * 6, bend, bend * 0.5]), "ur5_1": np.zeros((3, 6))}
    trajectory = retime(path, 0.5)
    assert trajectory.times[-1] == pytest.approx(3.0)
    tracker = TrajectoryTracker(cell, trajectory, "ur5_0", period=0.1)
    q, acting = np.zeros(6), np.zeros(6)
    for k in range(40):
        # on the shared clock one tick late: every joint where the trajectory was a tick ago
        np.testing.assert_allclose(
            q, trajectory.sample("ur5_0", max(0.0, 0.1 * (k - 1))), atol=1e-9
        )
        u = tracker.plan(q, {}, bend * 0.5).velocity
        assert np.all(np.abs(u) <= 0.5 + 1e-12)
        q, acting = q + 0.1 * acting, u
    np.testing.assert_allclose(q, bend * 0.5, atol=1e-9)


def _colliding_segments(cell: Cell, waypoints: Mapping[str, np.ndarray]) -> list[int]:
    """The segments of a joint path on which the episodes' own collision check (the cell
    simulator, every arm pair and self-collisions at 10 instants per segment, more than CHOMP's
    4) finds a collision; independent of CHOMP's own flag."""
    hits = []
    with CellSimulator(cell, substeps=10) as sim:
        sim.reset({a: w[0] for a, w in waypoints.items()})
        for k in range(len(waypoints[cell.arm_ids[0]]) - 1):
            # one second per segment: far below every joint's velocity limit
            if sim.step({a: w[k + 1] - w[k] for a, w in waypoints.items()}, 1.0).collided:
                hits.append(k)
        end = sim.positions()
    for a, w in waypoints.items():  # the simulator followed the path (no joint limit clamped it)
        np.testing.assert_allclose(end[a], w[-1], atol=1e-9)
    return hits


# seed 5: the straight path is free already; seed 6: it collides, so CHOMP must bend it
@pytest.mark.parametrize("seed", [5, 6])
def test_chomp_plans_all_arms_and_checks_the_result_exactly(seed: int) -> None:
    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(seed))
    s = np.linspace(0.0, 1.0, 101)[:, None]
    straight = {
        a: scenario.start[a] + s * (scenario.goal[a] - scenario.start[a]) for a in cell.arm_ids
    }
    assert bool(_colliding_segments(cell, straight)) == (seed == 6)
    result = plan_chomp(cell, scenario.start, scenario.goal)
    assert result.collision_free
    assert _colliding_segments(cell, result.waypoints) == []  # not only CHOMP's word for it
    for arm in cell.arm_ids:
        w = result.waypoints[arm]
        assert w.shape == (101, 6)
        np.testing.assert_array_equal(w[0], scenario.start[arm])
        # the paper's CHOMP aims at the goal as given: continuous joints are not unwrapped
        np.testing.assert_array_equal(w[-1], scenario.goal[arm])


def test_chomp_unwraps_continuous_joints_only_when_asked() -> None:
    """``wrap_continuous`` (MoveIt's behaviour) aims each continuous joint at the goal's turn
    nearest the start; the default keeps the goal as given, as the paper's baseline does."""
    from nehmo_core.planning.baselines.chomp import ChompSettings

    cell = load_cell("dual_ur5")
    robot = cell.arm("ur5_0").robot
    start = {a: np.zeros(6) for a in cell.arm_ids}
    goal = {a: np.zeros(6) for a in cell.arm_ids}
    goal["ur5_0"] = np.array([5.0, -0.5, 1.0, 0.0, 0.0, -4.0])  # joints 1 and 6 the long way
    quick = ChompSettings(max_iterations=1)
    as_given = plan_chomp(cell, start, goal, quick).waypoints["ur5_0"][-1]
    nearest = plan_chomp(cell, start, goal, replace(quick, wrap_continuous=True))
    end = nearest.waypoints["ur5_0"][-1]
    np.testing.assert_array_equal(as_given, goal["ur5_0"])
    assert robot.continuous.all()
    np.testing.assert_allclose(end, goal["ur5_0"] - np.array([2, 0, 0, 0, 0, -2]) * np.pi)
    assert np.all(np.abs(end - start["ur5_0"]) <= np.pi)


def test_ompl_rrt_connect_finds_a_collision_free_path() -> None:
    from nehmo_core.planning.baselines.ompl import OmplSettings

    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(4))
    trackers, summary = centralized_trackers(
        "ompl", cell, scenario.start, scenario.goal, 0.04, ompl=OmplSettings(time_limit=20.0)
    )
    assert summary["success"]
    q = dict(scenario.start)
    acting = {a: np.zeros(6) for a in cell.arm_ids}  # one tick of latency, as in episodes
    with CellWorld(cell) as world:
        for _ in range(1500):
            cmd = {a: trackers[a].plan(q[a], q, scenario.goal[a]).velocity for a in cell.arm_ids}
            q = {a: q[a] + 0.04 * acting[a] for a in cell.arm_ids}
            acting = cmd
            world.set_configuration(q)
            assert not world.in_collision(self_collision=False)
    for a in cell.arm_ids:
        assert np.abs(cell.arm(a).robot.wrap(q[a] - scenario.goal[a])).max() < 1e-3


def test_ompl_paths_keep_their_clearance_and_endpoints_may_lower_it() -> None:
    from nehmo_core.planning.baselines.ompl import OmplSettings, plan_rrt_connect

    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(4))
    with pytest.raises(InvalidValueError, match="clearance"):
        OmplSettings(clearance=-0.01)
    with CellWorld(cell) as world:

        def closest(q: Mapping[str, np.ndarray]) -> float:
            world.set_configuration(q)
            return min([0.05, *(c.distance for c in world.collisions(margin=0.05))])

        ends = min(closest(scenario.start), closest(scenario.goal))
        for setting in (0.01, 2.0 * ends):  # the second is above an endpoint's distance
            expected = setting if ends >= setting else 0.5 * ends
            result = plan_rrt_connect(
                cell, scenario.start, scenario.goal, OmplSettings(20.0, clearance=setting), world
            )
            assert result.solved
            assert result.clearance == pytest.approx(expected, rel=1e-3)  # PyBullet distances
        path = np.concatenate([result.waypoints[a] for a in cell.arm_ids], axis=1)
        dense = [
            closest({"ur5_0": q[:6], "ur5_1": q[6:]})
            for a, b in itertools.pairwise(path)
            for q in (a + s * (b - a) for s in np.linspace(0.0, 1.0, 11))  # ≤ 0.01 rad apart
        ]
        # checked states keep the clearance; between checks (0.02 rad) a link moves mm at most
        assert min(dense) > 0.5 * result.clearance


def test_one_arm_plans_past_a_frozen_peer_and_names_a_blocked_end() -> None:
    """``plan_arm_alone``: a path from the arm's start to its goal whose states keep the
    clearance from the frozen peer and are free of self-collision; an end that does not is
    named, with nothing searched; a bad clearance is one clear error."""
    from nehmo_core.planning.baselines.ompl import plan_arm_alone

    cell = load_cell("dual_ur5")
    scenario = sample_scenario(cell, np.random.default_rng(4))
    with CellWorld(cell) as world:
        world.set_configuration(scenario.start)
        clearance = 0.5 * min(0.05, world.distance("ur5_0", "ur5_1"))
        path = plan_arm_alone(
            cell, "ur5_0", scenario.start, scenario.goal["ur5_0"], clearance, 10.0, world=world
        )
        assert path.solved and not path.blocked
        np.testing.assert_allclose(path.waypoints[0], scenario.start["ur5_0"])
        np.testing.assert_allclose(path.waypoints[-1], scenario.goal["ur5_0"])
        assert path.length >= np.linalg.norm(scenario.goal["ur5_0"] - scenario.start["ur5_0"])
        world.set_configuration(scenario.start)
        for q in path.waypoints:
            world.set_joint_positions("ur5_0", q)
            assert world.distance("ur5_0", "ur5_1") >= clearance
            assert not world.self_collisions("ur5_0")
        # a goal inside the frozen peer: found by sampling, then named as blocked
        rng = np.random.default_rng(0)
        robot = cell.arm("ur5_0").robot
        for _ in range(2000):
            inside = rng.uniform(robot.lower, robot.upper)
            world.set_joint_positions("ur5_0", inside)
            if world.distance("ur5_0", "ur5_1") < 0.0:
                break
        else:
            pytest.fail("no configuration of ur5_0 inside ur5_1 was sampled")
        blocked = plan_arm_alone(cell, "ur5_0", scenario.start, inside, clearance, world=world)
        assert blocked.blocked == "goal" and not blocked.solved and blocked.length == 0.0
        far = plan_arm_alone(
            cell, "ur5_0", scenario.start, scenario.goal["ur5_0"], 1.0, world=world
        )
        assert far.blocked == "start"  # bases 0.6 m apart: no pose keeps 1 m
    with pytest.raises(InvalidValueError, match="clearance"):
        plan_arm_alone(cell, "ur5_0", scenario.start, scenario.goal["ur5_0"], -0.01)


def test_chomp_check_reports_self_collisions() -> None:
    from nehmo_core.planning.baselines.chomp import _collision_free

    cell = load_cell("dual_ur5")
    robot = cell.arm("ur5_0").robot
    rng = np.random.default_rng(0)
    upright = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])
    with CellWorld(cell) as world:
        low, high = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
        for _ in range(5000):  # ur5_0 folded into itself, clear of an upright ur5_1
            q = rng.uniform(low, high)
            world.set_configuration({"ur5_0": q, "ur5_1": upright})
            hits = world.collisions()
            if hits and all(c.arm_a == c.arm_b == "ur5_0" for c in hits):
                break
        else:
            pytest.fail("no self-colliding configuration found")
        trajs = [np.stack([q, q]), np.stack([upright, upright])]
        assert not world.in_collision(self_collision=False)
        assert not _collision_free(world, cell, trajs, 2)
