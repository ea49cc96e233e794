"""The joint-limit stage: no command drives a joint past its limit, so the stages after it check
the step the arm takes (a Panda's hand once grazed its base because they did not)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.pipeline import read_tick
from nehmo_core.planning.opt.tick import NO_PEERS
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.sim.scenario_files import load_scenario_set

DATA = Path(__file__).resolve().parents[1] / "data" / "self_contact"


def _one_panda(settings: PlannerSettings | None = None) -> NehmoPlanner:
    cell = Cell("one_panda", (ArmSpec("panda_0", load_robot("panda"), Pose()),))
    return NehmoPlanner(cell, "panda_0", [], settings or PlannerSettings())


def test_a_joint_stops_at_its_limit_and_is_never_pushed() -> None:
    planner = _one_panda()
    stage = planner.stage("joint_limits")
    robot, dt = planner.robot, planner.settings.opt.tick
    q = np.clip(np.zeros(7), robot.lower, robot.upper)
    q[1] = robot.lower[1]  # joint 2 at its lower limit
    q[3] = robot.upper[3] - 0.005  # joint 4 half a centimetre-radian below its upper one
    tick = read_tick(planner, q, {}, q, {}, None)
    u = np.array([0.3, -0.5, 0.2, 0.5, -0.1, 0.4, -0.5])
    out = stage.filter(tick, NO_PEERS, u)
    assert out[1] == 0.0  # no further past the limit
    assert out[3] == pytest.approx(0.005 / dt)  # only as far as the limit
    np.testing.assert_array_equal(np.delete(out, [1, 3]), np.delete(u, [1, 3]))
    inward = np.array([0.0, 0.5, 0.0, -0.5, 0.0, 0.0, 0.0])
    np.testing.assert_array_equal(stage.filter(tick, NO_PEERS, inward), inward)
    assert stage.shortened == 1
    # from where the command in flight leaves the arm: past the limit already, a stop
    planner.commanded(np.array([0.0, 0.0, 0.0, 0.5, 0.0, 0.0, 0.0]))
    assert stage.filter(tick, NO_PEERS, u)[3] == 0.0
    planner.close()


def test_joints_that_wrap_are_left_alone() -> None:
    """Every UR5 joint wraps (its range is a full turn or more): nothing is clipped."""
    cell = Cell("one_ur5", (ArmSpec("ur5_0", load_robot("ur5"), Pose()),))
    planner = NehmoPlanner(cell, "ur5_0", [], PlannerSettings())
    assert planner.robot.continuous.all()
    q = np.full(6, 3.1)
    tick = read_tick(planner, q, {}, q, {}, None)
    u = np.full(6, 0.5)
    np.testing.assert_array_equal(planner.stage("joint_limits").filter(tick, NO_PEERS, u), u)
    planner.close()


def _dual_panda_scenario_14(settings: PlannerSettings) -> list:
    """``dual_panda`` seed 60, scenario 14: ``panda_0``'s fail-safe held joint 2 at its lower
    limit while the hand swung toward the base."""
    scenario = load_scenario_set(DATA / "dual_panda_seed60_head15.json").scenarios[14]
    cell = load_cell("dual_panda")
    kinds = {a: "nehmo" for a in cell.arm_ids}
    planners = build_planners(cell, kinds, scenario, 0.04, ModelRegistry(), settings)
    result = run_episode(cell, scenario, planners, EpisodeSettings(time_limit=7.0))
    return list(result.collisions)


def test_the_panda_hand_keeps_off_its_base_at_a_joint_limit() -> None:
    settings = PlannerSettings().override({"opt.deadline": 3600.0})
    assert not _dual_panda_scenario_14(settings)
    # the fail-safe that drove joint 2 into its limit is the paper's, every joint at full speed
    # (the default deadband keeps that joint still here): with it, the stage keeps the hand off
    # the base; without the stage the self-clearance check predicts a joint-2 motion the arm
    # never makes (with the Panda models of 2026-11-29: the hand grazes the base at 5.76 s)
    sweep = settings.override({"fail_safe.deadband": 0.0})
    assert not _dual_panda_scenario_14(sweep)
    off = _dual_panda_scenario_14(sweep.override({"joint_limits.enabled": False}))
    assert any(c.arm_a == c.arm_b == "panda_0" for c in off)


def test_the_stage_is_off_in_the_paper_preset() -> None:
    planner = _one_panda(PlannerSettings.preset("paper"))
    assert "joint_limits" not in {s.name for s in planner.stages}
    planner.close()


def test_opt_gets_the_limits_as_rows() -> None:
    """A joint within a step of its limit gets a row Opt keeps (so no step is clipped after
    the solve, which the other rows did not see); standing still keeps every row."""
    planner = _one_panda()
    stage = planner.stage("joint_limits")
    robot = planner.robot
    q = np.clip(np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0]), robot.lower, robot.upper)
    q[1] = robot.lower[1]  # joint 2 at its lower limit
    q[3] = robot.upper[3] - 0.01  # joint 4 a centiradian below its upper one
    rows = stage.rows(q)
    assert rows.count == 2 and rows.satisfied(np.zeros(7))
    step = planner.settings.opt.t_plan * planner.settings.opt.u_max
    assert not rows.satisfied(np.eye(7)[3] * step)  # a full step past joint 4's limit
    assert not rows.satisfied(-np.eye(7)[1] * 0.001)  # any step below joint 2's
    goal = q + np.array([0.3, -0.3, 0.3, 0.3, 0.0, 0.0, 0.0])  # beyond both limits
    u = planner.plan(q, {}, goal).velocity
    y = planner.settings.opt.t_plan * u
    assert y[1] >= -1e-9 and y[3] <= 0.01 + 1e-9
    assert y[0] == pytest.approx(step)  # the free joints go at full speed
    planner.close()
