"""Start/goal sampling per the paper's protocol (DESIGN.md § 6), in this project's joint zeros.

The authors sample UR5 joints in their model's zeros; ``example-robot-data``'s UR5 differs by
−π/2 on shoulder_lift (q₂) and wrist_1 (q₄), so those two ranges are shifted here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import Cell, RobotModel, wrap_angle

_HALF_PI = np.pi / 2
SAMPLING_RANGES: dict[str, np.ndarray] = {
    # (dof, 2) [rad]: low, high per joint.
    "ur5": np.array(
        [
            [-5.0, -1.5],
            [-1.0 - _HALF_PI, 0.5 - _HALF_PI],
            [1.0, 2.0],
            [-0.2 - _HALF_PI, 0.8 - _HALF_PI],
            [-2.5, -0.5],
            [-1e-4, 0.0],
        ]
    ),
}


def sample_configuration(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    """One joint vector [rad]: the protocol's box for the UR5, the joint limits otherwise."""
    if robot.name in SAMPLING_RANGES:
        box = SAMPLING_RANGES[robot.name]
        q = rng.uniform(box[:, 0], box[:, 1])
    else:
        lo = np.maximum(robot.lower, -np.pi)
        hi = np.minimum(robot.upper, np.pi)
        q = rng.uniform(lo, hi)
    return robot.wrap(q)


@dataclass(frozen=True)
class Scenario:
    """Start and goal joint vectors per arm id."""

    start: Mapping[str, np.ndarray]
    goal: Mapping[str, np.ndarray]


def _collision_free(world: CellWorld, q: Mapping[str, np.ndarray]) -> bool:
    world.set_configuration(q)
    return not world.in_collision()


def sample_scenario(
    cell: Cell,
    rng: np.random.Generator,
    world: CellWorld | None = None,
    start_tries: int = 100,
    goal_tries: int = 10,
) -> Scenario:
    """Collision-free start and goal configurations of every arm (authors' retry counts)."""
    own = world is None
    w = world if world is not None else CellWorld(cell)
    try:
        start = goal = None
        for _ in range(start_tries):
            cand = {a.arm_id: sample_configuration(a.robot, rng) for a in cell.arms}
            if _collision_free(w, cand):
                start = cand
                break
        for _ in range(goal_tries if start is not None else 0):
            cand = {a.arm_id: sample_configuration(a.robot, rng) for a in cell.arms}
            if _collision_free(w, cand):
                goal = cand
                break
        if start is None or goal is None:
            raise NehmoError(f"no collision-free start/goal found for cell {cell.name!r}")
        return Scenario(start, goal)
    finally:
        if own:
            w.close()


def goal_error(q: np.ndarray, goal: np.ndarray, robot: RobotModel) -> np.ndarray:
    """Per-joint error [rad], wrapped on continuous joints."""
    e = np.asarray(q, dtype=np.float64) - np.asarray(goal, dtype=np.float64)
    c = robot.continuous
    e[c] = wrap_angle(e[c])
    return e
