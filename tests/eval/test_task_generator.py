"""Generated task files (Ha et al.'s base-placement protocol): the rules, the file format, the
seeds, the command line, and ``nehmo evaluate --tasks`` on them."""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from nehmo_core.cli import main as nehmo_main
from nehmo_core.errors import NehmoError
from nehmo_core.eval.cli import main as evaluate_main
from nehmo_core.eval.ha_tasks import HaTask, check_joint_convention, load_task, load_tasks
from nehmo_core.eval.task_generator import (
    BASE_MAX_DISTANCE,
    BASE_MIN_DISTANCE,
    WORKSPACE_RADIUS,
    TaskGenerator,
    TaskSpec,
    ha_difficulty,
    hemisphere_point,
    sample_bases,
    task_rng,
    write_tasks,
)
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import ROBOT_NAMES
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.robots.registry import HA_BENCHMARK_ROBOT
from nehmo_core.sim.scenarios import goal_error, sampling_box

HA_TASKS = Path(__file__).parents[1] / "data" / "ha_tasks"
SPEC = TaskSpec(3, clearance=0.05, min_goal_distance=1.0)  # stricter than the defaults


@pytest.fixture(scope="module")
def three_arm_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("gen3")
    write_tasks(SPEC, seed=7, count=3, out=out)
    return out


@pytest.fixture(scope="module")
def three_arm_tasks(three_arm_dir: Path) -> list[HaTask]:
    return load_tasks(three_arm_dir)


def _check_base_rules(xy: np.ndarray) -> None:
    """Every base >= 0.3 m from all others and within 1.0 m of at least one other."""
    d = np.linalg.norm(xy[:, None] - xy[None], axis=2)
    np.fill_diagonal(d, np.inf)
    assert d.min() >= BASE_MIN_DISTANCE
    if len(xy) > 1:
        assert (d.min(axis=1) <= BASE_MAX_DISTANCE).all()


def test_generated_files_load_and_pass_the_joint_convention(
    three_arm_dir: Path, three_arm_tasks: list[HaTask]
) -> None:
    names = sorted(p.name for p in three_arm_dir.glob("*.json"))
    assert names == [f"gen_3arm_s7_{k:03d}.json" for k in range(3)]
    for task in three_arm_tasks:
        assert task.task_id == task.path.stem and task.arm_count == 3
        assert check_joint_convention(task) < 1e-9
        assert task.obstacles == () and 0.0 <= (task.difficulty or 0.0) <= 1.0
        raw = json.loads(task.path.read_text())
        assert raw["start_goal_config"] is None and raw["robot"] == HA_BENCHMARK_ROBOT
        assert raw["generator"]["clearance"] == SPEC.clearance
        assert raw["difficulty"] == pytest.approx(ha_difficulty([b[0] for b in raw["base_poses"]]))
        for arm, (xyz, quat) in zip(task.cell.arms, raw["base_poses"], strict=True):
            assert xyz[2] == 0.0 and quat[:2] == [0.0, 0.0]  # table-mounted, yaw only
            assert arm.base.xyz == pytest.approx(xyz)
            assert np.cos(arm.base.yaw - 2 * np.arctan2(quat[2], quat[3])) == pytest.approx(1.0)
        assert task.cell.arms[0].base.xyz == (0.0, 0.0, 0.0)
        _check_base_rules(np.array([a.base.xyz[:2] for a in task.cell.arms]))


@pytest.mark.parametrize("arms", [3, 8])
def test_base_rules_hold(arms: int) -> None:
    yaws = []
    for k in range(40):
        bases = sample_bases(arms, task_rng(0, arms, k))
        assert len(bases) == arms and bases[0].xyz == (0.0, 0.0, 0.0)
        assert all(b.xyz[2] == 0.0 and b.rpy[:2] == (0.0, 0.0) for b in bases)
        _check_base_rules(np.array([b.xyz[:2] for b in bases]))
        yaws += [b.yaw for b in bases]
    assert min(yaws) >= 0 and max(yaws) < 2 * np.pi and np.std(yaws) > 1.0  # yaw is random


def test_starts_and_goals_keep_the_clearance_checked_independently(
    three_arm_tasks: list[HaTask],
) -> None:
    for task in three_arm_tasks:
        with CellWorld(task.cell) as world:
            for q in (task.scenario.start, task.scenario.goal):
                world.set_configuration(q)
                assert not world.in_collision(), task.task_id  # arm pairs and self
                for a, b in itertools.combinations(task.cell.arm_ids, 2):
                    assert world.distance(a, b) >= SPEC.clearance, (task.task_id, a, b)


def test_goals_are_far_from_starts_and_inside_the_sampling_box(
    three_arm_tasks: list[HaTask],
) -> None:
    for task in three_arm_tasks:
        for arm in task.cell.arms:
            start, goal = task.scenario.start[arm.arm_id], task.scenario.goal[arm.arm_id]
            assert np.linalg.norm(goal_error(goal, start, arm.robot)) >= SPEC.min_goal_distance
            box = sampling_box(arm.robot)
            for q in (start, goal):  # drawn in the box, then wrapped (the UR5's joint 1)
                turns = [q + k * 2 * np.pi for k in (-1, 0, 1)]
                assert np.any([(t >= box[:, 0]) & (t <= box[:, 1]) for t in turns], axis=0).all()


def test_hemisphere_points_are_drawn_as_theirs() -> None:
    rng = np.random.default_rng(0)
    p = np.array([hemisphere_point(rng) for _ in range(4000)])
    r = np.linalg.norm(p, axis=1)
    assert r.max() <= WORKSPACE_RADIUS and p[:, 2].min() >= 0.0
    assert r.mean() / WORKSPACE_RADIUS == pytest.approx(2 / 3, abs=0.02)  # E[sqrt(u)]
    azimuth = np.arctan2(p[:, 1], p[:, 0])
    assert np.histogram(azimuth, bins=4)[0].min() > 900  # uniform around the base


def test_ik_configurations_keep_the_rules_and_look_like_their_files(tmp_path: Path) -> None:
    spec = TaskSpec(3, clearance=0.03, configs="ik")
    tasks = [load_task(p) for p in write_tasks(spec, seed=3, count=3, out=tmp_path)]
    ours = []
    for task in tasks:
        assert json.loads(task.path.read_text())["generator"]["configs"] == "ik"
        assert check_joint_convention(task) < 1e-9
        with CellWorld(task.cell) as world:
            for q in (task.scenario.start, task.scenario.goal):
                world.set_configuration(q)
                assert not world.in_collision(), task.task_id
                for a, b in itertools.combinations(task.cell.arm_ids, 2):
                    assert world.distance(a, b) >= spec.clearance
                for arm in task.cell.arms:
                    tip = world.link_world_positions(arm.arm_id)[arm.robot.tip_link]
                    assert np.linalg.norm(tip - np.array(arm.base.xyz)) < WORKSPACE_RADIUS + 0.05
        for arm in task.cell.arms:
            start, goal = task.scenario.start[arm.arm_id], task.scenario.goal[arm.arm_id]
            assert np.linalg.norm(goal_error(goal, start, arm.robot)) >= spec.min_goal_distance
            for q in (start, goal):
                assert (q >= arm.robot.lower).all() and (q <= arm.robot.upper).all()
                ours.append(q)
    # their files: the elbow on the side of their home posture, the last joint never turned
    theirs = np.concatenate(
        [
            np.array(json.loads(p.read_text())[k])
            for p in sorted(HA_TASKS.glob("*.json"))
            for k in ("start_config", "goal_config")
        ]
    )
    for q in (theirs, np.array(ours)):
        assert (q[:, 2] > 0).all() and np.abs(q[:, 5]).max() < 1e-3


@pytest.mark.parametrize("robot", [r for r in ROBOT_NAMES if r != HA_BENCHMARK_ROBOT])
def test_ik_configurations_of_other_robots_start_inside_their_limits(robot: str) -> None:
    with TaskGenerator(TaskSpec(2, robot=robot, configs="ik")) as generator:
        raw = generator.generate(0, 0)
        lower, upper = generator.robot.lower, generator.robot.upper
    for q in (*raw["start_config"], *raw["goal_config"]):
        q = np.array(q)
        assert np.isfinite(q).all() and (q >= lower).all() and (q <= upper).all()
    assert raw["generator"]["configs"] == "ik" and raw["robot"] == robot


def test_same_seed_same_files_other_seed_other_files(tmp_path: Path) -> None:
    spec = TaskSpec(2)
    a, b, c = (write_tasks(spec, s, 2, tmp_path / f"{s}_{i}") for i, s in enumerate((4, 4, 5)))
    assert [p.read_bytes() for p in a] == [p.read_bytes() for p in b]
    assert [p.name for p in c] == ["gen_2arm_s5_000.json", "gen_2arm_s5_001.json"]
    for p, q in zip(a, c, strict=True):
        assert (
            json.loads(p.read_text())["start_config"] != json.loads(q.read_text())["start_config"]
        )
    # task k does not depend on how many tasks were asked for
    with TaskGenerator(spec) as generator:
        assert json.dumps(generator.generate(4, 1), indent=1) + "\n" == a[1].read_text()


def test_their_difficulty_score_is_reproduced() -> None:
    for name in ("135003", "135006", "135011"):  # 1, 4 and 2 arms
        raw = json.loads((HA_TASKS / f"{name}.json").read_text())
        ours = ha_difficulty([b[0] for b in raw["base_poses"]])
        assert ours == pytest.approx(raw["difficulty"], abs=2e-3), name


def test_another_robot_gets_its_tip_pose_self_collision_checks_and_no_difficulty() -> None:
    other = next(r for r in ROBOT_NAMES if r != HA_BENCHMARK_ROBOT)  # draws self-collide at times
    with TaskGenerator(TaskSpec(2, robot=other)) as generator:
        tasks = [generator.generate(1, k) for k in range(12)]
        robot = generator.robot
    for data in tasks:
        assert data["robot"] == other and data["difficulty"] is None
        arms = []
        for i, ((xyz, quat), (target, _), q) in enumerate(
            zip(data["base_poses"], data["target_eff_poses"], data["goal_config"], strict=True)
        ):
            base = Pose(tuple(xyz), (0.0, 0.0, float(2 * np.arctan2(quat[2], quat[3]))))
            arms.append(ArmSpec(f"arm{i}", robot, base))
            with torch.no_grad():
                q_t = torch.tensor([q], dtype=torch.float64)
                tip = ArmKinematics(robot, base).link_transforms(q_t)[robot.tip_link][0]
            assert np.allclose(tip[:3, 3].numpy(), target, atol=1e-9)  # no tool offset
        with CellWorld(Cell(data["id"], tuple(arms))) as world:
            for configs in (data["start_config"], data["goal_config"]):
                world.set_configuration({a.arm_id: q for a, q in zip(arms, configs, strict=True)})
                assert not world.in_collision(), data["id"]
                assert world.distance("arm0", "arm1") >= TaskSpec.clearance


def test_an_impossible_request_fails_with_what_to_relax() -> None:
    spec = TaskSpec(2, min_goal_distance=100.0, arm_tries=5, restarts=2, layouts=2)
    with (
        TaskGenerator(spec) as generator,
        pytest.raises(NehmoError, match="no collision-free goal"),
    ):
        generator.generate(0, 0)


@pytest.mark.parametrize(
    ("args", "option"),
    [
        (["--arms", "0"], "--arms"),
        (["--arms", "2", "--count", "0"], "--count"),
        (["--arms", "2", "--robot", "no_such_robot"], "--robot"),
        (["--arms", "2", "--seed", "-1"], "--seed"),
        (["--arms", "2", "--clearance", "-0.1"], "--clearance"),
        (["--arms", "2", "--min-goal-distance", "inf"], "--min-goal-distance"),
        (["--arms", "2", "--out", "{file}"], "--out"),
        (["--arms", "2", "--configs", "joints"], "--configs"),
        (["--arms", "2", "--out", "{file}/sub"], "--out"),
        (["--arms", "2", "--count", "1", "--min-goal-distance", "100"], "minimum goal distance"),
    ],
)
def test_bad_input_gives_one_line_naming_the_parameter(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], option: str
) -> None:
    afile = tmp_path / "a_file"
    afile.write_text("")
    argv = ["tasks", "generate", "--no-progress", "--out", str(tmp_path / "out")]
    argv += [a.format(file=afile) for a in args]
    assert nehmo_main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nehmo tasks: error:") and option in lines[0]
    assert not list(tmp_path.rglob("*.json"))


def test_generated_tasks_run_under_evaluate(tmp_path: Path) -> None:
    tasks, out = tmp_path / "tasks", tmp_path / "out"
    argv = ["tasks", "generate", "--arms", "2", "--count", "2", "--seed", "3", "--out", str(tasks)]
    assert nehmo_main([*argv, "--no-progress"]) == 0
    assert [t.task_id for t in load_tasks(tasks)] == ["gen_2arm_s3_000", "gen_2arm_s3_001"]
    assert load_task(tasks / "gen_2arm_s3_000.json").arm_count == 2
    code = evaluate_main(
        ["--tasks", str(tasks), "--planners", "naive", "--out", str(out), "--no-progress"]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped"] == []
    (row,) = summary["rows"]
    assert row["row"] == "naive" and row["ours"]["episodes"] == 2
    assert set(row["by_arms"]) == {"2"} and row["ours"]["errors"] == 0
