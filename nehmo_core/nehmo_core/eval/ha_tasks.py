"""Ha et al.'s multi-arm benchmark tasks (CoRL 2020) as cells and scenarios.

A task file (JSON) holds, per arm, a base pose ``[[x, y, z], [qx, qy, qz, qw]]`` [m] in the world
frame, a start and a goal joint vector of a UR5 (URDF joint order; the registry's
:data:`~nehmo_core.robots.registry.HA_BENCHMARK_ROBOT`) and the goal pose of their end effector
(flange plus gripper). :func:`load_task` turns one into a :class:`HaTask`: a
:class:`~nehmo_core.robots.model.Cell` with one UR5 per base pose (``ur5_0`` …) and a
:class:`~nehmo_core.sim.scenarios.Scenario`.

Their joint convention is checked, not assumed: :func:`check_joint_convention` runs our forward
kinematics on the goal configuration and requires their goal end-effector pose to sit at one
fixed offset from our ``ee_link`` (their tool tip lies :data:`TOOL_OFFSET` along ``ee_link``'s
x axis, with the same orientation) in every arm of every task.

Tasks with obstacles are loaded but flagged (:attr:`HaTask.obstacles`): the planners model arms
only, so the runner lists and skips them.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from nehmo_core.errors import InvalidValueError, ModelFileError
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.robots.registry import HA_BENCHMARK_ROBOT
from nehmo_core.sim.scenarios import Scenario

__all__ = [
    "TOOL_OFFSET",
    "HaTask",
    "check_joint_convention",
    "load_task",
    "load_tasks",
    "pair_distances",
]

TOOL_OFFSET = 0.0477
"""[m] their end-effector target lies this far along our ``ee_link``'s x axis (same frame
orientation); measured on the shipped task files by :func:`check_joint_convention`."""
CONVENTION_TOL = 2e-3  # [m] and [rad]


@dataclass(frozen=True)
class HaTask:
    """One benchmark task: its id, cell, start/goal scenario and what else the file says."""

    task_id: str
    path: Path
    cell: Cell
    scenario: Scenario
    targets: tuple[np.ndarray, ...]  # per arm, their goal tool pose (4, 4) in the world
    obstacles: tuple[dict[str, Any], ...]
    difficulty: float | None

    @property
    def arm_count(self) -> int:
        return len(self.cell.arms)


def _require(data: dict[str, Any], key: str, path: Path) -> Any:
    if key not in data:
        raise ModelFileError(f"{path}: task file has no {key!r} entry")
    return data[key]


def _base_pose(entry: Any, path: Path, index: int) -> Pose:
    try:
        xyz, quat = (np.asarray(v, dtype=np.float64) for v in entry)
    except (TypeError, ValueError):
        raise InvalidValueError(
            f"{path.name}: base_poses[{index}]", "must be [[x, y, z], [qx, qy, qz, qw]]", entry
        ) from None
    if xyz.shape != (3,) or quat.shape != (4,) or not np.isclose(np.linalg.norm(quat), 1, 1e-3):
        raise InvalidValueError(
            f"{path.name}: base_poses[{index}]", "must be [[x, y, z], unit [qx, qy, qz, qw]]", entry
        )
    roll, pitch, yaw = Rotation.from_quat(quat).as_euler("xyz")  # fixed axes, as Pose
    return Pose((float(xyz[0]), float(xyz[1]), float(xyz[2])), (roll, pitch, yaw))


def _tool_pose(entry: Any) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(entry[1]).as_matrix()
    T[:3, 3] = entry[0]
    return T


def load_task(path: str | Path) -> HaTask:
    """Read one task file; bad entries raise with the file, the entry and the rule."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ModelFileError(f"{path}: cannot read task file ({exc})") from None
    bases = _require(data, "base_poses", path)
    starts = _require(data, "start_config", path)
    goals = _require(data, "goal_config", path)
    if not bases or not len(bases) == len(starts) == len(goals):
        raise InvalidValueError(
            f"{path.name}: base_poses/start_config/goal_config",
            "must list the same (non-zero) number of arms",
            [len(bases), len(starts), len(goals)],
        )
    robot = load_robot(HA_BENCHMARK_ROBOT)
    arms, start, goal = [], {}, {}
    for i, (base, q0, q1) in enumerate(zip(bases, starts, goals, strict=True)):
        arm_id = f"{robot.name}_{i}"
        arms.append(ArmSpec(arm_id, robot, _base_pose(base, path, i)))
        start[arm_id] = robot.check_q(q0, f"{path.name}: start_config[{i}]")
        goal[arm_id] = robot.check_q(q1, f"{path.name}: goal_config[{i}]")
    targets = tuple(_tool_pose(t) for t in data.get("target_eff_poses") or ())
    task_id = str(data.get("id", path.stem))
    difficulty = data.get("difficulty")
    return HaTask(
        task_id=task_id,
        path=path,
        cell=Cell(f"ha_{task_id}", tuple(arms)),
        scenario=Scenario(start, goal),
        targets=targets,
        obstacles=tuple(data.get("obstacles") or ()),
        difficulty=None if difficulty is None else float(difficulty),
    )


def load_tasks(directory: str | Path) -> list[HaTask]:
    """Every ``*.json`` task of ``directory`` (sorted by file name)."""
    folder = Path(directory)
    if not folder.is_dir():
        raise InvalidValueError("--tasks", "must be a directory of task JSON files", str(folder))
    files = sorted(folder.glob("*.json"))
    if not files:
        raise InvalidValueError("--tasks", "must hold at least one *.json task file", str(folder))
    return [load_task(f) for f in files]


def tool_offsets(task: HaTask) -> np.ndarray:
    """Per arm ``(dx, dy, dz, rx, ry, rz)``: their goal tool pose in our goal ``ee_link`` frame
    ([m], rotation vector [rad])."""
    out = []
    for arm, target in zip(task.cell.arms, task.targets, strict=True):
        kin = ArmKinematics(arm.robot, arm.base)
        q = torch.from_numpy(np.asarray(task.scenario.goal[arm.arm_id], np.float64)[None])
        with torch.no_grad():
            ee = kin.link_transforms(q)["ee_link"][0].double().numpy()
        rel = np.linalg.inv(ee) @ target
        out.append(np.concatenate([rel[:3, 3], Rotation.from_matrix(rel[:3, :3]).as_rotvec()]))
    return np.array(out).reshape(-1, 6)


def check_joint_convention(task: HaTask) -> float:
    """Largest deviation of ``task``'s goal tool poses from ``TOOL_OFFSET`` along our
    ``ee_link`` x axis ([m] or [rad]); raises if it exceeds :data:`CONVENTION_TOL`."""
    if not task.targets:
        return 0.0
    if len(task.targets) != task.arm_count:
        raise InvalidValueError(
            f"{task.path.name}: target_eff_poses", f"must hold {task.arm_count} poses", "…"
        )
    expected = np.array([TOOL_OFFSET, 0, 0, 0, 0, 0])
    worst = float(np.abs(tool_offsets(task) - expected).max())
    if worst > CONVENTION_TOL:
        raise InvalidValueError(
            f"{task.path.name}: goal_config",
            "must put our UR5's ee_link where the file's target_eff_poses say (joint order "
            f"shoulder_pan … wrist_3, tool {TOOL_OFFSET} m along ee_link x); largest deviation",
            round(worst, 4),
        )
    return worst


def pair_distances(cell: Cell) -> list[float]:
    """Horizontal base distance [m] of every pair of arms of ``cell``."""
    out = []
    for a, b in cell.pairs():
        pa, pb = cell.arm(a).base.xyz, cell.arm(b).base.xyz
        out.append(math.hypot(pa[0] - pb[0], pa[1] - pb[1]))
    return out
