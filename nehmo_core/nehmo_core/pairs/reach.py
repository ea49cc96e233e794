"""How far an arm's collision geometry reaches from its base axis, and so which base distances
a pair model must cover.

Two table-mounted arms can touch only if their bases are at most ``reach₁ + reach₂`` apart,
where ``reach`` is the largest horizontal distance of any point of an arm's collision geometry
from its base's vertical axis over its joint space (a reach measured with every joint free, joint
limits included). It is measured on PyBullet's collision shapes through their world-frame
axis-aligned boxes, which contain the shapes: the boxes can only overstate it, which is the safe
side for "which pairs can touch".
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel

__all__ = ["REACH_SAMPLES", "base_range", "horizontal_reach"]

REACH_SAMPLES = 4000
"""Random configurations per reach measurement (plus every joint at its limits' midpoints)."""
RANGE_STEP = 0.05
"""[m] A pair's base range is rounded outward to this step."""
MIN_BASE_DISTANCE = 0.25
"""[m] The nearest bases a pair model covers (Ha et al.'s protocol keeps bases >= 0.3 m apart)."""


def horizontal_reach(robot: RobotModel, samples: int = REACH_SAMPLES, seed: int = 0) -> float:
    """[m] The largest horizontal distance of the arm's collision geometry from its base axis."""
    world = CellWorld(Cell(f"reach_{robot.name}", (ArmSpec("arm", robot, Pose()),)))
    try:
        body, client = world.body("arm"), world.client
        links = [-1, *range(pb.getNumJoints(body, physicsClientId=client))]
        rng = np.random.default_rng(seed)
        lo, hi = np.maximum(robot.lower, -math.pi), np.minimum(robot.upper, math.pi)
        best = 0.0
        for q in rng.uniform(lo, hi, size=(samples, robot.dof)):
            world.set_joint_positions("arm", q)
            for link in links:
                a, b = pb.getAABB(body, link, physicsClientId=client)
                x = max(abs(a[0]), abs(b[0]))
                y = max(abs(a[1]), abs(b[1]))
                best = max(best, math.hypot(x, y))
        return best
    finally:
        world.close()


def base_range(reach_1: float, reach_2: float) -> tuple[float, float]:
    """[m] Base distances at which two arms of these reaches can touch, rounded outward."""
    high = math.ceil((reach_1 + reach_2) / RANGE_STEP) * RANGE_STEP
    return MIN_BASE_DISTANCE, round(high, 3)
