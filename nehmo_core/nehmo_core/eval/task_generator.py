"""Task files after Ha et al.'s base-placement protocol, for any number of arms and any robot.

``nehmo tasks generate --arms 3 --count 20 --seed 0 --out DIR`` (:mod:`.task_generator_cli`)
writes task files in the format of Ha et al.'s multi-arm benchmark (CoRL 2020), which
:mod:`nehmo_core.eval.ha_tasks` reads and ``nehmo evaluate --tasks DIR`` runs. The rules:

* Bases, with their limits (0.3 m and 1.0 m between bases): the first at the origin; each next one
  drawn uniformly in the 1.0 m disc around a uniformly chosen earlier base and kept when it is at
  least 0.3 m from every earlier base (up to :data:`BASE_TRIES` draws per base). So every base is
  >= 0.3 m from all others and within 1.0 m of at least one. Yaw uniform in [0, 2π); every base
  table-mounted at z = 0. (Their own sampler chains each base to the previous one by an offset
  uniform in ±1.0 m per axis and redraws the layout when a pair is closer than 0.3 m.)
* Start, then goal, drawn arm by arm: each arm (``configs="uniform"``, the default) uniform in
  the robot's scenario sampling box (:func:`~nehmo_core.sim.scenarios.sampling_box`), or
  (``configs="ik"``, as Ha et al.'s code draws them) PyBullet's inverse kinematics for the
  robot's tip link, started from :data:`HOME` (for a robot it does not list, the middle of the
  joint limits, 0 for a joint that wraps), toward a point drawn as they draw it in the
  hemisphere of radius :data:`WORKSPACE_RADIUS` around the base, the solution kept only within
  the joint limits; either way kept when it is free of self-collision
  (:class:`~nehmo_core.geometry.pybullet_world.CellWorld`'s rule) and at least ``clearance``
  (default 0.02 m, signed PyBullet distance) from every arm placed before it; a goal must also
  lie at least ``min_goal_distance`` (default 0.5 rad, L2 norm of the wrapped joint differences)
  from the arm's start. An arm that finds no draw in ``arm_tries`` starts the configuration over
  (up to ``restarts`` times); a layout without a start or a goal is redrawn (up to ``layouts``
  times); then :class:`~nehmo_core.errors.NehmoError` names the task and what to relax.
* Task ``k`` of seed ``s`` with ``n`` arms draws everything from ``default_rng([s, n, k])`` (same
  arguments, same file) and is named ``gen_{n}arm_s{s}_{k:03d}``.
* The file: ``base_poses``, ``start_config``, ``goal_config``, ``target_eff_poses`` (forward
  kinematics of the goal: for the benchmark robot their tool, ``TOOL_OFFSET`` along ``ee_link``'s
  x axis, so :func:`~nehmo_core.eval.ha_tasks.check_joint_convention` passes; for another robot
  its tip link), ``start_goal_config`` null, ``obstacles`` [], ``difficulty`` (their score,
  :func:`ha_difficulty`, for the benchmark robot; null otherwise), ``id``, and ``robot`` and
  ``generator`` (the parameters), which their loader and ours ignore. ``load_task`` reads every
  file as the benchmark robot, so only its tasks run under ``nehmo evaluate --tasks`` (another
  robot's are rejected there, by the joint count or the joint-convention check).
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pybullet as pb
import torch
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval.ha_tasks import TOOL_OFFSET
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.descriptions import robot_names
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.robots.registry import HA_BENCHMARK_ROBOT
from nehmo_core.sim.scenarios import goal_error, sample_configuration

__all__ = [
    "BASE_MAX_DISTANCE",
    "BASE_MIN_DISTANCE",
    "TaskGenerator",
    "TaskSpec",
    "ha_difficulty",
    "hemisphere_point",
    "sample_bases",
    "task_id",
    "task_rng",
    "write_tasks",
]

BASE_MIN_DISTANCE = 0.3  # [m] every base at least this far from all others (Ha et al.)
BASE_MAX_DISTANCE = 1.0  # [m] every new base within this of an earlier one (Ha et al.)
BASE_HEIGHT = 0.0  # [m] table-mounted
BASE_TRIES = 1000  # draws per base
WORKSPACE_RADIUS = 0.85  # [m] their UR5's workspace hemisphere (ik targets, difficulty)
DIFFICULTY_STEP = 0.05  # [m] their grid
CONFIGS = ("uniform", "ik")  # how a start or goal is drawn
HOME = {HA_BENCHMARK_ROBOT: (-math.pi, -math.pi / 2, math.pi / 2, -math.pi / 2, -math.pi / 2, 0.0)}
"""Their inverse kinematics' start posture, per robot [rad] (their UR5's home)."""


@dataclass(frozen=True)
class TaskSpec:
    """What to generate: arm count, robot, the clearances, and the bounds of the search."""

    arms: int
    robot: str = HA_BENCHMARK_ROBOT
    clearance: float = 0.02  # [m] between every pair of arms, at start and at goal
    min_goal_distance: float = 0.5  # [rad] each arm's goal from its start (L2, wrapped)
    arm_tries: int = 100  # draws per arm before the configuration starts over
    restarts: int = 50  # configurations tried per base layout
    layouts: int = 3  # base layouts tried per task
    configs: str = "uniform"  # how each start and goal is drawn (CONFIGS)

    def __post_init__(self) -> None:
        if self.arms < 1:
            raise InvalidValueError("arms", "must be >= 1", self.arms)
        if self.robot not in robot_names():
            raise InvalidValueError(
                "robot", f"must be a registered robot {list(robot_names())}", self.robot
            )
        for name in ("clearance", "min_goal_distance"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise InvalidValueError(name, "must be a finite number >= 0", value)
        if self.configs not in CONFIGS:
            raise InvalidValueError("configs", f"must be one of {list(CONFIGS)}", self.configs)
        for name in ("arm_tries", "restarts", "layouts"):
            if getattr(self, name) < 1:
                raise InvalidValueError(name, "must be >= 1", getattr(self, name))


def task_id(arms: int, seed: int, index: int) -> str:
    return f"gen_{arms}arm_s{seed}_{index:03d}"


def task_rng(seed: int, arms: int, index: int) -> np.random.Generator:
    """The generator of task ``index`` of the set with ``seed`` and ``arms`` arms."""
    if seed < 0:
        raise InvalidValueError("seed", "must be >= 0", seed)
    return np.random.default_rng([int(seed), int(arms), int(index)])


def sample_bases(count: int, rng: np.random.Generator) -> list[Pose]:
    """``count`` table-mounted base poses by the module's rules (the first at the origin)."""
    xy = [np.zeros(2)]
    while len(xy) < count:
        for _ in range(BASE_TRIES):
            anchor = xy[int(rng.integers(len(xy)))]
            r, angle = BASE_MAX_DISTANCE * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
            p = anchor + r * np.array([math.cos(angle), math.sin(angle)])
            if min(float(np.linalg.norm(p - q)) for q in xy) >= BASE_MIN_DISTANCE:
                xy.append(p)
                break
        else:
            raise NehmoError(f"no place for base {len(xy) + 1} of {count} in {BASE_TRIES} draws")
    yaws = rng.uniform(0, 2 * math.pi, size=count)
    return [
        Pose((float(p[0]), float(p[1]), BASE_HEIGHT), (0.0, 0.0, float(y)))
        for p, y in zip(xy, yaws, strict=True)
    ]


def hemisphere_point(rng: np.random.Generator, radius: float = WORKSPACE_RADIUS) -> np.ndarray:
    """A point [m] in the upper hemisphere of ``radius`` around the origin, drawn as Ha et al.
    draw their targets: azimuth and elevation uniform, the distance ``radius·√u``."""
    i, j, k = rng.uniform(size=3)
    r, elevation = radius * math.sqrt(j), k * math.pi / 2
    return r * np.array(
        [
            math.cos(2 * math.pi * i) * math.cos(elevation),
            math.sin(2 * math.pi * i) * math.cos(elevation),
            math.sin(elevation),
        ]
    )


def ha_difficulty(positions: Any, radius: float = WORKSPACE_RADIUS) -> float:
    """Ha et al.'s difficulty of a base layout: the largest share of one arm's workspace (the
    half ball of ``radius`` above its base, on their 5 cm grid) within ``radius`` of another
    base."""
    bases = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if len(bases) < 2:
        return 0.0
    axis = np.arange(-radius, radius, DIFFICULTY_STEP)
    up = np.arange(0.0, radius, DIFFICULTY_STEP)
    grid = np.stack(np.meshgrid(axis, axis, up, indexing="ij"), axis=-1).reshape(-1, 3)
    grid = grid[np.linalg.norm(grid, axis=1) < radius]
    worst = 0.0
    for i, base in enumerate(bases):
        others = np.delete(bases, i, axis=0)
        near = np.linalg.norm((grid + base)[:, None, :] - others[None], axis=2) < radius
        worst = max(worst, float(near.any(axis=1).mean()))
    return worst


def _pose_entry(T: np.ndarray) -> list[list[float]]:
    """A (4, 4) transform as ``[[x, y, z], [qx, qy, qz, qw]]``."""
    quat = Rotation.from_matrix(T[:3, :3]).as_quat()
    return [[float(v) for v in T[:3, 3]], [float(v) for v in quat]]


class TaskGenerator:
    """Generates the tasks of one :class:`TaskSpec`; owns two PyBullet worlds (close it)."""

    def __init__(self, spec: TaskSpec) -> None:
        self.spec = spec
        self.robot = load_robot(spec.robot)
        arms = tuple(
            ArmSpec(f"{self.robot.name}_{i}", self.robot, Pose()) for i in range(spec.arms)
        )
        self.world = CellWorld(Cell("generator", arms))  # bases moved per layout
        self.solo = CellWorld(Cell("self", arms[:1]))  # self-collision checks
        self.kinematics = ArmKinematics(self.robot)
        self.tool = np.eye(4)
        if spec.configs == "ik":
            self._ik_setup()
        if self.robot.name == HA_BENCHMARK_ROBOT:
            self.tool[0, 3] = TOOL_OFFSET

    def close(self) -> None:
        self.world.close()
        self.solo.close()

    def __enter__(self) -> TaskGenerator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _arm(
        self, arm: ArmSpec, rng: np.random.Generator, placed: dict[str, np.ndarray], start: Any
    ) -> np.ndarray | None:
        """One draw of ``arm`` that passes the rules given the arms ``placed``, or None."""
        spec, robot = self.spec, arm.robot
        for _ in range(spec.arm_tries):
            q = self._draw(rng)
            if q is None:
                continue  # an inverse-kinematics solution beyond the joint limits
            if (
                start is not None
                and np.linalg.norm(goal_error(q, start, robot)) < spec.min_goal_distance
            ):
                continue
            self.solo.set_joint_positions(self.solo.cell.arm_ids[0], q)
            if self.solo.in_collision():
                continue
            self.world.set_joint_positions(arm.arm_id, q)
            cutoff = spec.clearance + 0.01
            if all(self.world.distance(arm.arm_id, o, cutoff) >= spec.clearance for o in placed):
                return q
        return None

    def _ik_setup(self) -> None:
        """What every inverse-kinematics draw shares: the start posture, the tip link and where
        the arm's joints sit among the body's movable ones (PyBullet's solution order)."""
        robot, world = self.robot, self.solo
        arm = world.cell.arm_ids[0]
        wraps = robot.continuous  # else the middle of each joint's limits, 0 for one that wraps
        # (a wrapping joint's limits may be infinite: no arithmetic on them)
        middle = (np.where(wraps, 0.0, robot.lower) + np.where(wraps, 0.0, robot.upper)) / 2
        self._home = np.array(HOME.get(robot.name, middle))
        self._tip = world.link_index(arm, robot.tip_link)
        body, client = world.body(arm), world.client
        movable = [
            j
            for j in range(pb.getNumJoints(body, physicsClientId=client))
            if pb.getJointInfo(body, j, physicsClientId=client)[2] != pb.JOINT_FIXED
        ]
        self._solution_index = [movable.index(j) for j in world.joint_indices(arm)]

    def _draw(self, rng: np.random.Generator) -> np.ndarray | None:
        """One draw of the spec's kind; None for an inverse-kinematics solution beyond the
        joint limits."""
        robot = self.robot
        if self.spec.configs == "uniform":
            return sample_configuration(robot, rng)
        world = self.solo
        arm = world.cell.arm_ids[0]
        world.set_joint_positions(arm, self._home)
        solution = pb.calculateInverseKinematics(
            world.body(arm), self._tip, hemisphere_point(rng).tolist(), physicsClientId=world.client
        )
        q = np.array([solution[i] for i in self._solution_index])
        if np.any(q < robot.lower) or np.any(q > robot.upper):
            return None
        return q

    def _configuration(
        self, cell: Cell, rng: np.random.Generator, start: dict[str, np.ndarray] | None = None
    ) -> dict[str, np.ndarray] | None:
        """Every arm's start (``start`` None) or goal, drawn arm by arm, or None."""
        for _ in range(self.spec.restarts):
            placed: dict[str, np.ndarray] = {}
            for arm in cell.arms:
                q = self._arm(arm, rng, placed, None if start is None else start[arm.arm_id])
                if q is None:
                    break
                placed[arm.arm_id] = q
            else:
                return placed
        return None

    def generate(self, seed: int, index: int) -> dict[str, Any]:
        """Task ``index`` of the set with ``seed``, as the JSON object of its file."""
        spec = self.spec
        rng = task_rng(seed, spec.arms, index)
        name = task_id(spec.arms, seed, index)
        missing = "start"
        for _ in range(spec.layouts):
            bases = sample_bases(spec.arms, rng)
            arms = tuple(
                ArmSpec(a.arm_id, a.robot, b)
                for a, b in zip(self.world.cell.arms, bases, strict=True)
            )
            cell = Cell(name, arms)
            for arm in arms:
                self.world.set_base_pose(arm.arm_id, arm.base)
            start = self._configuration(cell, rng)
            goal = None if start is None else self._configuration(cell, rng, start)
            if start is not None and goal is not None:
                return self._task(cell, start, goal, seed, index)
            missing = "start" if start is None else "goal"
        raise NehmoError(
            f"task {name}: no collision-free {missing} of {spec.arms} {self.robot.name} arms with "
            f"every pair >= {spec.clearance} m apart (goals >= {spec.min_goal_distance} rad from "
            f"the starts) in {spec.layouts} base layouts x {spec.restarts} configurations x "
            f"{spec.arm_tries} draws per arm; lower the clearance or the minimum goal distance"
        )

    def _task(
        self,
        cell: Cell,
        start: dict[str, np.ndarray],
        goal: dict[str, np.ndarray],
        seed: int,
        index: int,
    ) -> dict[str, Any]:
        ids = cell.arm_ids
        q = torch.from_numpy(np.stack([goal[a] for a in ids]))
        with torch.no_grad():
            tips = self.kinematics.link_transforms(q)[self.robot.tip_link].double().numpy()
        targets = [
            arm.base.matrix() @ T @ self.tool for arm, T in zip(cell.arms, tips, strict=True)
        ]
        positions = [arm.base.xyz for arm in cell.arms]
        benchmark = self.robot.name == HA_BENCHMARK_ROBOT
        return {
            "id": cell.name,
            "robot": self.robot.name,
            "base_poses": [  # yaw only: [0, 0, sin(yaw / 2), cos(yaw / 2)]
                [list(a.base.xyz), [0.0, 0.0, math.sin(a.base.yaw / 2), math.cos(a.base.yaw / 2)]]
                for a in cell.arms
            ],
            "start_config": [start[a].tolist() for a in ids],
            "goal_config": [goal[a].tolist() for a in ids],
            "target_eff_poses": [_pose_entry(T) for T in targets],
            "start_goal_config": None,
            "obstacles": [],
            "difficulty": ha_difficulty(positions) if benchmark else None,
            "generator": {"seed": seed, "index": index, **asdict(self.spec)},
        }


def write_tasks(
    spec: TaskSpec, seed: int, count: int, out: Path, progress: bool = False
) -> list[Path]:
    """Generate tasks ``0 .. count-1`` of ``seed`` into ``out/<id>.json``; their paths."""
    if count < 1:
        raise InvalidValueError("count", "must be >= 1", count)
    task_rng(seed, spec.arms, 0)  # checks the seed
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    with TaskGenerator(spec) as generator:
        bar = tqdm(range(count), desc=f"{spec.arms}-arm tasks", unit="task", disable=not progress)
        for index in bar:
            data = generator.generate(seed, index)
            path = out / f"{data['id']}.json"
            path.write_text(json.dumps(data, indent=1) + "\n")
            paths.append(path)
    return paths
